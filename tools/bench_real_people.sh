#!/usr/bin/env bash
# Benchmark (not a test): the dense map on the real recording of people walking before a
# static camera (`../shared/data/real/ist/confusao`; issue 80's real-people goals).
# Writes the recording's per-pixel mover truth once (tools/static_camera_truth.py, into
# OUT/truth, links to the recording), then runs `dopslam run` on it (dense on, real
# detector, default real-time mode) RUNS times with each build, and one `--no-dop` run
# as the unmasked reference. Per run: the masks against the truth (`dense.json`
# `truth`: pixels masked within range, static fused, movers kept out), the mesh's
# vertices more than 15 cm in front of each pixel's far end and of its 95th percentile
# (and of those the rare ones, seen at their depth in under half of the frames with
# depth there: a mover's ghost; a chair leg whose depth flickers to the floor behind it
# is seen there in most), and the share of the background within 4 m its surface
# covers (tools/static_camera_ghosts.py); one row a run and the medians a build.
# Two reference rows come last: the recording with the truth's movers cleared from its
# depth (static_camera_truth.py --without-movers) run without DOP and with it, judged
# against the same background: what a perfect mask would leave, so the floor of each
# figure (a static chair leg whose depth flickers to the floor lies in front of its
# pixel's far end in every map).
#
#   bash tools/bench_real_people.sh [--runs 3] [--bin B] [--base-bin B] [--out DIR]
#       [--sequence DIR] [--settings S.yaml]
#
# Needs numpy and Pillow in data/venv (tools/test.sh installs them).
set -euo pipefail
cd "$(dirname "$0")/.."
runs=3
bin=$PWD/target/release/dopslam
base=
out=outputs/bench/real_people
sequence=../shared/data/real/ist/confusao
settings=../shared/data/calibration/RGB-D_IST_Xtion.yaml
while [ $# -gt 0 ]; do
  case $1 in
    --runs) runs=$2; shift 2 ;;
    --bin) bin=$(realpath "$2"); shift 2 ;;
    --base-bin) base=$(realpath "$2"); shift 2 ;;
    --out) out=$2; shift 2 ;;
    --sequence) sequence=$2; shift 2 ;;
    --settings) settings=$2; shift 2 ;;
    -h|--help) sed -n '2,23p' "$0"; exit 0 ;;
    *) echo "bench_real_people.sh: unknown argument $1 (--help)" >&2; exit 2 ;;
  esac
done
python=data/venv/bin/python
[ -x "$bin" ] || { echo "bench_real_people.sh: no dopslam at $bin (cargo build --release)" >&2; exit 2; }
[ -z "$base" ] || [ -x "$base" ] || { echo "bench_real_people.sh: no dopslam at $base" >&2; exit 2; }
[ -f "$sequence/depth.txt" ] || { echo "bench_real_people.sh: $sequence is not a TUM-layout recording (no depth.txt)" >&2; exit 2; }
[ -f "$settings" ] || { echo "bench_real_people.sh: no settings file $settings" >&2; exit 2; }
"$python" -c "import numpy, PIL" 2>/dev/null \
  || { echo "bench_real_people.sh: $python cannot import numpy and PIL (bash tools/test.sh installs them)" >&2; exit 2; }
# The output folder is this script's own: a new one, or one it made before (marked),
# whose earlier runs it replaces; it never clears a folder it did not make.
if [ -d "$out" ] && [ -n "$(ls -A "$out")" ] && [ ! -f "$out/.bench_real_people" ]; then
  echo "bench_real_people.sh: $out holds files this script did not write; name a new --out" >&2
  exit 2
fi
mkdir -p "$out"
touch "$out/.bench_real_people"
sequence=$(realpath "$sequence")
settings=$(realpath "$settings")
# The truth is written once a recording: kept with what made it, never reused for another.
made="$sequence $settings"
if [ -d "$out/truth" ] && [ "$(cat "$out/truth.source" 2>/dev/null)" != "$made" ]; then
  echo "bench_real_people.sh: $out/truth was made from another recording or settings; name a new --out" >&2
  exit 2
fi
if [ ! -d "$out/truth" ] || [ ! -d "$out/without_movers" ]; then
  rm -rf "$out/truth" "$out/without_movers"
  "$python" tools/static_camera_truth.py "$sequence" "$out/truth" --settings "$settings" \
    --without-movers "$out/without_movers"
  echo "$made" >"$out/truth.source"
fi
rows=$out/rows.tsv
: >"$rows"
builds=(this)
[ -z "$base" ] || builds+=(base)
judge() { # judge NAME BUILD RUN DIR: one row
  local name=$1 build=$2 run=$3 dir=$4
  "$python" tools/static_camera_ghosts.py "$sequence" "$dir" --settings "$settings" --json >"$dir.far.json"
  "$python" tools/static_camera_ghosts.py "$sequence" "$dir" --settings "$settings" --percentile 95 --json >"$dir.p95.json"
  python3 - "$dir" "$name" "$build" "$run" >>"$rows" <<'PY'
import json, sys
d, name, build, run = sys.argv[1:]
dense = json.load(open(f"{d}/dense.json"))
truth = dense["truth"]
far = next(iter(json.load(open(f"{d}.far.json")).values()))
p95 = next(iter(json.load(open(f"{d}.p95.json")).values()))
print("\t".join([name, build, run, f"{dense['masked_fusable_percent']:.1f}", f"{truth['static_kept']:.4f}",
                 f"{truth['dynamic_removed']:.4f}", str(far["in_front"]), f"{far['in_front_percent']:.3f}",
                 str(far["in_front_rare"]), str(p95["in_front"]), str(p95["in_front_rare"]),
                 f"{far['surface_covered_percent']:.1f}", f"{dense['total_s']:.1f}"]))
PY
}
for r in $(seq 1 "$runs"); do
  for build in "${builds[@]}"; do
    exe=$bin; [ "$build" = base ] && exe=$base
    dir=$out/$build-$r
    rm -rf "$dir"
    "$exe" run "$out/truth" --settings "$settings" --out "$dir" >"$dir.log" 2>&1 \
      || { echo "run failed: $dir.log" >&2; tail -3 "$dir.log" >&2; exit 1; }
    judge dop "$build" "$r" "$dir"
  done
done
reference() { # reference NAME RECORDING [ARGS]: one run of this build, one row
  local name=$1 recording=$2
  shift 2
  rm -rf "${out:?}/$name"
  "$bin" run "$recording" --settings "$settings" "$@" --out "$out/$name" >"$out/$name.log" 2>&1 \
    || { echo "run failed: $out/$name.log" >&2; tail -3 "$out/$name.log" >&2; exit 1; }
  judge "$name" this 1 "$out/$name"
}
reference no_dop "$out/truth" --no-dop
reference no_movers_no_dop "$out/without_movers" --no-dop
reference no_movers_dop "$out/without_movers"
python3 - "$rows" <<'PY'
import statistics, sys
rows = [line.rstrip("\n").split("\t") for line in open(sys.argv[1])]
head = ["map", "build", "run", "masked in range %", "static fused", "movers kept out",
        "vertices in front of the far end", "%", "of them rare", "in front of the 95th pct", "of them rare",
        "surface covered %", "dense s"]
print("| " + " | ".join(head) + " |")
print("|" + "---|" * len(head))
for r in rows:
    print("| " + " | ".join(r) + " |")
for key in sorted({(r[0], r[1]) for r in rows}):
    group = [r for r in rows if (r[0], r[1]) == key]
    if len(group) > 1:
        med = [f"{statistics.median(float(r[k]) for r in group):g}" for k in range(3, len(head))]
        print("| " + " | ".join([key[0], key[1], "median"] + med) + " |")
PY
