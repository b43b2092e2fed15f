#!/usr/bin/env bash
# The project's benchmark (not a test): the micro-benchmarks (ORB extraction, TSDF
# integration, depth registration, evaluation: `cargo bench --bench micro`; pose graph, full BA, vocabulary:
# `cargo bench --bench global`) and the synthetic suite through `dopslam batch`
# (every preset, the three modes, five seeds: configs/batch/suite.toml; tracking time per
# frame, ATE, RPE, coverage per sequence and mode), checked against `dopslam eval` and
# evo (tools/check_batch.py), into one report with the machine and the date.
#
#   bash tools/bench.sh            # the whole suite: several hours on 2 cores
#   bash tools/bench.sh --quick    # configs/batch/quick.toml: about 10 minutes
#   bash tools/bench.sh --out DIR  # default outputs/bench/<date>[-quick]
# A re-run with the same --out resumes the batch where it stopped.
set -euo pipefail
cd "$(dirname "$0")/.."
quick=0
out=""
while [ $# -gt 0 ]; do
    case "$1" in
        --quick) quick=1; shift ;;
        --out) out=$2; shift 2 ;;
        *) echo "usage: bash tools/bench.sh [--quick] [--out DIR]" >&2; exit 2 ;;
    esac
done
manifest=configs/batch/suite.toml
suffix=""
if [ $quick = 1 ]; then manifest=configs/batch/quick.toml; suffix=-quick; fi
[ -n "$out" ] || out="outputs/bench/$(date +%Y-%m-%d)$suffix"
mkdir -p "$out"
say() { printf '\033[1m[bench]\033[0m %s\n' "$*" >&2; }

say "building"
source tools/system_packages.sh
cargo build --release --quiet "${CARGO_FEATURES[@]}"
say "micro-benchmarks (cargo bench --bench micro, --bench global)"
cargo bench --quiet --bench micro 2>/dev/null | grep ':' | tee "$out/micro.txt"
cargo bench --quiet --bench global 2>/dev/null | grep ':' | grep -v '^threads:' | tee "$out/global.txt"
say "synthetic suite: dopslam batch $manifest"
./target/release/dopslam batch "$manifest" --out "$out/batch" | tail -3
python=python3
[ -x data/venv/bin/python3 ] && python=data/venv/bin/python3
$python tools/check_batch.py "$out/batch" > "$out/check.txt" || say "check_batch found mismatches (see $out/check.txt)"
tail -1 "$out/check.txt" >&2

machine=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')
memory=$(awk '/MemTotal/ {printf "%.0f GiB", $2 / 1048576}' /proc/meminfo)
{
    echo "# dopslam benchmark$( [ $quick = 1 ] && echo ' (quick)')"
    echo
    echo "Date: $(date -u '+%Y-%m-%d %H:%M UTC'); commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')$(git diff --quiet 2>/dev/null || echo ' (with uncommitted changes)')"
    echo
    echo "Machine: ${machine:-$(uname -m)}, $(nproc) cores, $memory; $(uname -sr)"
    echo
    echo "## Micro-benchmarks"
    echo
    echo "| what | figure |"
    echo "|---|---|"
    sed -E 's/^([^:]*): (.*)$/| \1 | \2 |/' "$out/micro.txt" "$out/global.txt"
    echo
    echo "## Synthetic suite ($manifest)"
    echo
    sed '1,/^$/d' "$out/batch/results.md"
    echo
    echo "ATE check against dopslam eval and evo: $(tail -1 "$out/check.txt")"
    echo
    echo "Plots and map previews: $out/batch/report.html"
} > "$out/REPORT.md"
say "wrote $out/REPORT.md"
