#!/usr/bin/env bash
# The headline figures (a benchmark, not a test), written into docs/results.md and the
# README's results block, with the machine, the date and the commit:
#   1. the demo (configs/synth/demo.toml, the quick start's scene; needs nothing outside
#      the repository): ATE with and without DOP, mover points in each dense map; its
#      picture becomes docs/images/demo_maps.png;
#   2. the cut-out presets (real people cut out of a TUM frame, real fr3 frame timing;
#      needs ../shared/data) through tools/bench_people.sh: the real detector in the
#      default real-time mode (the headline), ORB-SLAM2 behaviour, and oracle boxes in
#      real time (an upper bound, never instead of the headline).
#
#   bash tools/results.sh [--seeds N] [PRESET ...]    # default: 1 seed, the five cut-out presets
# About 12 minutes on 2 cores with one seed.
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=1
while [ $# -gt 0 ]; do
    case "$1" in
        --seeds) seeds=$2; shift 2 ;;
        -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
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

people="$out/people.md"
if [ -d ../shared/data ]; then
    say "cut-out presets: tools/bench_people.sh (dop-onnx-rt, no-dop, dop-oracle-rt; $seeds seed(s))"
    bash tools/bench_people.sh --seeds "$seeds" --variants "dop-onnx-rt no-dop dop-oracle-rt" "${presets[@]}" > "$people"
else
    echo "(skipped: ../shared/data, with the real frame timing of the cut-out presets, is not beside the checkout)" > "$people"
fi

python3 - "$out" "$demo_seconds" <<'PY'
import json, pathlib, platform, re, subprocess, sys
out, demo_seconds = pathlib.Path(sys.argv[1]), int(sys.argv[2])
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
machine = f"{cpu}, {subprocess.run(['nproc'], capture_output=True, text=True).stdout.strip()} cores, {mem:.0f} GiB"
head = f"Date {date}; commit {commit}{' (with uncommitted changes)' if dirty else ''}; {machine}."
doc = f"""# Measured results

Written by `bash tools/results.sh` (do not edit by hand). {head}

Every figure uses the real detector (YOLOv4-tiny at 320x256, the default) in the
default real-time mode unless its row says otherwise; oracle boxes (`dop-oracle-rt`)
are an upper bound beside it. Real-time runs vary from run to run (thread
interleaving); `--seeds N` repeats each preset on N generated sequences.

## The demo (`configs/synth/demo.toml`, 300 frames)

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
         "`docs/results.md`. Real detector, default real-time mode.", "",
         "```text", summary, "```", ""]
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
