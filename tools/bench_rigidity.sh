#!/usr/bin/env bash
# Benchmark (not a test): the geometric check's rigidity test ([dop] rigidity_sigmas)
# or, with --toggle prediction-gate, the pose's prediction gate ([tracking]
# prediction_gate_share); docs/dop-model.md. Per preset and seed, one sequence,
# tracked --runs times with the toggle off (0) and on (the default), in the default
# real-time mode with the installed detector (--deterministic: inline detection,
# reproducible). Prints one markdown row per run and the medians per preset: ATE
# RMSE, points the rigidity test found moved per frame, the dynamic keypoints'
# precision / recall against the true masks, median tracking time.
#
#   bash tools/bench_rigidity.sh [--toggle rigidity|prediction-gate] [--seeds N] [--runs R]
#                                [--frames F] [--out DIR] [--deterministic] [PRESET ...]
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${DOPSLAM_BIN:-./target/release/dopslam}
seeds=3
runs=1
toggle=rigidity
out=
mode=()
frames=()
presets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2 ;;
    --runs) runs=$2; shift 2 ;;
    --toggle) toggle=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --frames) frames=(--frames "$2"); shift 2 ;;
    --deterministic) mode=(--deterministic); shift ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) presets+=("$1"); shift ;;
  esac
done
[ ${#presets[@]} -gt 0 ] || presets=(unknown_movers_close unknown_movers cutout_xyz cutout_static)
[ -n "${DOPSLAM_BIN:-}" ] || cargo build --release --quiet
case "$toggle" in
  rigidity) off='[dop]\nrigidity_sigmas = 0.0\n' ;;
  prediction-gate) off='[tracking]\nprediction_gate_share = 0.0\n' ;;
  *) echo "unknown toggle $toggle (rigidity | prediction-gate)" >&2; exit 2 ;;
esac
out=${out:-outputs/bench/$toggle}
mkdir -p "$out"
printf "$off" > "$out/off.toml"
printf '' > "$out/on.toml"
: > "$out/rows.jsonl"
for preset in "${presets[@]}"; do
  for ((s = 1; s <= seeds; s++)); do
    seq=$out/seq/$preset-$s
    seed_args=()
    [ "$s" -gt 1 ] && seed_args=(--seed $((1000 + s - 1)))
    [ -f "$seq/rgb.txt" ] || "$bin" synth --config "configs/synth/$preset.toml" "${seed_args[@]}" "${frames[@]}" --out "$seq" --force >/dev/null
    for variant in off on; do for ((r = 1; r <= runs; r++)); do
      run=$out/run/$variant/$preset-$s-$r
      mkdir -p "$(dirname "$run")"
      "$bin" run "$seq" --out "$run" --no-dense "${mode[@]}" --config "$out/$variant.toml" >"$run.log" 2>&1 \
        || { echo "run failed: $run.log" >&2; continue; }
      python3 - "$preset" "$s" "$variant" "$run/report.json" >>"$out/rows.jsonl" <<'PY'
import json, statistics, sys
preset, seed, variant, path = sys.argv[1:]
r = json.load(open(path))
frames = r["frames"]
c = r["detection"].get("classification") or {}
print(json.dumps(dict(
    preset=preset, seed=int(seed), variant=variant,
    ate_mm=1000 * r["ate"]["ape"]["statistics"]["rmse"],
    moved_per_frame=sum(f.get("rigidity_outliers", 0) for f in frames) / len(frames),
    precision=c.get("precision"), recall=c.get("recall"),
    median_ms=statistics.median(f["tracking_ms"] for f in frames))))
PY
    done; done
  done
done
python3 - "$out/rows.jsonl" "$toggle" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
fmt = lambda r: "%.1f | %.0f | %.3f / %.3f | %.1f" % (
    r["ate_mm"], r["moved_per_frame"], r["precision"] or 0, r["recall"] or 0, r["median_ms"])
toggle = sys.argv[2]
print(f"| preset | seed | {toggle} | ATE (mm) | found moved per frame | keypoint precision / recall | median ms |")
print("|---|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['preset']} | {r['seed']} | {r['variant']} | {fmt(r)} |")
print()
print(f"| preset | {toggle} | runs | median ATE (mm) | found moved per frame | precision / recall | median ms |")
print("|---|---|---|---|---|---|---|")
for preset in dict.fromkeys(r["preset"] for r in rows):
    for variant in ("off", "on"):
        g = [r for r in rows if r["preset"] == preset and r["variant"] == variant]
        if not g:
            continue
        med = lambda k: statistics.median(r[k] or 0 for r in g)
        print("| %s | %s | %d | %.1f | %.0f | %.3f / %.3f | %.1f |" % (
            preset, variant, len(g), med("ate_mm"), med("moved_per_frame"),
            med("precision"), med("recall"), med("median_ms")))
PY
