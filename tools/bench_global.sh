#!/usr/bin/env bash
# Benchmark (not a test): the global pass (loop closing, essential graph, full BA) on
# generated sequences (made once into outputs/bench/): ATE RMSE of the tracking pass
# (trajectory_tracking.txt) against the final trajectory (trajectory.txt), loops
# closed, candidates rejected, full-BA time. Default: the real detector (onnx) in the
# default real-time mode, with the DOP model.
#
#   bash tools/bench_global.sh [--detections onnx|oracle|none] [PRESET ...]
#   DOPSLAM_RUN_ARGS=--deterministic bash tools/bench_global.sh
set -euo pipefail
cd "$(dirname "$0")/.."
detections=onnx
if [ "${1:-}" = "--detections" ]; then detections=$2; shift 2; fi
presets=("$@")
if [ ${#presets[@]} -eq 0 ]; then
  presets=(loop_room loop_walking static_room fr2_desk_room walking_xyz walking_static walking_rpy walking_halfsphere cutout_xyz)
fi
cargo build --release --quiet
mkdir -p outputs/bench
echo "cores: $(nproc), detections: $detections, args: ${DOPSLAM_RUN_ARGS:-(default real-time)}"
printf '%-20s %8s %5s %12s %12s %6s %9s %9s\n' preset coverage kfs "ATE track" "ATE global" loops rejected "BA ms"
for preset in "${presets[@]}"; do
  seq=outputs/bench/$preset
  if [ ! -f "$seq/rgb.txt" ]; then
    ./target/release/dopslam synth --config "configs/synth/$preset.toml" --out "$seq" --force >/dev/null
  fi
  out=outputs/bench/global-$preset-$detections${DOPSLAM_RUN_ARGS:+-det}
  rm -rf "$out"
  ./target/release/dopslam run "$seq" --out "$out" --detections "$detections" --no-dense ${DOPSLAM_RUN_ARGS:-} >/dev/null 2>&1 || echo "$preset: dopslam run failed (see $out)"
  python3 - "$preset" "$out/report.json" <<'PY'
import json, sys
name, path = sys.argv[1], sys.argv[2]
r = json.load(open(path))
g = r.get("global") or {}
ate = lambda e: f"{e['ape']['statistics']['rmse']:.4f}" if e else "-"
ba = g.get("full_ba") or {}
rejected = sum(1 for c in g.get("candidates", []) if not c["accepted"])
print(f"{name:<20} {r['totals']['coverage_percent']:7.1f}% {r['totals']['keyframes']:5d} {ate(r.get('ate_tracking')):>12} {ate(r.get('ate')):>12} "
      f"{len(g.get('loops', [])):6d} {rejected:9d} {ba.get('milliseconds', 0):9.0f}")
PY
done
