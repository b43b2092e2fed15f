#!/usr/bin/env bash
# Benchmark (not a test) of issue 82's sessions: two recordings of one rendered room
# (configs/synth/revisit_a.toml: a full turn with two walkers; revisit_b.toml: the same
# room, `[scene] room_of`, starting half a turn on, three other walkers). Renders them
# once into outputs/bench/sessions/, runs the first, then the second three ways: on
# its own, with `--map` (continued) and with `--map --map-frozen`, each N times (real
# detector, default real-time mode, dense pass off), and prints
# tools/sessions_table.py's table: the second's ATE in the first's world frame without
# alignment (goal <= 1 cm; the first run's row gives its own map's error, which the
# second inherits), the frame it was placed at (goal: within 30 frames of its
# first view of a mapped place, frame 0 here), keyframes, tracking time per frame
# (frozen against its own run: goal no slower), the map file's size and load time.
#
#   bash tools/bench_sessions.sh [N]
#
# DOPSLAM_BIN: the binary (default ./target/release/dopslam, built when unset); OUT:
# where the runs go (default outputs/bench/sessions/runs).
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-1}
dopslam=${DOPSLAM_BIN:-./target/release/dopslam}
[ -n "${DOPSLAM_BIN:-}" ] || cargo build --release --quiet
python=data/venv/bin/python
base=outputs/bench/sessions
mkdir -p "$base"
for name in revisit_a revisit_b; do
  [ -f "$base/$name/groundtruth.txt" ] || "$dopslam" synth --config "configs/synth/$name.toml" --out "$base/$name" --force
done
dirs=()
for i in $(seq 1 "$runs"); do
  out=${OUT:-$base/runs}/$i
  "$dopslam" run "$base/revisit_a" --out "$out/first" --no-dense > /dev/null
  "$dopslam" run "$base/revisit_b" --out "$out/alone" --no-dense > /dev/null
  "$dopslam" run "$base/revisit_b" --out "$out/continued" --no-dense --map "$out/first" > /dev/null
  "$dopslam" run "$base/revisit_b" --out "$out/frozen" --no-dense --map "$out/first" --map-frozen > /dev/null
  dirs+=("$out/first" "$out/alone" "$out/continued" "$out/frozen")
done
"$python" tools/sessions_table.py "$base/revisit_a" "$base/revisit_b" "${dirs[@]}"
