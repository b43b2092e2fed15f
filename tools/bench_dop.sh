#!/usr/bin/env bash
# Benchmark (not a test): ATE of the three ways of treating moving objects on the
# synthetic presets, with the oracle detections (the detector's errors left out) or a
# real model:
#   bash tools/bench_dop.sh [--detections oracle|onnx] [PRESET ...]
# Runs `dopslam run --deterministic` with --no-dop, --mask-boxes and --dop on each
# preset (sequences generated once into outputs/bench/) and prints one line per preset:
# ATE RMSE per mode, keyframes, and with --dop the median keypoints removed per frame.
set -euo pipefail
cd "$(dirname "$0")/.."
detections=oracle
if [ "${1:-}" = "--detections" ]; then detections=$2; shift 2; fi
presets=("$@")
if [ ${#presets[@]} -eq 0 ]; then
  presets=(walking_xyz walking_static walking_rpy walking_halfsphere sitting static_room)
fi
cargo build --release --quiet
mkdir -p outputs/bench
printf '%-20s %12s %12s %12s %8s %10s\n' preset "no-dop (m)" "mask (m)" "dop (m)" "dop kfs" "removed/fr"
for preset in "${presets[@]}"; do
  seq=outputs/bench/$preset
  if [ ! -f "$seq/rgb.txt" ]; then
    ./target/release/dopslam synth --config "configs/synth/$preset.toml" --out "$seq" --force >/dev/null
  fi
  for mode in no-dop mask-boxes dop; do
    out=outputs/bench/dop-$detections-$preset-$mode
    rm -rf "$out"
    ./target/release/dopslam run "$seq" --out "$out" --detections "$detections" --$mode --deterministic >/dev/null 2>&1 \
      || echo "$preset $mode: dopslam run failed (see $out)"
  done
  python3 - "$preset" outputs/bench/dop-$detections-$preset <<'PY'
import json, statistics, sys
name, base = sys.argv[1], sys.argv[2]
def load(mode):
    return json.load(open(f"{base}-{mode}/report.json"))
ate = {m: load(m)["ate"]["ape"]["statistics"]["rmse"] for m in ("no-dop", "mask-boxes", "dop")}
dop = load("dop")
removed = statistics.median(f["dynamic_keypoints"] for f in dop["frames"])
print(f'{name:20s} {ate["no-dop"]:12.4f} {ate["mask-boxes"]:12.4f} {ate["dop"]:12.4f} '
      f'{dop["totals"]["keyframes"]:8d} {removed:10.0f}')
PY
done
