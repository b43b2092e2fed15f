#!/usr/bin/env bash
# Benchmark (not a test): movers no detector knows (configs/synth/unknown_movers.toml:
# a box slid across the floor and set down, a balloon drifting at head height, one
# walker). Per seed, in the default real-time mode with the installed detector: the
# run on the sequence and on the same room and path without the movers (`synth
# --without-movers`), ORB-SLAM2 behaviour (--no-dop) on the sequence, and the dense
# pass with today's masks and with the masks before depth segments (no segments, a
# disc around every dynamic keypoint). Prints one markdown row per seed.
#
#   bash tools/bench_unknown.sh [--seeds N] [--jobs J] [--out DIR] [--preset NAME]
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${DOPSLAM_BIN:-./target/release/dopslam}
seeds=5
jobs=1
out=outputs/bench/unknown
preset=unknown_movers
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2 ;;
    --jobs) jobs=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --preset) preset=$2; shift 2 ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
done
[ -n "${DOPSLAM_BIN:-}" ] || cargo build --release --quiet
mkdir -p "$out"
printf '[dense]\nmask_segments = false\nmask_disc_neighbours = 0\n' > "$out/before.toml"
printf '' > "$out/today.toml"

one() {
  local s=$1 seed_args=() seq=$out/seq-$1 control=$out/control-$1
  [ "$s" -gt 1 ] && seed_args=(--seed $((1000 + s - 1)))
  [ -f "$seq/rgb.txt" ] || "$bin" synth --config "configs/synth/$preset.toml" "${seed_args[@]}" --out "$seq" --force >/dev/null
  [ -f "$control/rgb.txt" ] || "$bin" synth --config "configs/synth/$preset.toml" "${seed_args[@]}" --without-movers --out "$control" --force >/dev/null
  "$bin" run "$seq" --out "$out/run-$s" --no-dense --dop --detections onnx >"$out/run-$s.log" 2>&1
  "$bin" run "$control" --out "$out/control-run-$s" --no-dense --dop --detections onnx >"$out/control-run-$s.log" 2>&1
  "$bin" run "$seq" --out "$out/nodop-$s" --no-dense --no-dop --detections none >"$out/nodop-$s.log" 2>&1
  local row=()
  for masks in today before; do
    "$bin" fuse "$out/run-$s" --config "$out/$masks.toml" >>"$out/run-$s.log" 2>&1
    row+=("$(python3 -c "import json; t = json.load(open('$out/run-$s/dense.json'))['truth']; print(json.dumps(t))")")
  done
  python3 - "$s" "$out" "$seq" "$control" "${row[@]}" <<'PY'
import json, subprocess, sys
s, out, seq, control, today, before = sys.argv[1:]
m = lambda run, sq: json.loads(subprocess.check_output(["python3", "tools/people_metrics.py", run, sq, "--json"]))
dop, ctl, nodop = m(f"{out}/run-{s}", seq), m(f"{out}/control-run-{s}", control), m(f"{out}/nodop-{s}", seq)
today, before = json.loads(today), json.loads(before)
print(json.dumps(dict(seed=int(s), ate=dop["ate_rmse"], ate_control=ctl["ate_rmse"], ate_nodop=nodop["ate_rmse"],
                      median_ms=dop["median_ms"], today=today, before=before)))
PY
}
export -f one
export bin out preset
for ((s = 1; s <= seeds; s++)); do echo "$s"; done | xargs -P "$jobs" -n 1 bash -c 'one "$0"' > "$out/rows.jsonl"
python3 - "$out/rows.jsonl" <<'PY'
import json, statistics, sys
rows = sorted((json.loads(l) for l in open(sys.argv[1]) if l.strip()), key=lambda r: r["seed"])
print("| seed | ATE (mm) | without the movers (mm) | ratio | --no-dop (mm) | unknown movers kept out: today / before | all movers kept out | static fused: today / before |")
print("|---|---|---|---|---|---|---|---|")
for r in rows + [None]:
    if r is None:
        med = lambda f: statistics.median(f(x) for x in rows)
        r = dict(seed="median", ate=med(lambda x: x["ate"]), ate_control=med(lambda x: x["ate_control"]), ate_nodop=med(lambda x: x["ate_nodop"]),
                 today={k: med(lambda x: x["today"][k]) for k in ("unknown_removed", "dynamic_removed", "static_kept")},
                 before={k: med(lambda x: x["before"][k]) for k in ("unknown_removed", "dynamic_removed", "static_kept")})
    t, b = r["today"], r["before"]
    print(f"| {r['seed']} | {1000 * r['ate']:.2f} | {1000 * r['ate_control']:.2f} | {r['ate'] / r['ate_control']:.2f} | {1000 * r['ate_nodop']:.1f} | "
          f"{t['unknown_removed']:.3f} / {b['unknown_removed']:.3f} | {t['dynamic_removed']:.3f} / {b['dynamic_removed']:.3f} | {t['static_kept']:.3f} / {b['static_kept']:.3f} |")
PY
