#!/usr/bin/env bash
# Benchmark (not a test): the dense pass's masks and time (issue 80). For each preset
# and seed: synth, one tracking pass with the real detector in the default real-time
# mode (--no-dense), then `dopslam fuse` of the same trajectory with each variant
# (--variants; each a [dense] snippet in tools/dense_variants/NAME.toml, "default" the
# defaults). Each fusion gives, against the sequence's ground truth: pixels masked
# (all, and those with depth), movers' pixels kept out, static pixels fused, each mask
# source's pixels and precision (dense.json's truth.sources), the mesh's vertices on
# movers (`dopslam compare-maps` against movers.ply), and where the dense pass's time
# went (dense.json's stages) beside the tracking pass's wall time (report.json's
# times). One JSON line per run and variant goes to OUT/rows.jsonl;
# tools/dense_pass_table.py prints the tables.
#
#   bash tools/bench_dense_pass.sh [--seeds N] [--frames F] [--variants "V ..."]
#                                  [--refuse] [--out DIR] [PRESET ...]
#
# Default preset: desk_far_people (TUM fr2_desk's path, far walkers), 900 frames.
# Seeds: the preset's own, then 1001, 1002, ... --refuse: fuse the tracking runs
# already in OUT/runs again. DOPSLAM_BIN: the binary (default
# ./target/release/dopslam, built when unset).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${DOPSLAM_BIN:-./target/release/dopslam}
seeds=1
frames=900
variants="default map10"
refuse=0
out=outputs/bench/dense_pass
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2 ;;
    --frames) frames=$2; shift 2 ;;
    --variants) variants=$2; shift 2 ;;
    --refuse) refuse=1; shift ;;
    --out) out=$2; shift 2 ;;
    -h | --help) sed -n '2,20p' "$0"; exit 0 ;;
    *) break ;;
  esac
done
presets=("$@")
[ ${#presets[@]} -gt 0 ] || presets=(desk_far_people)
for variant in $variants; do
  [ -f "tools/dense_variants/$variant.toml" ] || { echo "--variants: no tools/dense_variants/$variant.toml" >&2; exit 2; }
done
[ -n "${DOPSLAM_BIN:-}" ] || cargo build --release --quiet
mkdir -p "$out/runs" "$out/seq"
rows=$out/rows.jsonl
rm -f "$rows"
for preset in "${presets[@]}"; do
  for ((s = 1; s <= seeds; s++)); do
    seq=$out/seq/$preset-$s
    run=$out/runs/$preset-$s
    seed_args=()
    [ "$s" -gt 1 ] && seed_args=(--seed $((1000 + s - 1)))
    echo "$preset seed $s" >&2
    [ -f "$seq/rgb.txt" ] || "$bin" synth --config "configs/synth/$preset.toml" ${seed_args[@]+"${seed_args[@]}"} \
      --frames "$frames" --out "$seq" --force >/dev/null
    if [ "$refuse" = 0 ] || [ ! -f "$run/report.json" ]; then
      rm -rf "$run"
      "$bin" run "$seq" --out "$run" --no-dense --dop --detections onnx >"$run.log" 2>&1 || { echo "failed: $run.log" >&2; continue; }
    fi
    for variant in $variants; do
      # The dense pass's own detections are cached in the run folder: every variant
      # after the first reuses them, so its detection time is not the pass's.
      { cat "tools/dense_variants/$variant.toml"; printf 'obj = false\npictures = false\n'; } > "$out/$variant.toml"
      "$bin" fuse "$run" --config "$out/$variant.toml" >>"$run.log" 2>&1 || { echo "fuse failed: $run.log" >&2; continue; }
      cp "$run/dense.json" "$run/dense-$variant.json"
      "$bin" compare-maps "$run/dense_mesh.ply" --movers "$seq/movers.ply" --reference "$seq/static_scene.ply" \
        --align --out "$run/compare" --json >"$run/mesh-$variant.json" 2>>"$run.log" || { echo "compare failed: $run.log" >&2; continue; }
      python3 - "$preset" "$s" "$variant" "$run" >>"$rows" <<'PY'
import json, sys
preset, seed, variant, run = sys.argv[1:]
load = lambda name: json.load(open(f"{run}/{name}"))
report, dense, mesh = load("report.json"), load(f"dense-{variant}.json"), load(f"mesh-{variant}.json")["maps"][0]
truth = dense["truth"]
times = report.get("times") or {}
tracking = next((s["seconds"] for s in times.get("stages", []) if s["stage"] == "tracking"), None)
with_depth = truth["mover_pixels"] + truth["static_pixels"]
masked_with_depth = truth["mover_pixels"] - truth["mover_pixels_fused"] + truth["static_pixels"] - truth["static_pixels_fused"]
print(json.dumps(dict(
    preset=preset, seed=int(seed), variant=variant, frames=dense["frames_fused"],
    ate_mm=1000 * report["ate"]["ape"]["statistics"]["rmse"],
    recording_s=times.get("recording_s"), tracking_s=tracking,
    masked_percent=dense["masked_percent"],
    masked_depth_percent=100.0 * masked_with_depth / max(with_depth, 1),
    mover_percent=100.0 * truth["mover_pixels"] / max(with_depth, 1),
    movers_kept_out=truth["dynamic_removed"], static_fused=truth["static_kept"],
    mesh_vertices=mesh["points"], mesh_mover_vertices=mesh["mover_points"],
    sources=truth.get("sources", []), released=dense.get("released_on_map", 0),
    stages=dense.get("stages", {}), dense_s=dense["total_s"],
    detection_ms=(dense.get("extra_detections") or {}).get("median_ms"),
)))
PY
    done
    rm -rf "$run/compare"
  done
done
python3 tools/dense_pass_table.py "$rows"
