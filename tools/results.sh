#!/usr/bin/env bash
# The headline figures (a benchmark, not a test), written into docs/results.md and the
# README's results block, with the machine, the date and the commit:
#   1. the demo (configs/synth/demo.toml, the quick start's scene; needs nothing outside
#      the repository): ATE with and without DOP, mover points in each dense map; its
#      picture becomes docs/images/demo_maps.png;
#   2. real data, shown first (needs ../shared/data, or DOPSLAM_SHARED_DATA): the real
#      KITTI stereo clips 01 and 06 (tools/bench_kitti.sh: ATE with and without DOP, medians
#      of --kitti-runs real-time runs each, interleaved), the real RGB-D recording of
#      people walking before a static camera (tools/bench_real_people.sh: masks against
#      its per-pixel truth, mesh vertices in front of the background, --real-runs runs)
#      and the wall time of whole runs of all three, stage by stage, with the real-time
#      factor (tools/bench_run_time.sh, --real-runs runs each);
#   3. the cut-out presets (real people cut out of a TUM frame, real fr3 frame timing;
#      needs ../shared/data) through tools/bench_people.sh: the real detector in the
#      default real-time mode (the headline), ORB-SLAM2 behaviour, and oracle boxes in
#      real time (an upper bound, never instead of the headline).
#
#   bash tools/results.sh [--seeds N] [--kitti-runs 10] [--real-runs 3] [PRESET ...]
#                                     # default: 1 seed, the five cut-out presets
# About 20 minutes on 2 cores with the defaults (12 without ../shared/data).
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=1
kitti_runs=10
real_runs=3
while [ $# -gt 0 ]; do
    case "$1" in
        --seeds) seeds=$2; shift 2 ;;
        --kitti-runs) kitti_runs=$2; shift 2 ;;
        --real-runs) real_runs=$2; shift 2 ;;
        -h|--help) sed -n '2,22p' "$0"; exit 0 ;;
        *) break ;;
    esac
done
presets=("$@")
say() { printf '\033[1m[results]\033[0m %s\n' "$*" >&2; }
source tools/system_packages.sh
cargo build --release --quiet "${CARGO_FEATURES[@]}"
bin=./target/release/dopslam
$bin doctor >/dev/null || { $bin doctor; exit 1; }
out=outputs/results
mkdir -p "$out" docs/images

say "demo: synth, run --compare-no-dop (real detector, real time)"
$bin synth --config configs/synth/demo.toml --out "$out/demo/sequence" --force >/dev/null
demo_start=$(date +%s)
$bin run "$out/demo/sequence" --config configs/run/demo.toml --out "$out/demo/run" --compare-no-dop \
    > "$out/demo.log" 2>&1
demo_seconds=$(( $(date +%s) - demo_start ))
cp "$out/demo/run/compare_no_dop/compare_perspective.png" docs/images/demo_maps.png

# Real data: each benchmark writes into its own folder under outputs/results (it
# replaces the runs it made there before, and refuses a folder it did not make).
shared=${DOPSLAM_SHARED_DATA:-../shared/data}
kitti_clips=$shared/real/kitti/sequences
ist=$shared/real/ist/confusao
ist_settings=$shared/calibration/RGB-D_IST_Xtion.yaml
rm -f "$out/kitti.md" "$out/real_people.md" "$out/run_time.md"
if [ -d "$kitti_clips/01/image_0" ] && [ -d "$kitti_clips/06/image_0" ] && [ -f "$ist/depth.txt" ]; then
    say "real KITTI clips 01 and 06: tools/bench_kitti.sh ($kitti_runs real-time runs a mode)"
    DOPSLAM_SHARED_DATA=$shared bash tools/bench_kitti.sh --runs "$kitti_runs" --out "$out/kitti" \
        > "$out/kitti.log" 2>&1 || { tail -5 "$out/kitti.log" >&2; exit 1; }
    cp "$out/kitti/results.md" "$out/kitti.md"
    say "real people before a static camera (IST): tools/bench_real_people.sh ($real_runs runs)"
    bash tools/bench_real_people.sh --runs "$real_runs" --out "$out/real_people" \
        --sequence "$ist" --settings "$ist_settings" > "$out/real_people.log" 2>&1 \
        || { tail -5 "$out/real_people.log" >&2; exit 1; }
    grep '^|' "$out/real_people.log" > "$out/real_people.md"
    say "whole runs' time per stage: tools/bench_run_time.sh ($real_runs runs each)"
    bash tools/bench_run_time.sh --runs "$real_runs" --out "$out/run_time" \
        "$kitti_clips/01::configs/calibration/Stereo_KITTI00-02.yaml" \
        "$kitti_clips/06::configs/calibration/Stereo_KITTI04-12.yaml" \
        "$ist::$ist_settings" > "$out/run_time.log" 2>&1 \
        || { tail -5 "$out/run_time.log" >&2; exit 1; }
    sed -n '/^medians$/,$p' "$out/run_time.log" | grep '^|' > "$out/run_time.md"
else
    say "real data: skipped ($shared/real holds no KITTI clips 01 and 06 or no IST recording)"
fi

people="$out/people.md"
if [ -d ../shared/data ]; then
    say "cut-out presets: tools/bench_people.sh (dop-onnx-rt, no-dop, dop-oracle-rt; $seeds seed(s))"
    bash tools/bench_people.sh --seeds "$seeds" --variants "dop-onnx-rt no-dop dop-oracle-rt" "${presets[@]}" > "$people"
else
    echo "(skipped: ../shared/data, with the real frame timing of the cut-out presets, is not beside the checkout)" > "$people"
fi

python3 - "$out" "$demo_seconds" "$kitti_runs" "$real_runs" <<'PY'
import json, pathlib, platform, re, subprocess, sys
out, demo_seconds = pathlib.Path(sys.argv[1]), int(sys.argv[2])
kitti_runs, real_runs = sys.argv[3], sys.argv[4]
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.machine())
mem = next(int(l.split()[1]) for l in open("/proc/meminfo") if l.startswith("MemTotal")) / 1048576
commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip() or "?"
# Changes to the source, not to what this script writes (the picture is already there).
ours = [":!docs/results.md", ":!docs/images/demo_maps.png", ":!README.md"]
dirty = subprocess.run(["git", "diff", "--quiet", "--", ".", *ours]).returncode != 0
date = subprocess.run(["date", "-u", "+%Y-%m-%d %H:%M UTC"], capture_output=True, text=True).stdout.strip()
log = (out / "demo.log").read_text()
summary = log[log.index("summary:"):].strip() if "summary:" in log else "(the demo printed no summary: see outputs/results/demo.log)"
table = (out / "demo/run/compare_no_dop/compare.md").read_text().split("\n\n")[2].strip()
people = (out / "people.md").read_text().strip()
def read_table(name):
    path = out / name
    return path.read_text().strip() if path.exists() else ""
kitti, real_people, run_time = (read_table(n) for n in ("kitti.md", "real_people.md", "run_time.md"))
def table_rows(text, first):
    return [[c.strip() for c in l.split("|")[1:-1]] for l in text.splitlines() if l.startswith(f"| {first}")]
real_section = ""
if kitti and real_people and run_time:
    real_section = f"""## Real data

ORB-SLAM2 itself could not be run beside these (no copy of its vocabulary,
`ORBvoc.txt`, can be obtained here).

### The real KITTI stereo clips (`../shared/data/real/kitti`, 51 frames each)

`bash tools/bench_kitti.sh --runs {kitti_runs}`: ORB-SLAM2's own settings files, whole
default runs without the dense pass, real time, modes interleaved; ATE against KITTI's
ground truth after the global pass.

{kitti}

### Real people before a static camera (`../shared/data/real/ist/confusao`, 149 frames)

`bash tools/bench_real_people.sh --runs {real_runs}`: whole default runs, dense pass on. The
masks against the recording's per-pixel truth (`tools/static_camera_truth.py`), and the
mesh's vertices more than 15 cm in front of each pixel's farthest depth over the
recording and of its 95th percentile ("rare": seen at their depth in under half the
frames, a mover's ghost); the last two rows are a recording with the truth's movers
taken out of its depth, the floor of those figures.

{real_people}

### Whole runs, stage by stage

`bash tools/bench_run_time.sh --runs {real_runs}` on the three real recordings: the process's
wall time and peak memory, each stage's wall time, and the real-time factor (the run's
wall time over the recording's duration; below 1 keeps up with it), medians.

{run_time}

"""
machine = f"{cpu}, {subprocess.run(['nproc'], capture_output=True, text=True).stdout.strip()} cores, {mem:.0f} GiB"
head = f"Date {date}; commit {commit}{' (with uncommitted changes)' if dirty else ''}; {machine}."
doc = f"""# Measured results

Written by `bash tools/results.sh` (do not edit by hand). {head}

Every figure uses the real detector (YOLOv4-tiny at 320x256, the default) in the
default real-time mode unless its row says otherwise; oracle boxes (`dop-oracle-rt`)
are an upper bound beside it. Real-time runs vary from run to run (thread
interleaving); `--seeds N` repeats each preset on N generated sequences.

{real_section}## The demo (`configs/synth/demo.toml`, 300 frames)

`dopslam run outputs/results/demo/sequence --config configs/run/demo.toml --compare-no-dop`
({demo_seconds} s for both runs, both dense passes and the comparison):

```text
{summary}
```

{table}

![maps](images/demo_maps.png)

## People cut out of real photos (`configs/synth/cutout_*.toml`)

`bash tools/bench_people.sh --variants "dop-onnx-rt no-dop dop-oracle-rt"`: ATE after
the global pass, person recall on keyframes, the DOP state's recall and precision
against the true masks, median tracking time per frame (ORB extraction included).

{people}
"""
pathlib.Path("docs/results.md").write_text(doc)
rows = [l for l in people.splitlines() if l.startswith("| cutout")]
def pick(variant):
    return {r.split("|")[1].strip(): [c.strip() for c in r.split("|")[1:-1]] for r in rows if f"| {variant} |" in r}
dop, nodop = pick("dop-onnx-rt"), pick("no-dop")
lines = [f"From `bash tools/results.sh` ({date}, commit {commit}, {machine}); all of it in",
         "`docs/results.md`. Real detector, default real-time mode.", ""]
if real_section:
    lines += [f"Real KITTI stereo clips, ATE RMSE after the global pass (medians of {kitti_runs} runs; ORB-SLAM2 could not be run here):", "",
              "| clip | with DOP (m) | without DOP (m) |", "|---|---|---|"]
    for clip in ("KITTI 01", "KITTI 06"):
        # The first table's rows (runs a number); the comparison's rows come after.
        ate = {r[1]: r[3].split(" ")[0] for r in table_rows(kitti, clip) if r[2].isdigit()}
        lines.append(f"| {clip} | {ate.get('dop', '-')} | {ate.get('no-dop', '-')} |")
    ist = next((r for r in table_rows(real_people, "dop") if r[2] == "median"), None)
    refs = {r[0]: r for r in table_rows(real_people, "no")}
    if ist and "no_dop" in refs:
        ist_nodop = refs["no_dop"]
        lines += ["", f"Real people walking before a static camera (IST, medians of {real_runs} runs): the dense "
                  f"map keeps out {ist[5]} of the movers' pixels and fuses {ist[4]} of the static ones; "
                  f"{ist[7]} % of its mesh vertices ({ist[6]}) lie more than 15 cm in front of the background, "
                  f"{ist[8]} of them seen there in under half the frames (ghosts), against {ist_nodop[7]} % "
                  f"({ist_nodop[6]}, {ist_nodop[8]} rare) without DOP; it covers {ist[11]} % of the background."]
    lines += ["", "| recording | recording s | run s | real-time factor | tracking s | dense s |", "|---|---|---|---|---|---|"]
    for r in table_rows(run_time, ""):
        if len(r) >= 11 and r[0] != "sequence":
            name = {"01": "KITTI 01", "06": "KITTI 06", "confusao": "IST people"}.get(r[0], r[0])
            lines.append(f"| {name} | {r[5]} | {r[6]} | {r[7]} | {r[8]} | {r[10]} |")
    lines.append("")
lines += ["The demo:", "", "```text", summary, "```", ""]
if dop:
    lines += ["| cut-out preset | ATE with DOP (m) | ATE without DOP (m) | person recall | median tracking (ms) |",
              "|---|---|---|---|---|"]
    for preset, cells in dop.items():
        lines.append(f"| {preset} | {cells[3]} | {nodop.get(preset, ['-'] * 4)[3]} | {cells[7]} | {cells[9]} |")
readme = pathlib.Path("README.md").read_text()
block = "<!-- results:begin -->\n" + "\n".join(lines) + "\n<!-- results:end -->"
readme = re.sub(r"<!-- results:begin -->.*?<!-- results:end -->", lambda _: block, readme, flags=re.S)
pathlib.Path("README.md").write_text(readme)
PY
say "wrote docs/results.md, docs/images/demo_maps.png and the README's results block"
