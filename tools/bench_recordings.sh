#!/usr/bin/env bash
# Benchmark (not a test): is reading a recording ever the bottleneck? One `dopslam synth`
# sequence (640x480 RGB-D) written by the rosbags package as a ROS 1 bag (uncompressed
# and lz4), a ROS 2 MCAP bag and a ROS 2 SQLite bag; each read whole on one core by
# `dopslam info --read-frames` (frames/s, peak memory), beside the TUM folder reader and
# the Python rosbags reader (AnyReader, every colour and depth message deserialised
# into a numpy image) on the same files; and the tracking rate of the same sequence
# (`dopslam run --no-dense`, median tracking time per frame). Also rosbag2's message
# compression, a bag split in three, and Azure Kinect .mkv files (BGRA and MJPEG colour,
# depth registered on reading) of the same room. Then a recording REPEAT times as long
# (the frames written again with new stamps) read with the same peak memory
# (streaming; --repeat 1 leaves it out). Writes rows.jsonl and table.md under OUT.
#
#   bash tools/bench_recordings.sh [--frames N] [--repeat K] [--out DIR]
#   DOPSLAM_TEST_PYTHON=/path/to/python  (with rosbags, numpy, pillow; default data/venv)
#   DOPSLAM_BIN=/path/to/dopslam  (another build, for a before/after pair; default
#   ./target/release/dopslam)
set -euo pipefail
cd "$(dirname "$0")/.."
frames=300
repeat=10
out=outputs/bench/recordings
while [ $# -gt 0 ]; do
  case "$1" in
    --frames) frames=$2; shift 2 ;;
    --repeat) repeat=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    *) echo "unknown option $1 (see the header of $0)" >&2; exit 2 ;;
  esac
done
py=${DOPSLAM_TEST_PYTHON:-data/venv/bin/python}
dopslam=${DOPSLAM_BIN:-./target/release/dopslam}
[ -x "$dopslam" ] || { echo "no $dopslam: build first (bash tools/setup.sh)" >&2; exit 1; }
mkdir -p "$out"
work=$(mktemp -d "${TMPDIR:-/tmp}/bench-recordings.XXXXXX")
trap 'rm -rf "$work"' EXIT
seq=$work/seq
$dopslam synth --config configs/synth/static_room.toml --frames "$frames" --out "$seq" >/dev/null
: > "$out/rows.jsonl"

# rate_of LABEL PATH: dopslam's read rate and peak memory, as a JSON row.
rate_of() {
  local line
  line=$($dopslam info "$2" --read-frames | tail -1)
  echo "$line" | awk -v label="$1" -v size="$(du -sm "$2" | cut -f1)" \
    '{ gsub(/[(,]/, ""); print "{\"reader\": \"dopslam\", \"input\": \"" label "\", \"frames\": " $2 ", \"seconds\": " $5 ", \"fps\": " $7 ", \"peak_mib\": " $13 ", \"mib\": " size "}" }' \
    | tee -a "$out/rows.jsonl"
}

# python_rate LABEL PATH: the rosbags reader on the same file.
python_rate() {
  "$py" - "$1" "$2" <<'EOF' | tee -a "$out/rows.jsonl"
import json, sys, time
import numpy as np
from pathlib import Path
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
label, path = sys.argv[1], Path(sys.argv[2])
start = time.perf_counter()
images = 0
with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
    wanted = [c for c in reader.connections if c.msgtype.endswith('/Image')]
    for connection, _, raw in reader.messages(connections=wanted):
        msg = reader.deserialize(raw, connection.msgtype)
        dtype = np.float32 if msg.encoding == '32FC1' else np.uint8
        np.frombuffer(msg.data, dtype).reshape(msg.height, -1).copy()
        images += 1
seconds = time.perf_counter() - start
print(json.dumps({"reader": "rosbags", "input": label, "frames": images // 2, "seconds": round(seconds, 3),
                  "fps": round(images / 2 / seconds, 1)}))
EOF
}

# bytes_rate LABEL PATH FRAMES: the file's bytes alone (every file under PATH read from the
# page cache into one reused 1 MiB buffer, nothing decoded), in frames/s: the bound for
# any reader that reads the recording's bytes.
bytes_rate() {
  "$py" - "$1" "$2" "$3" <<'EOF' | tee -a "$out/rows.jsonl"
import json, sys, time
from pathlib import Path
label, path, frames = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
files = sorted(p for p in ([path] if path.is_file() else path.rglob('*')) if p.is_file())
buf = bytearray(1 << 20)
for p in files:  # into the page cache first, as the readers find them
    with open(p, 'rb') as f:
        while f.readinto(buf):
            pass
start = time.perf_counter()
for p in files:
    with open(p, 'rb') as f:
        while f.readinto(buf):
            pass
seconds = time.perf_counter() - start
print(json.dumps({"reader": "bytes", "input": label, "fps": round(frames / seconds, 1)}))
EOF
}

rate_of folder "$seq"
bytes_rate folder "$seq" "$frames"
for variant in "ros1:--format ros1" "ros1-lz4:--format ros1 --compression lz4" \
               "ros2-mcap:--format ros2-mcap" "ros2-sqlite:--format ros2-sqlite" \
               "ros2-mcap-zstd-message:--format ros2-mcap --compression zstd-message" \
               "ros2-sqlite-split-3:--format ros2-sqlite --split 3"; do
  label=${variant%%:*}
  target=$work/$label
  case $label in ros1*) target=$target.bag ;; esac
  # shellcheck disable=SC2086
  "$py" tools/write_recording.py "$seq" "$target" ${variant#*:} 2>/dev/null
  rate_of "$label" "$target"
  bytes_rate "$label" "$target" "$frames"
  python_rate "$label" "$target"
done

# Azure Kinect recordings of the same room (depth rendered by its own 640x576 camera,
# 32 mm beside the colour one, registered on reading; ffmpeg muxes them).
if command -v ffmpeg >/dev/null 2>&1; then
  { cat configs/synth/static_room.toml
    printf '\n[depth_camera]\noffset = [0.032, 0.002, 0.004]\n[depth_camera.camera]\n'
    printf 'fx = 504.0\nfy = 504.5\ncx = 321.5\ncy = 330.0\nwidth = 640\nheight = 576\n'; } > "$work/kinect.toml"
  $dopslam synth --config "$work/kinect.toml" --frames "$frames" --out "$work/kinect-seq" >/dev/null
  for colour in bgra mjpeg; do
    "$py" tools/write_kinect.py "$work/kinect-seq" "$work/kinect-$colour.mkv" --colour "$colour" 2>/dev/null
    rate_of "azure-kinect-$colour" "$work/kinect-$colour.mkv"
    bytes_rate "azure-kinect-$colour" "$work/kinect-$colour.mkv" "$frames"
  done
  rm -rf "$work/kinect-seq"
else
  echo "no ffmpeg: the Azure Kinect rows are left out" >&2
fi

# The tracking rate of the same frames (no detector: the fastest the tracker goes).
$dopslam run "$seq" --no-dense --no-global --detections none --out "$work/run" > "$work/run.log" 2>&1
grep -o "median [0-9.]* ms" "$work/run.log" | head -1 | awk '{ print "{\"reader\": \"tracking\", \"ms\": " $2 ", \"fps\": " 1000 / $2 "}" }' \
  | tee -a "$out/rows.jsonl"

# A recording REPEAT times as long: the same peak memory when reading streams.
[ "$repeat" -gt 1 ] || { echo "--repeat 1: the long recordings are left out" >&2; skip_long=1; }
[ -n "${skip_long:-}" ] || {
"$py" tools/write_recording.py "$seq" "$work/long" --format ros2-mcap --repeat "$repeat" 2>/dev/null
rate_of "ros2-mcap-x$repeat" "$work/long"
rm -rf "$work/long"
"$py" tools/write_recording.py "$seq" "$work/long.bag" --format ros1 --repeat "$repeat" 2>/dev/null
rate_of "ros1-x$repeat" "$work/long.bag"
}

"$py" - "$out" <<'EOF'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
rows = [json.loads(l) for l in (out / 'rows.jsonl').read_text().splitlines() if l.strip()]
track = next((r for r in rows if r['reader'] == 'tracking'), None)
lines = ['| input | MiB | frames | dopslam frames/s | peak MiB | rosbags frames/s | dopslam / rosbags | dopslam / tracking | file bytes alone frames/s |',
         '|---|---|---|---|---|---|---|---|---|']
for r in rows:
    if r['reader'] != 'dopslam':
        continue
    py = next((p for p in rows if p['reader'] == 'rosbags' and p['input'] == r['input']), None)
    raw = next((p for p in rows if p['reader'] == 'bytes' and p['input'] == r['input']), None)
    lines.append('| {} | {} | {} | {:.0f} | {} | {} | {} | {} | {} |'.format(
        r['input'], r['mib'], r['frames'], r['fps'], r['peak_mib'],
        f"{py['fps']:.0f}" if py else '', f"{r['fps'] / py['fps']:.1f}x" if py else '',
        f"{r['fps'] / track['fps']:.1f}x" if track else '', f"{raw['fps']:.0f}" if raw else ''))
if track:
    lines.append(f"\nTracking (no detector, --no-dense): median {track['ms']} ms a frame, {track['fps']:.0f} frames/s.")
(out / 'table.md').write_text('\n'.join(lines) + '\n')
print('\n'.join(lines))
EOF
