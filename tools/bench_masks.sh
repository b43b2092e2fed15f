#!/usr/bin/env bash
# Benchmark (not a test): the dense masks with and without the free-space evidence
# ([dense] mask_free_space_seconds), issue 35's dense goals. For each preset and seed:
# synth, one tracking pass with the real detector in the default real-time mode
# (--no-dense), then `dopslam fuse` with the evidence off, near (the frames within
# 0.5 s only: mask_free_space_far_seconds = 0) and on (the default, the far neighbours
# too): movers' pixels kept out and static pixels fused against the ground-truth masks
# (and the unknown movers' share on the non-COCO presets); then the keyframes' point
# cloud without carving (fusion = "points") each way, judged by `dopslam compare-maps`
# against the sequence's movers.ply (mover points). One JSON line per run and variant
# goes to OUT/rows.jsonl; tools/masks_table.py prints the medians.
#
#   bash tools/bench_masks.sh [--seeds N] [--jobs J] [--frames F] [--variants "V ..."]
#                             [--out DIR] [PRESET ...]
#
# --variants: which of off, near, on to fuse (default all three; "on" alone measures
# the default masks at a third of the time).
# --refuse: keep the tracking runs already in OUT/runs and only fuse them again (a
# change to the dense pass, measured on the same trajectories; rows.jsonl is rewritten).
# --frames F: the first F frames of each preset only (a quick check of the script).
# Default presets: the five cut-out presets and the two non-COCO ones. Seeds 1001,
# 1002, ... beside each preset's own. DOPSLAM_BIN: the binary (default
# ./target/release/dopslam, built when unset).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${DOPSLAM_BIN:-./target/release/dopslam}
seeds=5
jobs=1
frames_text=""
variants="off near on"
refuse=0
out=outputs/bench/masks
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2 ;;
    --jobs) jobs=$2; shift 2 ;;
    --frames) frames_text="--frames $2"; shift 2 ;;
    --variants) variants=$2; shift 2 ;;
    --refuse) refuse=1; shift ;;
    --out) out=$2; shift 2 ;;
    *) break ;;
  esac
done
for variant in $variants; do
  case "$variant" in off | near | on) ;; *) echo "--variants: '$variant' is not off, near or on" >&2; exit 2 ;; esac
done
presets=("$@")
[ ${#presets[@]} -gt 0 ] || presets=(cutout_xyz cutout_static cutout_rpy cutout_halfsphere cutout_seated_leaves unknown_movers unknown_movers_close)
[ -n "${DOPSLAM_BIN:-}" ] || cargo build --release --quiet
mkdir -p "$out/runs" "$out/seq"
# The fusions: no mesh, cloud or pictures where only the masks are measured.
printf '[dense]\nmask_free_space_seconds = 0.0\nmesh = false\ncloud = false\npictures = false\n' > "$out/off.toml"
printf '[dense]\nmask_free_space_far_seconds = 0.0\nmesh = false\ncloud = false\npictures = false\n' > "$out/near.toml"
printf '[dense]\nmesh = false\ncloud = false\npictures = false\n' > "$out/on.toml"
printf '[dense]\nfusion = "points"\nmask_free_space_seconds = 0.0\npictures = false\n' > "$out/points-off.toml"
printf '[dense]\nfusion = "points"\nmask_free_space_far_seconds = 0.0\npictures = false\n' > "$out/points-near.toml"
printf '[dense]\nfusion = "points"\npictures = false\n' > "$out/points-on.toml"

one() {
  local preset=$1 s=$2 seed_args=() seq run frames
  read -r -a frames <<<"$frames_text"
  seq=$out/seq/$preset-$s
  run=$out/runs/$preset-$s
  [ "$s" -gt 1 ] && seed_args=(--seed $((1000 + s - 1)))
  [ -f "$seq/rgb.txt" ] || "$bin" synth --config "configs/synth/$preset.toml" "${seed_args[@]}" ${frames[@]+"${frames[@]}"} --out "$seq" --force >/dev/null
  if [ "$refuse" = 1 ]; then
    [ -f "$run/report.json" ] || { echo "no tracking run to fuse again: $run" >&2; return; }
  else
    rm -rf "$run"
    "$bin" run "$seq" --out "$run" --no-dense --dop --detections onnx >"$run.log" 2>&1 || { echo "failed: $run.log" >&2; return; }
  fi
  for variant in $variants; do
    "$bin" fuse "$run" --config "$out/$variant.toml" >>"$run.log" 2>&1 || { echo "fuse failed: $run.log" >&2; continue; }
    cp "$run/dense.json" "$run/dense-$variant.json"
    "$bin" fuse "$run" --config "$out/points-$variant.toml" >>"$run.log" 2>&1 || { echo "fuse failed: $run.log" >&2; continue; }
    "$bin" compare-maps "$run/dense_points.ply" --movers "$seq/movers.ply" --reference "$seq/static_scene.ply" \
      --align --out "$run/compare-$variant" --json >"$run/cloud-$variant.json" 2>>"$run.log" || { echo "compare failed: $run.log" >&2; continue; }
    python3 - "$preset" "$s" "$variant" "$run" >>"$out/rows.jsonl" <<'PY'
import json, sys
preset, seed, variant, run = sys.argv[1:]
report = json.load(open(f"{run}/report.json"))
dense = json.load(open(f"{run}/dense-{variant}.json"))
cloud = json.load(open(f"{run}/cloud-{variant}.json"))["maps"][0]
truth = dense["truth"]
recall = report["detection"].get("person_recall") or {}
print(json.dumps(dict(
    preset=preset, seed=int(seed), free_space=variant,
    ate_mm=1000 * report["ate"]["ape"]["statistics"]["rmse"],
    person_recall=recall.get("recall"),
    median_tracking_ms=report["totals"]["median_tracking_ms"],
    movers_kept_out=truth["dynamic_removed"], static_fused=truth["static_kept"],
    unknown_kept_out=truth.get("unknown_removed"), masked_percent=dense["masked_percent"],
    dense_seconds=dense["total_s"],
    cloud_points=cloud["points"], cloud_mover_points=cloud["mover_points"],
)))
PY
  done
  rm -f "$run/dense_points.ply"
  rm -rf "$run/compare-off" "$run/compare-near" "$run/compare-on"
}
export -f one
export bin out frames_text variants refuse
rm -f "$out/rows.jsonl"
for preset in "${presets[@]}"; do
  for ((s = 1; s <= seeds; s++)); do echo "$preset $s"; done
done | xargs -P "$jobs" -n 2 bash -c 'one "$0" "$1"'
python3 tools/masks_table.py "$out/rows.jsonl"
