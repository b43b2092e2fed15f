#!/usr/bin/env bash
# What the Rerun recording costs a run: the same frames tracked with and without
# --rerun, runs interleaved (default real-time mode, the real detector, no dense
# pass), the median tracking time per frame and the wall time of each, and the
# recording's size per 1000 frames at the default image scale.
#
#   tools/bench_rerun.sh [PRESET] [FRAMES] [REPEATS]
#   (default: configs/synth/demo.toml, the bundled demo room with two real people,
#   300 frames, 3 runs each)
set -euo pipefail
cd "$(dirname "$0")/.."
preset=${1:-configs/synth/demo.toml}
frames=${2:-300}
repeats=${3:-3}
command -v dopslam >/dev/null 2>&1 || export PATH="$HOME/.cargo/bin:$PATH"
work=$(mktemp -d "${TMPDIR:-/tmp}/bench-rerun.XXXXXX")
trap 'rm -rf "$work"' EXIT
dopslam synth --config "$preset" --out "$work/seq" --frames "$frames" >/dev/null
median_ms() { python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['totals']['median_tracking_ms'])" "$1"; }
printf '%-8s %-4s %12s %10s %12s\n' mode run median_ms wall_s rrd_MiB_per_1000
for run in $(seq 1 "$repeats"); do
    for mode in off rerun; do
        out="$work/$mode-$run"
        extra=()
        [ "$mode" = rerun ] && extra=(--rerun "$out.rrd")
        start=$EPOCHREALTIME
        dopslam run "$work/seq" --out "$out" --no-dense "${extra[@]}" >/dev/null 2>"$out.log"
        wall=$(python3 -c "import sys; print(float(sys.argv[2]) - float(sys.argv[1]))" "$start" "$EPOCHREALTIME")
        size=-
        if [ "$mode" = rerun ]; then
            size=$(python3 -c "import os,sys; print(f'{os.path.getsize(sys.argv[1]) / 2**20 * 1000 / int(sys.argv[2]):.1f}')" "$out.rrd" "$frames")
            grep -h "dropped" "$out.log" || true
        fi
        printf '%-8s %-4s %12.2f %10.1f %12s\n' "$mode" "$run" "$(median_ms "$out/report.json")" "$wall" "$size"
    done
done
