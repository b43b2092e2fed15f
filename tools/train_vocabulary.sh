#!/usr/bin/env bash
# Trains the default place-recognition vocabulary shipped as data/vocabulary.dbow
# (k = 10, L = 4, about 10^4 words, 0.44 MB): ORB descriptors of 300 frames each of
# three generated presets (walking_xyz, fr2_desk_room, static_room; none of the loop
# presets it is then tested on) and the real single frames in ../shared/data/frames
# (TUM, KITTI, photos) when present. Deterministic (seeded k-means++).
#
#   bash tools/train_vocabulary.sh [OUT]   # default data/vocabulary.dbow
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-data/vocabulary.dbow}
bin=target/release/dopslam
[ -x "$bin" ] || cargo build --release
inputs=()
for preset in walking_xyz fr2_desk_room static_room; do
    dir=outputs/seq/vocab_$preset
    [ -d "$dir/rgb" ] || "$bin" synth --config "configs/synth/$preset.toml" --out "$dir" --frames 300 --force
    inputs+=("$dir/rgb")
done
if [ -d ../shared/data/frames ]; then
    inputs+=(../shared/data/frames)
else
    echo "note: ../shared/data/frames absent: training on generated frames only" >&2
fi
"$bin" vocab train "${inputs[@]}" --out "$out" --max-images 1000
