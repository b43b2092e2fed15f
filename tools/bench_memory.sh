#!/usr/bin/env bash
# Benchmark (not a test): peak memory of long runs. Images are streamed, so memory
# should follow the map (keyframes and map points), not the number of frames. Makes
# (once, into outputs/bench/) a 5000-frame room (loop_walking: 5.5 turns around the
# room with two walkers) and the full 4541-frame KITTI 00 street (street_kitti00 at
# its full length; needs ../shared/data), runs `dopslam run` on a 1000-frame prefix
# and on the whole of each (real detector, default real-time mode, global pass on;
# dense pass off unless --dense) and prints the peak resident memory from the report
# (VmHWM) with the map's size.
#
#   bash tools/bench_memory.sh [--dense] [room|street ...]
set -euo pipefail
cd "$(dirname "$0")/.."
dense=--no-dense
if [ "${1:-}" = "--dense" ]; then dense=; shift; fi
which=("$@")
if [ ${#which[@]} -eq 0 ]; then which=(room street); fi
cargo build --release --quiet
mkdir -p outputs/bench
printf '%-8s %7s %9s %6s %9s %10s %10s %9s\n' sequence frames coverage kfs points "peak MiB" "MiB/kf" "dense MiB"
for name in "${which[@]}"; do
  case $name in
    room) preset=loop_walking; frames=5000; seq=outputs/bench/long_room ;;
    street) preset=street_kitti00; frames=4541; seq=outputs/bench/long_street ;;
    *) echo "unknown: $name (room or street)" >&2; exit 2 ;;
  esac
  if [ ! -f "$seq/scene.toml" ]; then
    ./target/release/dopslam synth --config "configs/synth/$preset.toml" --frames "$frames" --out "$seq" --force >/dev/null
  fi
  input=$seq
  for kitti in "$seq"/kitti/sequences/*/; do [ -d "$kitti" ] && input=${kitti%/}; done
  for n in 1000 "$frames"; do
    out=outputs/bench/memory-$name-$n
    rm -rf "$out"
    ./target/release/dopslam run "$input" --out "$out" --frames "$n" $dense >"$out.log" 2>&1 || echo "$name: dopslam run failed (see $out.log)"
    python3 - "$name" "$out/report.json" <<'PY'
import json, sys
name, path = sys.argv[1], sys.argv[2]
r = json.load(open(path))
t = r["totals"]
peak = t.get("peak_memory_mib") or 0.0
dense = (r.get("dense") or {}).get("peak_memory_mib")
print(f"{name:<8} {t['frames']:7d} {t['coverage_percent']:8.1f}% {t['keyframes']:6d} {t['map_points']:9d} "
      f"{peak:10.0f} {peak / max(t['keyframes'], 1):10.2f} {dense if dense is not None else '-':>9}")
PY
  done
done
