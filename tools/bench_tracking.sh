#!/usr/bin/env bash
# Benchmark (not a test): tracking accuracy and time per frame of `dopslam run` on
# synthetic sequences (generated once into outputs/bench/), the ORB-SLAM2 baseline
# (--no-dop) until the DOP model lands.
#
#   bash tools/bench_tracking.sh [PRESET ...]
#   DOPSLAM_RUN_ARGS=--deterministic bash tools/bench_tracking.sh   (local mapping inline)
# Prints one line per preset: frames, coverage, keyframes, ATE RMSE, median/mean
# tracking time with its breakdown (ORB extraction, matching, optimisation).
set -euo pipefail
cd "$(dirname "$0")/.."
presets=("$@")
if [ ${#presets[@]} -eq 0 ]; then
  presets=(static_room fr1_xyz_room fr2_desk_room loop_room walking_xyz walking_static walking_rpy walking_halfsphere sitting)
fi
cargo build --release --quiet
mkdir -p outputs/bench
echo "cores: $(nproc)"
printf '%-20s %7s %9s %5s %10s %9s %9s %7s %7s %7s\n' preset frames coverage kfs "ATE (m)" "med ms" "mean ms" "ORB" match optim
for preset in "${presets[@]}"; do
  seq=outputs/bench/$preset
  if [ ! -f "$seq/rgb.txt" ]; then
    ./target/release/dopslam synth --config "configs/synth/$preset.toml" --out "$seq" --force >/dev/null
  fi
  rm -rf "outputs/bench/run-$preset"
  ./target/release/dopslam run "$seq" --out "outputs/bench/run-$preset" --no-dop ${DOPSLAM_RUN_ARGS:-} >/dev/null 2>&1 || echo "$preset: dopslam run failed (see outputs/bench/run-$preset)"
  python3 - "$preset" "outputs/bench/run-$preset/report.json" <<'PY'
import json, sys
name, path = sys.argv[1], sys.argv[2]
r = json.load(open(path)); t = r["totals"]
ate = r["ate"]["ape"]["statistics"]["rmse"] if r.get("ate") else float("nan")
print(f'{name:20s} {t["frames"]:7d} {t["coverage_percent"]:8.1f}% {t["keyframes"]:5d} {ate:10.4f} '
      f'{t["median_tracking_ms"]:9.1f} {t["mean_tracking_ms"]:9.1f} {t["median_extraction_ms"]:7.1f} '
      f'{t["median_matching_ms"]:7.1f} {t["median_optimisation_ms"]:7.1f}')
PY
done
