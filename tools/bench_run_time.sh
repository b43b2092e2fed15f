#!/usr/bin/env bash
# Benchmark (not a test): the wall time of whole runs (`dopslam run`, dense pass on,
# real detector, default real-time mode), repeated, with each stage's time and
# real-time factor from report.json (`times.stages`) and the process's own wall time
# and peak memory (/usr/bin/time: loading the model and the vocabulary included).
# Prints one row a run and the medians a sequence. With --base-bin a second build
# runs each sequence too, interleaved with this one (run 1 of each, then run 2 ...),
# so that both meet the same machine load.
#
#   bash tools/bench_run_time.sh [--runs 3] [--bin B] [--base-bin B] [--out DIR]
#       SEQUENCE[::SETTINGS.yaml][::--frames N] ...
#
# SEQUENCE: any folder `dopslam run` reads; ::SETTINGS an ORB-SLAM2 settings file
# (KITTI: configs/calibration/Stereo_KITTI00-02.yaml for 00-02, Stereo_KITTI04-12.yaml
# for 04-12); a third part is passed to `dopslam run` as it is (e.g. `--frames 900`).
# Example, the issue 80 figures:
#   bash tools/bench_run_time.sh \
#     ../shared/data/real/kitti/sequences/01::configs/calibration/Stereo_KITTI00-02.yaml \
#     ../shared/data/real/kitti/sequences/06::configs/calibration/Stereo_KITTI04-12.yaml \
#     outputs/bench/desk_loop
set -euo pipefail
cd "$(dirname "$0")/.."
runs=3
bin=$PWD/target/release/dopslam
base=
out=outputs/bench/run_time
while [ $# -gt 0 ]; do
  case $1 in
    --runs) runs=$2; shift 2 ;;
    --bin) bin=$(realpath "$2"); shift 2 ;;
    --base-bin) base=$(realpath "$2"); shift 2 ;;
    --out) out=$2; shift 2 ;;
    -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
    *) break ;;
  esac
done
[ $# -gt 0 ] || { echo "bench_run_time.sh: name at least one sequence (--help)" >&2; exit 2; }
[ -x "$bin" ] || { echo "bench_run_time.sh: no dopslam at $bin (cargo build --release)" >&2; exit 2; }
[ -z "$base" ] || [ -x "$base" ] || { echo "bench_run_time.sh: no dopslam at $base" >&2; exit 2; }
[ -x /usr/bin/time ] || { echo "bench_run_time.sh: needs /usr/bin/time (apt-get install time)" >&2; exit 2; }
# The output folder is this script's own: a new one, or one it made before (marked),
# whose earlier runs it replaces; it never clears a folder it did not make.
if [ -d "$out" ] && [ -n "$(ls -A "$out")" ] && [ ! -f "$out/.bench_run_time" ]; then
  echo "bench_run_time.sh: $out holds files this script did not write; name a new --out" >&2
  exit 2
fi
mkdir -p "$out"
touch "$out/.bench_run_time"
rows=$out/rows.tsv
: >"$rows"
builds=(this)
[ -z "$base" ] || builds+=(base)
for spec in "$@"; do
  folder=${spec%%::*}
  rest=${spec#"$folder"}
  settings=$(echo "$rest" | awk -F'::' '{print $2}')
  extra=$(echo "$rest" | awk -F'::' '{print $3}')
  [ -d "$folder" ] || { echo "bench_run_time.sh: $folder is not a folder" >&2; exit 2; }
  args=()
  [ -z "$settings" ] || args+=(--settings "$(realpath "$settings")")
  # shellcheck disable=SC2206  # the extra arguments are words on purpose
  [ -z "$extra" ] || args+=($extra)
  name=$(basename "$folder")
  for r in $(seq 1 "$runs"); do
    for build in "${builds[@]}"; do
      exe=$bin; [ "$build" = base ] && exe=$base
      dir=$out/$name-$build-$r
      rm -rf "$dir"
      /usr/bin/time -f '%e %M' -o "$out/time.txt" "$exe" run "$(realpath "$folder")" "${args[@]}" \
        --out "$dir" >"$dir.log" 2>&1 || { echo "run failed: $dir.log" >&2; tail -3 "$dir.log" >&2; exit 1; }
      read -r wall kb <"$out/time.txt"
      python3 - "$dir/report.json" "$name" "$build" "$r" "$wall" "$kb" >>"$rows" <<'PY'
import json, sys
path, name, build, run, wall, kb = sys.argv[1:]
times = json.load(open(path))["times"]
stage = {s["stage"]: s["seconds"] for s in times["stages"]}
print("\t".join([name, build, run, wall, f"{int(kb) / 1024:.0f}", f"{times['recording_s']:.1f}",
                 f"{times['total_s']:.1f}", f"{times['real_time_factor']:.2f}"]
                + [f"{stage.get(s, 0.0):.1f}" for s in ("tracking", "global", "dense")]))
PY
      tail -1 "$rows"
    done
  done
done
python3 - "$rows" <<'PY'
import statistics, sys
rows = [line.rstrip("\n").split("\t") for line in open(sys.argv[1]) if line.strip()]
head = ["sequence", "build", "runs", "process s", "peak MiB", "recording s", "run s",
        "real-time factor", "tracking s", "global s", "dense s", "dense / tracking"]
print("\nmedians")
print("| " + " | ".join(head) + " |")
print("|" + "---|" * len(head))
for key in dict.fromkeys((r[0], r[1]) for r in rows):
    group = [r for r in rows if (r[0], r[1]) == key]
    med = [statistics.median(float(r[i]) for r in group) for i in range(3, 11)]
    ratio = statistics.median(float(r[10]) / max(float(r[8]), 1e-9) for r in group)
    print("| " + " | ".join([key[0], key[1], str(len(group))] + [f"{m:g}" for m in med]
                          + [f"{ratio:.2f}"]) + " |")
PY
