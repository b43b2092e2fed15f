#!/usr/bin/env bash
# Benchmark (not a test): people the detector misses or finds late. On the cut-out
# presets (real people, gait, close passes; configs/synth/cutout_*.toml) runs
# `dopslam run` in several variants and prints one markdown row per preset and variant
# with tools/people_metrics.py: ATE RMSE, one-frame RPE 95th percentile, path length
# over the true one, keyframes per frame, person recall on keyframes, the dynamic
# state's recall and precision against the masks, median tracking time.
#
#   bash tools/bench_people.sh [--seeds N] [--variants "dop-onnx-rt no-dop ..."] [PRESET ...]
#
# Variants (-rt: the default real-time mode, else --deterministic):
#   dop-onnx, dop-onnx-rt      DOP with the installed detector (the headline)
#   no-dop                     ORB-SLAM2 behaviour
#   mask-boxes-onnx            the naive method with the installed detector
#   dop-oracle, dop-oracle-rt  DOP with boxes from the true masks (upper bound; real
#                              time with the simulated detector latency)
#   dop-onnx-nogeo             DOP with the detector, geometric check off
#   geo-only                   no detector: the geometric check alone
#   dop-onnx-notrack           DOP with the detector, no object tracks
#   dop-onnx-t03               DOP with the detector at the old score threshold 0.3
#   dop-onnx-416, dop-onnx-416-rt   DOP with YOLOv4-tiny at its cfg's 416x416 (the
#                              default before 320x256)
#   dop-onnx-multi, dop-onnx-multi-rt   DOP with YOLOv4-tiny at 320x256 and 416x416,
#                              boxes merged (multi-scale)
#   dop-deim, dop-deim-rt      DOP with DEIMv2-femto (its threshold 0.3)
#   dop-pool, dop-pool-rt      DOP with YOLOv4-tiny (0.10) and DEIMv2-femto (0.30) pooled,
#                              one class-wise NMS
# Sequences are generated once into outputs/bench/ (seeds 1001, 1002, ... for N > 1).
set -euo pipefail
# DOPSLAM_BIN: the binary measured (default ./target/release/dopslam), e.g. a copy of an
# older build for a before/after comparison.
bin=${DOPSLAM_BIN:-./target/release/dopslam}
cd "$(dirname "$0")/.."
seeds=1
variants="dop-onnx dop-onnx-rt no-dop mask-boxes-onnx dop-oracle"
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2 ;;
    --variants) variants=$2; shift 2 ;;
    *) break ;;
  esac
done
presets=("$@")
if [ ${#presets[@]} -eq 0 ]; then
  presets=(cutout_xyz cutout_static cutout_rpy cutout_halfsphere cutout_seated_leaves)
fi
[ -n "${DOPSLAM_BIN:-}" ] || cargo build --release --quiet
mkdir -p outputs/bench
nogeo=outputs/bench/config-nogeo.toml
notrack=outputs/bench/config-notrack.toml
printf '[dop]\ngeometric = false\n' > "$nogeo"
printf '[dop]\ntrack_boxes = false\n' > "$notrack"
t03=outputs/bench/config-t03.toml
printf '[detector]\nscore_threshold = 0.3\n' > "$t03"
m416=outputs/bench/config-416.toml
printf '[detector]\nmodel_path = "%s/data/models/yolov4-tiny.onnx"\n' "$PWD" > "$m416"
multi=outputs/bench/config-multi.toml
printf '[detector]\nmodel_paths = ["%s/data/models/yolov4-tiny-320x256.onnx", "%s/data/models/yolov4-tiny.onnx"]\n' "$PWD" "$PWD" > "$multi"
deim=outputs/bench/config-deim.toml
printf '[detector]\nmodel = "deimv2-femto"\n' > "$deim"
pool=outputs/bench/config-pool.toml
printf '[[detector.pool]]\nmodel = "yolov4-tiny"\nscore_threshold = 0.1\n[[detector.pool]]\nmodel = "deimv2-femto"\nscore_threshold = 0.3\n' > "$pool"
echo "| preset | seed | variant | ATE RMSE (m) | RPE 1 frame p95 (m) | path / true | keyframes / frames | person recall | state recall / precision | median ms |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for preset in "${presets[@]}"; do
  for ((s = 1; s <= seeds; s++)); do
    seq=outputs/bench/$preset
    seed_args=()
    seed=own
    if [ "$s" -gt 1 ]; then
      seed=$((1000 + s - 1))
      seq=outputs/bench/$preset-seed$seed
      seed_args=(--seed "$seed")
    fi
    if [ ! -f "$seq/rgb.txt" ]; then
      "$bin" synth --config "configs/synth/$preset.toml" "${seed_args[@]}" --out "$seq" --force >/dev/null
    fi
    for variant in $variants; do
      args=()
      case "$variant" in
        *-rt) ;;
        *) args+=(--deterministic) ;;
      esac
      case "${variant%-rt}" in
        dop-onnx) args+=(--dop --detections onnx) ;;
        no-dop) args+=(--no-dop --detections none) ;;
        mask-boxes-onnx) args+=(--mask-boxes --detections onnx) ;;
        dop-oracle) args+=(--dop --detections oracle) ;;
        dop-onnx-nogeo) args+=(--dop --detections onnx --config "$nogeo") ;;
        dop-onnx-notrack) args+=(--dop --detections onnx --config "$notrack") ;;
        dop-onnx-t03) args+=(--dop --detections onnx --config "$t03") ;;
        dop-onnx-416) args+=(--dop --detections onnx --config "$m416") ;;
        dop-onnx-multi) args+=(--dop --detections onnx --config "$multi") ;;
        dop-deim) args+=(--dop --detections onnx --config "$deim") ;;
        dop-pool) args+=(--dop --detections onnx --config "$pool") ;;
        geo-only) args+=(--dop --detections none) ;;
        *) echo "unknown variant $variant" >&2; exit 2 ;;
      esac
      out=outputs/bench/people-$(basename "$seq")-$variant
      rm -rf "$out"
      if ! "$bin" run "$seq" --out "$out" --no-dense "${args[@]}" >"$out.log" 2>&1; then
        echo "| $preset | $seed | $variant | failed: see $out.log |"
        continue
      fi
      python3 - "$preset" "$seed" "$variant" "$out" "$seq" <<'PY'
import json, subprocess, sys
preset, seed, variant, out, seq = sys.argv[1:]
m = json.loads(subprocess.check_output(["python3", "tools/people_metrics.py", out, seq, "--json"]))
f = lambda v, p=4: "-" if v is None else f"{v:.{p}f}"
print(f"| {preset} | {seed} | {variant} | {f(m['ate_rmse'])} | {f(m['rpe1_p95'])} | {f(m['path_ratio'], 2)} | "
      f"{m['keyframes']} ({100 * m['keyframe_share']:.0f} %) | {f(m['person_recall'], 3)} | "
      f"{f(m['state_recall'], 3)} / {f(m['state_precision'], 3)} | {m['median_ms']:.1f} |", flush=True)
PY
    done
  done
done
