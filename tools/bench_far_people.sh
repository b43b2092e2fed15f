#!/usr/bin/env bash
# Benchmark (not a test): far people in the dense map (issue 47). For each preset and
# seed: synth, one tracking pass with the real detector in the default real-time mode
# (--no-dense), then `dopslam fuse` on the same trajectory with each of the variants
# (--variants, default "before after deim"): "before" (the dense pass's own detections
# on the whole image only, [dense] detect_tiles = 1, as before issue 47), "after" (the
# defaults: 2 x 2 tiles and the whole image) and "deim" (DEIMv2-femto on the whole
# image, where tools/setup.sh could install it). Each variant gives, against the sequence's
# ground truth: movers' pixels kept out and static pixels fused (dense.json), the TSDF
# mesh's vertices on movers and the keyframes' cloud without carving (fusion =
# "points") points on movers (`dopslam compare-maps` against movers.ply), the person
# recall of the dense pass's detections by person height (tools/person_recall.py
# against the oracle boxes) and the dense pass's time. One JSON line per run and
# variant goes to OUT/rows.jsonl; tools/far_people_table.py prints the table.
#
#   bash tools/bench_far_people.sh [--seeds N] [--frames F] [--variants "V ..."]
#                                  [--out DIR] [PRESET ...]
#
# Default preset: desk_far_people. Seeds: the preset's own, then 1001, 1002, ...
# --frames F: the first F frames only (a quick check of the script).
# DOPSLAM_BIN: the binary (default ./target/release/dopslam, built when unset).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${DOPSLAM_BIN:-./target/release/dopslam}
seeds=3
frames=()
variants="before after deim"
out=outputs/bench/far_people
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2 ;;
    --frames) frames=(--frames "$2"); shift 2 ;;
    --variants) variants=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    -h | --help) sed -n '2,23p' "$0"; exit 0 ;;
    *) break ;;
  esac
done
presets=("$@")
[ ${#presets[@]} -gt 0 ] || presets=(desk_far_people)
[ -n "${DOPSLAM_BIN:-}" ] || cargo build --release --quiet
mkdir -p "$out/runs" "$out/seq"
for variant in $variants; do
  case "$variant" in
    before) keys='detect_tiles = 1\n' ;;
    after) keys='' ;;
    deim) keys='detect_model = "deimv2-femto"\ndetect_tiles = 1\n' ;;
    *) echo "--variants: '$variant' is not before, after or deim" >&2; exit 2 ;;
  esac
  printf "[dense]\n${keys}obj = false\npictures = false\n" > "$out/$variant.toml"
  printf "[dense]\n${keys}fusion = \"points\"\npictures = false\n" > "$out/points-$variant.toml"
done
rows=$out/rows.jsonl
rm -f "$rows"

judge() { # MAP SEQ -> the JSON of compare-maps' first map
  "$bin" compare-maps "$1" --movers "$2/movers.ply" --reference "$2/static_scene.ply" \
    --align --out "$(dirname "$1")/compare" --json
}

for preset in "${presets[@]}"; do
  for ((s = 1; s <= seeds; s++)); do
    seq=$out/seq/$preset-$s
    run=$out/runs/$preset-$s
    seed_args=()
    [ "$s" -gt 1 ] && seed_args=(--seed $((1000 + s - 1)))
    echo "$preset seed $s" >&2
    [ -f "$seq/rgb.txt" ] || "$bin" synth --config "configs/synth/$preset.toml" ${seed_args[@]+"${seed_args[@]}"} \
      ${frames[@]+"${frames[@]}"} --out "$seq" --force >/dev/null
    rm -rf "$run"
    "$bin" run "$seq" --out "$run" --no-dense --dop --detections onnx >"$run.log" 2>&1 || { echo "failed: $run.log" >&2; continue; }
    for variant in $variants; do
      "$bin" fuse "$run" --config "$out/$variant.toml" >>"$run.log" 2>&1 || { echo "fuse failed: $run.log" >&2; continue; }
      cp "$run/dense.json" "$run/dense-$variant.json"
      judge "$run/dense_mesh.ply" "$seq" >"$run/mesh-$variant.json" 2>>"$run.log"
      python3 tools/person_recall.py "$seq/detections_oracle" "$run/detections_dense" --min-area 0 --json \
        >"$run/recall-$variant.json"
      "$bin" fuse "$run" --config "$out/points-$variant.toml" >>"$run.log" 2>&1 || { echo "fuse failed: $run.log" >&2; continue; }
      judge "$run/dense_points.ply" "$seq" >"$run/cloud-$variant.json" 2>>"$run.log"
      python3 - "$preset" "$s" "$variant" "$run" >>"$rows" <<'PY'
import json, sys
preset, seed, variant, run = sys.argv[1:]
load = lambda name: json.load(open(f"{run}/{name}"))
report, dense = load("report.json"), load(f"dense-{variant}.json")
mesh, cloud = load(f"mesh-{variant}.json")["maps"][0], load(f"cloud-{variant}.json")["maps"][0]
recall = load(f"recall-{variant}.json")
truth = dense["truth"]
print(json.dumps(dict(
    preset=preset, seed=int(seed), variant=variant,
    ate_mm=1000 * report["ate"]["ape"]["statistics"]["rmse"],
    keyframe_person_recall=(report["detection"].get("person_recall") or {}).get("recall"),
    movers_kept_out=truth["dynamic_removed"], static_fused=truth["static_kept"],
    mesh_vertices=mesh["points"], mesh_mover_vertices=mesh["mover_points"],
    cloud_points=cloud["points"], cloud_mover_points=cloud["mover_points"],
    dense_recall=recall["recall"], dense_recall_by_height=recall["by_height"],
    dense_detection_ms=(dense.get("extra_detections") or {}).get("median_ms"),
    dense_seconds=dense["total_s"],
)))
PY
    done
    rm -rf "$run/previous" "$run/compare"
  done
done
python3 tools/far_people_table.py "$rows"
