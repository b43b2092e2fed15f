#!/usr/bin/env bash
# Benchmark (not a test): `dopslam eval` against `evo_ape` on TUM fr2_desk
# (20957 ground-truth poses vs 2893 estimated), APE with SE(3) alignment, both
# tools' own defaults (evo: 0.01 s association). Prints the median of N runs each.
#
#   bash tools/bench_eval.sh [SHARED_DATA_DIR] [RUNS]
# evo is taken from $EVO_APE, else `evo_ape` on the PATH; without it only dopslam is timed.
set -euo pipefail
cd "$(dirname "$0")/.."
data=${1:-../shared/data}
runs=${2:-5}
gt="$data/trajectories/fr2_desk_groundtruth.txt"
est="$data/trajectories/fr2_desk_ORB.txt"
[ -f "$gt" ] || { echo "bench_eval: $gt not found (pass the shared data folder)"; exit 1; }
cargo build --release --quiet
median_time() {
    local times=()
    for _ in $(seq "$runs"); do
        local start end
        start=$(date +%s.%N)
        "$@" >/dev/null 2>&1
        end=$(date +%s.%N)
        times+=("$(echo "$end - $start" | bc -l)")
    done
    printf '%s\n' "${times[@]}" | sort -g | awk '{a[NR]=$1} END {m=(NR%2)?a[(NR+1)/2]:(a[NR/2]+a[NR/2+1])/2; printf "%.4f", m}'
}
ours=$(median_time ./target/release/dopslam eval "$gt" "$est" --rpe 1f)
echo "dopslam eval  (APE + RPE 1 frame): median ${ours} s over $runs runs"
evo=${EVO_APE:-$(command -v evo_ape || true)}
if [ -n "$evo" ]; then
    theirs=$(median_time "$evo" tum "$gt" "$est" -a)
    echo "evo_ape -a    (APE only):          median ${theirs} s over $runs runs"
    echo "speed-up: $(echo "$theirs / $ours" | bc -l | xargs printf '%.1f')x"
else
    echo "evo_ape not found: set EVO_APE or pip install evo==1.38.1 to compare"
fi
