#!/usr/bin/env bash
# Benchmark (not a test): ATE of the three ways of treating moving objects on the
# synthetic presets, with the oracle detections (the detector's errors left out) or a
# real model:
#   bash tools/bench_dop.sh [--detections oracle|onnx] [--seeds N] [--modes "no-dop mask-boxes dop"] [PRESET ...]
# Runs `dopslam run --deterministic` in each mode on each preset (sequences generated
# once into outputs/bench/; with --seeds N also N-1 more sequences of the preset drawn
# with seeds 1001, 1002, ... for the sensor noise and the movers) and prints per preset
# the ATE RMSE per mode (the median over the seeds, then each seed's), the keyframes
# and the median keypoints removed per frame with --dop; then tools/dop_compare.py on
# the preset's own seed: keypoints on the static scene and on movers used in the pose
# where the boxes are large.
set -euo pipefail
cd "$(dirname "$0")/.."
detections=oracle
seeds=1
modes="no-dop mask-boxes dop"
while [ $# -gt 0 ]; do
  case "$1" in
    --detections) detections=$2; shift 2 ;;
    --seeds) seeds=$2; shift 2 ;;
    --modes) modes=$2; shift 2 ;;
    *) break ;;
  esac
done
presets=("$@")
if [ ${#presets[@]} -eq 0 ]; then
  presets=(walking_xyz walking_static walking_rpy walking_halfsphere sitting static_room seated_leaves)
fi
cargo build --release --quiet
mkdir -p outputs/bench
for preset in "${presets[@]}"; do
  runs=()
  for ((s = 1; s <= seeds; s++)); do
    seq=outputs/bench/$preset
    seed_args=()
    if [ "$s" -gt 1 ]; then
      seq=outputs/bench/$preset-seed$((1000 + s - 1))
      seed_args=(--seed $((1000 + s - 1)))
    fi
    if [ ! -f "$seq/rgb.txt" ]; then
      ./target/release/dopslam synth --config "configs/synth/$preset.toml" "${seed_args[@]}" --out "$seq" --force >/dev/null
    fi
    for mode in $modes; do
      out=outputs/bench/dop-$detections-$(basename "$seq")-$mode
      rm -rf "$out"
      ./target/release/dopslam run "$seq" --out "$out" --detections "$detections" --$mode --deterministic --no-dense >/dev/null 2>&1 \
        || echo "$preset $mode: dopslam run failed (see $out)"
    done
    runs+=("outputs/bench/dop-$detections-$(basename "$seq")")
  done
  python3 - "$preset" "$modes" "${runs[@]}" <<'PY'
import json, statistics, sys
name, modes, bases = sys.argv[1], sys.argv[2].split(), sys.argv[3:]
def load(base, mode):
    return json.load(open(f"{base}-{mode}/report.json"))
cells = []
for mode in modes:
    ates = [load(b, mode)["ate"]["ape"]["statistics"]["rmse"] for b in bases]
    each = "" if len(ates) == 1 else " (" + " ".join(f"{a:.4f}" for a in ates) + ")"
    cells.append(f"{mode} {statistics.median(ates):.4f}{each}")
line = f"{name:20s} ATE RMSE (m): " + ", ".join(cells)
if "dop" in modes:
    dop = load(bases[0], "dop")
    removed = statistics.median(f["dynamic_keypoints"] for f in dop["frames"])
    c = dop["detection"].get("classification") or {}
    line += (f"; dop keyframes {dop['totals']['keyframes']}, removed/frame {removed:.0f}, "
             f"precision {c.get('precision', float('nan')):.3f} recall {c.get('recall', float('nan')):.3f}")
if "mask-boxes" in modes:
    c = load(bases[0], "mask-boxes")["detection"].get("classification") or {}
    line += f"; mask-boxes precision {c.get('precision', float('nan')):.3f} recall {c.get('recall', float('nan')):.3f}"
print(line, flush=True)
PY
  if [ "$modes" = "no-dop mask-boxes dop" ]; then
    python3 tools/dop_compare.py "outputs/bench/$preset" "outputs/bench/dop-$detections-$preset"
  fi
done
