#!/usr/bin/env bash
# Benchmark helper (not a test): the safety net of a refactor. Runs dopslam
# --deterministic on the demo and five presets, a stereo street among them (150
# frames, real detector, dense pass), and on the real KITTI clips of
# $DOPSLAM_SHARED_DATA/real/kitti (default ../shared/data; said when absent) with
# ORB-SLAM2's settings files, and prints one hash per output file; JSON reports are hashed without their
# timing and memory fields and with the output folder's path replaced, so two builds
# that compute the same thing print the same lines (from any checkout: its path is
# replaced too).
#
#   bash tools/determinism_hashes.sh [BIN] > hashes.txt   # BIN default ./target/release/dopslam
#   diff before.txt after.txt                              # empty: byte-identical outputs
set -euo pipefail
cd "$(dirname "$0")/.."
bin=$(realpath "${1:-./target/release/dopslam}")
work=outputs/determinism
mkdir -p "$work"
for preset in demo demo_walking cutout_xyz cutout_halfsphere loop_room street_demo; do
  seq=$work/seq-$preset
  [ -f "$seq/rgb.txt" ] || "$bin" synth --config "configs/synth/$preset.toml" --out "$seq" --frames 150 --force >/dev/null 2>&1
  [ -d "$seq/kitti/sequences/00" ] && seq=$seq/kitti/sequences/00  # a stereo preset
  out=$work/run-$preset
  rm -rf "$out"
  extra=()
  [ "$preset" = demo ] && extra=(--config configs/run/demo.toml)
  "$bin" run "$seq" "${extra[@]}" --deterministic --out "$out" >"$work/$preset.log" 2>&1 || echo "run $preset failed (see $work/$preset.log)" >&2
done
kitti=${DOPSLAM_SHARED_DATA:-../shared/data}/real/kitti
if [ -d "$kitti/sequences" ]; then
  for clip in 01 06; do
    [ -d "$kitti/sequences/$clip" ] || continue
    settings=configs/calibration/Stereo_KITTI04-12.yaml
    [ "$clip" = 01 ] && settings=configs/calibration/Stereo_KITTI00-02.yaml
    out=$work/run-kitti-$clip
    rm -rf "$out"
    "$bin" run "$kitti/sequences/$clip" --settings "$settings" --deterministic --out "$out" \
      >"$work/kitti-$clip.log" 2>&1 || echo "run kitti $clip failed (see $work/kitti-$clip.log)" >&2
  done
else
  echo "no real KITTI clips at $kitti: only the presets are hashed" >&2
fi
python3 - "$work" <<'PY'
import hashlib, json, os, re, sys
root = sys.argv[1]
# The checkout's own paths (its data folder: the detector's files) are not the run's.
repo = os.path.abspath(".")
timing = re.compile(r"(_ms$|^ms$|_s$|milliseconds|memory|seconds|^time|_time|elapsed|mib)")
def strip(v):
    if isinstance(v, dict):
        return {k: strip(x) for k, x in v.items() if not timing.search(k)}
    if isinstance(v, list):
        return [strip(x) for x in v]
    if isinstance(v, str):
        return v.replace(os.path.abspath(root), "ROOT").replace(root, "ROOT").replace(repo, "REPO")
    return v
for folder in sorted(d for d in os.listdir(root) if d.startswith("run-")):
    for dirpath, dirs, files in sorted(os.walk(os.path.join(root, folder))):
        dirs.sort()
        for name in sorted(files):
            if name.endswith(".rrd"):
                continue  # a Rerun recording holds its own ids and wall-clock times
            path = os.path.join(dirpath, name)
            data = open(path, "rb").read()
            if name.endswith(".json"):
                data = json.dumps(strip(json.loads(data)), sort_keys=True).encode()
            elif name == "detector.txt":
                data = data.replace(repo.encode(), b"REPO")
            print(hashlib.sha256(data).hexdigest()[:16], os.path.relpath(path, root))
PY
