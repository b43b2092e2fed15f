#!/usr/bin/env bash
# Benchmark (not a test): the two real KITTI stereo clips of ../shared/data/real/kitti
# (frames 0-50 of sequences 01 and 06, KITTI's ground truth), run as a user runs them:
# ORB-SLAM2's own settings files, the real detector, default real-time mode, --no-dense.
# Runs are interleaved (clip, then mode, then repetition) so that load on the machine
# falls on every mode alike. Prints per run and the medians: ATE RMSE (SE(3), as evo and
# the issue's table), ATE RMSE with Sim(3) alignment (what is left once the scale is
# forgiven), estimated path length / true, median tracking time per frame.
#
#   bash tools/bench_kitti.sh [--runs N] [--modes "dop no-dop"] [--extra] [--offset]
#                             [--decompose] [--paced] [--perturbed] [--out DIR]
#     --offset  each mode also without the rig's disparity offset ([global]
#               disparity_offset = false: neither found before tracking nor after)
#     --extra   also single runs of --dop --deterministic, --no-dop --deterministic,
#               --mask-boxes, and --dop with [stereo] bearing_baselines = 0 (before)
#     --decompose what DOP's real-time runs owe to what: each repetition also runs --dop
#               without a detector (--detections none: the model on geometry alone) and
#               --dop with the boxes of every frame read from a cache that `dopslam
#               detect` wrote once per clip (the same boxes at no CPU cost beside
#               tracking, answered after the cache's simulated latency), and --no-dop
#               with the detector running beside it ([detector] source = "onnx": its
#               CPU time without its boxes)
#     --paced   each mode also played at the recording's rate (--pace recording), as
#               ORB-SLAM2's stereo_kitti example plays KITTI (it waits for each frame's
#               time); the default plays frames as fast as the tracker goes
#     --perturbed each mode also --deterministic under 9 variants of the clip's settings
#               file (ORBextractor.nFeatures 1900/2000/2100 x iniThFAST 19/20/21): a
#               spread of runs without the threads' timing, each variant run by every
#               mode; such a mode stands against no-dop varied alike
# Runs of several script runs pool into one table (the spread between real-time runs is
# as large as the differences between modes: pool before you compare):
#   python3 tools/kitti_clip_figures.py table OUT1/runs.tsv OUT2/runs.tsv ...
# Under the table each mode stands against no-dop: the median difference with its 95 %
# bootstrap interval and the Mann-Whitney p; an interval that holds zero is no result.
#   DOPSLAM_SHARED_DATA=/path/to/shared/data   (default: ../shared/data)
#   DOPSLAM_BIN=/path/to/dopslam                (default: ./target/release/dopslam)
set -euo pipefail
cd "$(dirname "$0")/.."
runs=3
modes="dop no-dop"
extra=0
offset=0
decompose=0
paced=0
perturbed=0
out=outputs/bench/kitti
while [ $# -gt 0 ]; do
  case "$1" in
    --runs) runs=$2; shift 2 ;;
    --modes) modes=$2; shift 2 ;;
    --extra) extra=1; shift ;;
    --offset) offset=1; shift ;;
    --decompose) decompose=1; shift ;;
    --paced) paced=1; shift ;;
    --perturbed) perturbed=1; shift ;;
    --out) out=$2; shift 2 ;;
    *) echo "unknown option $1 (see the header of $0)" >&2; exit 2 ;;
  esac
done
data=${DOPSLAM_SHARED_DATA:-../shared/data}
kitti=$data/real/kitti
if [ ! -d "$kitti/sequences/01/image_0" ]; then
  echo "no real KITTI clips at $kitti (set DOPSLAM_SHARED_DATA)" >&2; exit 1
fi
cargo build --release --quiet
bin=${DOPSLAM_BIN:-./target/release/dopslam}
mkdir -p "$out/runs"
settings_of() { case $1 in 01) echo configs/calibration/Stereo_KITTI00-02.yaml ;; *) echo configs/calibration/Stereo_KITTI04-12.yaml ;; esac; }
printf '[stereo]\nbearing_baselines = 0.0\n' > "$out/bearings_off.toml"
printf '[global]\ndisparity_offset = false\n' > "$out/no_offset.toml"
printf '[detector]\nsource = "onnx"\n' > "$out/detector_on.toml"
# One run: clip, label, repetition, then dopslam's arguments. Appends a line to runs.tsv.
# The settings file: $orb_settings when set, else the clip's.
one() {
  local clip=$1 label=$2 rep=$3; shift 3
  local settings=${orb_settings:-$(settings_of "$clip")}
  local slug=${label//[^a-z0-9-]/_}
  local dir="$out/runs/$clip-$slug-r$rep"
  rm -rf "$dir"
  if ! "$bin" run "$kitti/sequences/$clip" --settings "$settings" --out "$dir" --no-dense "$@" >"$dir.log" 2>&1; then
    echo "$clip $label: dopslam run failed (see $dir.log)" >&2; return
  fi
  python3 tools/kitti_clip_figures.py run "$bin" "$kitti" "$clip" "$label" "$dir" >> "$out/runs.tsv"
}
rm -f "$out/runs.tsv"
echo "cores: $(nproc); $runs real-time run(s) of each mode, interleaved"
for clip in 01 06; do
  if [ "$decompose" = 1 ]; then
    rm -rf "$out/detect-$clip"
    "$bin" detect "$kitti/sequences/$clip" --out "$out/detect-$clip" > "$out/detect-$clip.log"
    printf '[detector]\nsource = "cache"\ncache_dir = "%s"\n' \
      "$(cd "$out" && pwd)/detect-$clip/detections" > "$out/cached_boxes-$clip.toml"
  fi
  for r in $(seq 1 "$runs"); do
    for mode in $modes; do
      one "$clip" "$mode" "$r" "--$mode"
      [ "$offset" = 0 ] || one "$clip" "$mode, no disparity offset" "$r" "--$mode" --config "$out/no_offset.toml"
      [ "$paced" = 0 ] || one "$clip" "$mode, paced as recorded" "$r" "--$mode" --pace recording
    done
    if [ "$decompose" = 1 ]; then
      one "$clip" "dop, no detector" "$r" --dop --detections none
      one "$clip" "dop, cached boxes" "$r" --dop --config "$out/cached_boxes-$clip.toml"
      one "$clip" "no-dop, detector running" "$r" --no-dop --config "$out/detector_on.toml"
    fi
  done
  if [ "$extra" = 1 ]; then
    one "$clip" "dop --deterministic" 1 --dop --deterministic
    one "$clip" "no-dop --deterministic" 1 --no-dop --deterministic
    one "$clip" "mask-boxes" 1 --mask-boxes
    one "$clip" "dop, bearing_baselines = 0 (before)" 1 --dop --config "$out/bearings_off.toml"
  fi
  if [ "$perturbed" = 1 ]; then
    for features in 1900 2000 2100; do
      for fast in 19 20 21; do
        varied="$out/settings-$clip-$features-$fast.yaml"
        sed -e "s/^ORBextractor.nFeatures:.*/ORBextractor.nFeatures: $features/" \
            -e "s/^ORBextractor.iniThFAST:.*/ORBextractor.iniThFAST: $fast/" \
            "$(settings_of "$clip")" > "$varied"
        grep -q "^ORBextractor.iniThFAST: $fast\$" "$varied" && grep -q "^ORBextractor.nFeatures: $features\$" "$varied" \
          || { echo "$(settings_of "$clip"): no ORBextractor.nFeatures/iniThFAST line to vary" >&2; exit 1; }
        for mode in $modes; do
          orb_settings=$varied one "$clip" "$mode, deterministic, settings varied" \
            "$features-$fast" "--$mode" --deterministic
        done
      done
    done
  fi
done
python3 tools/kitti_clip_figures.py table "$out/runs.tsv" | tee "$out/results.md"
echo "wrote $out/results.md (runs in $out/runs)"
