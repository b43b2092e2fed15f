#!/usr/bin/env bash
# Benchmark (not a test): frames per second of `dopslam synth` at 640x480 on this
# machine, on a whole walking_xyz sequence (827 frames at the real fr3 timing).
#
#   bash tools/bench_synth.sh [PRESET] [FRAMES]
set -euo pipefail
cd "$(dirname "$0")/.."
preset=${1:-walking_xyz}
frames=${2:-827}
cargo build --release --quiet
out=$(mktemp -d)
./target/release/dopslam synth --config "configs/synth/$preset.toml" --out "$out/seq" --frames "$frames"
echo "cores: $(nproc); output $(du -sh "$out/seq" | cut -f1)"
rm -rf "$out"
