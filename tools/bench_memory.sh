#!/usr/bin/env bash
# Benchmark (not a test): peak memory of long runs. Images are streamed, so memory
# should follow the map (keyframes and map points), not the number of frames. Makes
# (once, into outputs/bench/) a 5000-frame room (loop_walking: 5.5 turns around the
# room with two walkers), the full 4541-frame KITTI 00 street (street_kitti00 at
# its full length; needs ../shared/data) and, when asked, the 2836-frame RGB-D desk
# loop (desk_far_people: TUM fr2_desk's real path, walkers behind the desk) and the
# street driven three times (`laps`: KITTI 00's path three times over, joined by
# U-turns, tools/laps_path.py; 14,321 frames, 11.5 km; one lap and one join are
# rendered, 4890 frames, 7.5 GB, about an hour on 2 cores, and the rest are links to
# them, tools/repeat_sequence.py), runs `dopslam run` on a 1000-frame prefix
# and on the whole of each (real detector, default real-time mode, global pass on;
# dense pass off unless --dense) and prints the peak resident memory from the report
# (VmHWM) with the map's size, each stage's own peak (`times.stages`), the global
# pass's parts' (`global.memory`: loops, full BA, frames) and the dense pass's
# (`dense.memory`): fusion, marching cubes, the cloud, the files.
#
#   bash tools/bench_memory.sh [--dense] [--lengths "1200 3600"] [--config FILE] [room|street|desk|laps ...]
#
# --lengths: the prefixes run (default: 1000 frames and the whole sequence).
# --config: a partial config every run takes (for example `[global.loops]
#   during_tracking = true`, docs/design.md "Loops closed during tracking").
set -euo pipefail
cd "$(dirname "$0")/.."
dense=--no-dense
lengths=
extra=()
while [ $# -gt 0 ]; do
  case $1 in
    --dense) dense=; shift ;;
    --lengths) lengths=$2; shift 2 ;;
    --config) extra=(--config "$(realpath "$2")"); shift 2 ;;
    *) break ;;
  esac
done
which=("$@")
if [ ${#which[@]} -eq 0 ]; then which=(room street); fi
cargo build --release --quiet
mkdir -p outputs/bench
printf '%-8s %7s %9s %6s %9s %9s %8s %8s %8s %8s %8s %8s %8s %8s %8s %8s %8s %8s\n' sequence frames coverage kfs points "peak MiB" "MiB/kf" \
  tracking global outputs dense loops full_ba frames fusion mesh cloud files
for name in "${which[@]}"; do
  case $name in
    room) preset=loop_walking; frames=5000; seq=outputs/bench/long_room ;;
    street) preset=street_kitti00; frames=4541; seq=outputs/bench/long_street ;;
    desk) preset=desk_far_people; frames=2836; seq=outputs/bench/desk_loop ;;
    laps) preset=street_laps; seq=outputs/bench/three_laps; rendered=outputs/bench/lap_and_join ;;
    *) echo "unknown: $name (room, street, desk or laps)" >&2; exit 2 ;;
  esac
  config=configs/synth/$preset.toml
  if [ "$name" = laps ]; then
    # The street preset along a path that drives KITTI 00 three times.
    path=$PWD/outputs/bench/three_laps_path
    mkdir -p "$path"
    python=python3; [ -x data/venv/bin/python3 ] && python=data/venv/bin/python3  # numpy
    $python tools/laps_path.py ../shared/data/kitti-poses/00.txt "$path/00.txt" --laps 3
    frames=$(wc -l <"$path/00.txt")
    config=$path/street_laps.toml
    sed -e 's/^name = .*/name = "street_laps"/' -e "s|^file = .*|file = \"$path/00.txt\"|" \
      configs/synth/street_kitti00.toml >"$config"
  fi
  if [ "$name" = laps ]; then
    # Laps and joins repeat pose for pose: render one of each, link the rest.
    period=$(python3 tools/repeat_sequence.py "$path/00.txt" --period)
    if [ ! -f "$rendered/scene.toml" ]; then
      ./target/release/dopslam synth --config "$config" --frames "$period" --out "$rendered" --force >/dev/null
    fi
    [ -d "$seq" ] || python3 tools/repeat_sequence.py "$path/00.txt" "$rendered/kitti" "$seq"
  elif [ ! -f "$seq/scene.toml" ]; then
    ./target/release/dopslam synth --config "$config" --frames "$frames" --out "$seq" --force >/dev/null
  fi
  input=$seq
  for kitti in "$seq"/kitti/sequences/*/; do [ -d "$kitti" ] && input=${kitti%/}; done
  for n in ${lengths:-1000 $frames}; do
    out=outputs/bench/memory-$name-$n
    rm -rf "$out"
    ./target/release/dopslam run "$input" --out "$out" --frames "$n" $dense "${extra[@]}" >"$out.log" 2>&1 || echo "$name: dopslam run failed (see $out.log)"
    python3 - "$name" "$out/report.json" <<'PY'
import json, sys
name, path = sys.argv[1], sys.argv[2]
r = json.load(open(path))
t = r["totals"]
times = r.get("times") or {}
peak = times.get("peak_memory_mib") or t.get("peak_memory_mib") or 0.0
# Each stage's own peak (report.json `times.stages`), the global pass's parts
# (`global.memory`) and the dense pass's (`dense.memory`).
stages = {s["stage"]: s.get("peak_memory_mib") for s in times.get("stages", [])}
parts = (r.get("dense") or {}).get("memory") or {}
cell = lambda v: f"{v:8.0f}" if v is not None else f"{'-':>8}"
cells = " ".join(cell(stages.get(k)) for k in ("tracking", "global", "outputs", "dense"))
glob = (r.get("global") or {}).get("memory") or {}
cells += " " + " ".join(cell(glob.get(k + "_mib")) for k in ("loops", "full_ba", "frames"))
cells += " " + " ".join(cell(parts.get(k + "_mib")) for k in ("fusion", "mesh", "cloud", "writing"))
print(f"{name:<8} {t['frames']:7d} {t['coverage_percent']:8.1f}% {t['keyframes']:6d} {t['map_points']:9d} "
      f"{peak:9.0f} {peak / max(t['keyframes'], 1):8.2f} {cells}")
PY
  done
done
