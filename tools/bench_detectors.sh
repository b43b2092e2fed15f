#!/usr/bin/env bash
# Benchmark (not a test): which detector, and which masks, by measurement (issue 35).
# For each preset and seed, in the default real-time mode, runs the tracking with each
# detector choice, then fuses the dense map twice: with the DOP masks cut at depth (the
# default) and with whole dynamic boxes (--mask-boxes). One JSON line per run and
# masking goes to OUT/rows.jsonl; tools/detector_table.py turns them into the table
# (medians over seeds).
#
#   bash tools/bench_detectors.sh [--seeds N] [--jobs J] [--out DIR] [PRESET ...]
#
# Detectors: yolov4-tiny (the default), deimv2-femto, pool (both, one class-wise NMS).
# --jobs J runs J sequences at once (real-time figures are only comparable at the same
# J on the same machine). DOPSLAM_BIN: the binary (default ./target/release/dopslam).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${DOPSLAM_BIN:-./target/release/dopslam}
seeds=5
jobs=1
out=outputs/bench/detectors
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2 ;;
    --jobs) jobs=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    *) break ;;
  esac
done
presets=("$@")
[ ${#presets[@]} -gt 0 ] || presets=(cutout_xyz cutout_static cutout_rpy cutout_halfsphere cutout_seated_leaves)
[ -n "${DOPSLAM_BIN:-}" ] || cargo build --release --quiet
mkdir -p "$out/runs" "$out/seq"
printf '[detector]\nmodel = "deimv2-femto"\n' > "$out/deimv2-femto.toml"
printf '[[detector.pool]]\nmodel = "yolov4-tiny"\nscore_threshold = 0.1\n[[detector.pool]]\nmodel = "deimv2-femto"\nscore_threshold = 0.3\n' > "$out/pool.toml"
printf '' > "$out/yolov4-tiny.toml"

# One sequence: generate it, then every detector and both maskings, one after another.
one() {
  local preset=$1 s=$2 seed_args=() seq
  seq=$out/seq/$preset-$s
  [ "$s" -gt 1 ] && seed_args=(--seed $((1000 + s - 1)))
  [ -f "$seq/rgb.txt" ] || "$bin" synth --config "configs/synth/$preset.toml" "${seed_args[@]}" --out "$seq" --force >/dev/null
  for detector in yolov4-tiny deimv2-femto pool; do
    local run=$out/runs/$preset-$s-$detector
    rm -rf "$run"
    "$bin" run "$seq" --out "$run" --no-dense --dop --detections onnx --config "$out/$detector.toml" >"$run.log" 2>&1 || { echo "failed: $run.log" >&2; continue; }
    local metrics
    metrics=$(python3 tools/people_metrics.py "$run" "$seq" --json)
    for masking in depth-cut boxes; do
      local flag=()
      [ "$masking" = boxes ] && flag=(--mask-boxes)
      "$bin" fuse "$run" "${flag[@]}" >>"$run.log" 2>&1 || { echo "fuse failed: $run.log" >&2; continue; }
      python3 - "$preset" "$s" "$detector" "$masking" "$run/dense.json" "$metrics" >>"$out/rows.jsonl" <<'PY'
import json, sys
preset, seed, detector, masking, dense, metrics = sys.argv[1:]
d = json.load(open(dense))
row = dict(preset=preset, seed=int(seed), detector=detector, masking=masking, **json.loads(metrics))
row.update({k: d["truth"][k] for k in ("dynamic_removed", "static_kept", "unknown_removed")})
row["masked_percent"] = d["masked_percent"]
print(json.dumps(row))
PY
    done
    rm -rf "$run/dense_mesh.ply" "$run/dense_mesh.obj" "$run/dense_points.ply"
  done
}
export -f one
export bin out
rm -f "$out/rows.jsonl"
for preset in "${presets[@]}"; do
  for ((s = 1; s <= seeds; s++)); do echo "$preset $s"; done
done | xargs -P "$jobs" -n 2 bash -c 'one "$0" "$1"'
python3 tools/detector_table.py "$out/rows.jsonl"
