#!/usr/bin/env bash
# Benchmark (not a test): the keyframe detectors on the synthetic people_from_photos
# preset (real people cut out of a TUM frame, composited into a rendered room).
#   bash tools/bench_detect.sh [EVERY]
# Runs `dopslam detect` with YOLOv4-tiny (data/models) and YOLOX-nano
# (../shared/models) on every EVERY-th frame (default 10) and prints, per model, the
# recall of the oracle person boxes (a detection of class person with IoU >= 0.5) and
# the median inference time per image on this machine.
set -euo pipefail
cd "$(dirname "$0")/.."
every=${1:-10}
cargo build --release --quiet
seq=outputs/bench/people_from_photos
if [ ! -f "$seq/rgb.txt" ]; then
  ./target/release/dopslam synth --config configs/synth/people_from_photos.toml --out "$seq" --force >/dev/null
fi
echo "cores: $(nproc)"
for model in yolov4-tiny yolox-nano; do
  extra=()
  [ "$model" = yolox-nano ] && extra=(--model-path ../shared/models/yolox_nano.onnx)
  out=outputs/bench/detect-$model
  rm -rf "$out"
  ./target/release/dopslam detect "$seq" --model "$model" "${extra[@]}" --every "$every" --out "$out" > "$out.log"
  python3 - "$model" "$seq/detections_oracle" "$out/detections" "$out.log" <<'PY'
import json, os, re, statistics, sys
model, oracle_dir, found_dir, log = sys.argv[1:]
def iou(a, b):
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0])); h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    u = (a[2]-a[0])*(a[3]-a[1]) + (b[2]-b[0])*(b[3]-b[1]) - w*h
    return w*h/u if u > 0 else 0.0
hits = total = 0
for name in sorted(os.listdir(found_dir)):
    truth = [d["box"] for d in json.load(open(os.path.join(oracle_dir, name)))["detections"] if d["class"] == "person"]
    found = [d["box"] for d in json.load(open(os.path.join(found_dir, name)))["detections"] if d["class"] == "person"]
    total += len(truth)
    hits += sum(1 for t in truth if any(iou(t, f) >= 0.5 for f in found))
times = [float(m) for m in re.findall(r"\(([0-9.]+) ms\)", open(log).read())]
print(f"{model:12s} frames {len(times):4d}  person recall {hits}/{total} = {100*hits/max(total,1):5.1f} %  "
      f"median inference {statistics.median(times):6.1f} ms")
PY
done
