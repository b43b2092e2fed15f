#!/usr/bin/env bash
# Benchmark (not a test): tracking accuracy and time per frame of `dopslam run` on
# synthetic sequences (generated once into outputs/bench/), in real-time mode (local
# mapping and detection in their own threads).
#
#   bash tools/bench_tracking.sh [--mode no-dop|mask-boxes|dop] [--detections oracle|onnx] [PRESET ...]
#   DOPSLAM_RUN_ARGS=--deterministic bash tools/bench_tracking.sh   (local mapping inline)
# Default: --mode no-dop (the ORB-SLAM2 baseline) with no detector. Prints one line per
# preset: frames, coverage, keyframes, ATE RMSE, median/mean tracking time with its
# breakdown (ORB extraction, matching, optimisation, DOP model).
set -euo pipefail
cd "$(dirname "$0")/.."
mode=no-dop
detections=none
while [ $# -gt 0 ]; do
  case "$1" in
    --mode) mode=$2; shift 2 ;;
    --detections) detections=$2; shift 2 ;;
    *) break ;;
  esac
done
presets=("$@")
if [ ${#presets[@]} -eq 0 ]; then
  presets=(static_room fr1_xyz_room fr2_desk_room loop_room walking_xyz walking_static walking_rpy walking_halfsphere sitting)
fi
cargo build --release --quiet
mkdir -p outputs/bench
echo "cores: $(nproc), --$mode, detections: $detections"
printf '%-20s %7s %9s %5s %10s %9s %9s %7s %7s %7s %7s\n' preset frames coverage kfs "ATE (m)" "med ms" "mean ms" "ORB" match optim dop
for preset in "${presets[@]}"; do
  seq=outputs/bench/$preset
  if [ ! -f "$seq/rgb.txt" ]; then
    ./target/release/dopslam synth --config "configs/synth/$preset.toml" --out "$seq" --force >/dev/null
  fi
  out=outputs/bench/run-$preset-$mode-$detections
  rm -rf "$out"
  ./target/release/dopslam run "$seq" --out "$out" --$mode --detections "$detections" --no-dense ${DOPSLAM_RUN_ARGS:-} >/dev/null 2>&1 || echo "$preset: dopslam run failed (see $out)"
  python3 - "$preset" "$out/report.json" <<'PY'
import json, sys
name, path = sys.argv[1], sys.argv[2]
r = json.load(open(path)); t = r["totals"]
ate = r["ate"]["ape"]["statistics"]["rmse"] if r.get("ate") else float("nan")
print(f'{name:20s} {t["frames"]:7d} {t["coverage_percent"]:8.1f}% {t["keyframes"]:5d} {ate:10.4f} '
      f'{t["median_tracking_ms"]:9.1f} {t["mean_tracking_ms"]:9.1f} {t["median_extraction_ms"]:7.1f} '
      f'{t["median_matching_ms"]:7.1f} {t["median_optimisation_ms"]:7.1f} {t["median_dop_ms"]:7.2f}')
PY
done
