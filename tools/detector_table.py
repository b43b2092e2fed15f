#!/usr/bin/env python3
"""The detector decision table from tools/bench_detectors.sh's rows: per detector and
masking, the medians over presets and seeds of person recall on keyframes, the
dynamic state's recall and precision, ATE RMSE, median tracking time, and in the dense
pass the movers' pixels kept out and the static pixels fused; then per preset.

    python3 tools/detector_table.py outputs/bench/detectors/rows.jsonl
"""
import json
import statistics
import sys


def median(rows, key):
    values = [r[key] for r in rows if r.get(key) is not None]
    return statistics.median(values) if values else None


def fmt(value, digits=3):
    return "-" if value is None else f"{value:.{digits}f}"


def table(rows, title):
    print(f"\n{title}\n")
    print("| detector | masks | runs | person recall | state recall / precision | ATE (mm) | median ms | movers kept out | static fused |")
    print("|---|---|---|---|---|---|---|---|---|")
    keys = sorted({(r["detector"], r["masking"]) for r in rows}, key=lambda k: (["yolov4-tiny", "deimv2-femto", "pool"].index(k[0]), k[1] != "depth-cut"))
    for detector, masking in keys:
        group = [r for r in rows if r["detector"] == detector and r["masking"] == masking]
        ate = median(group, "ate_rmse")
        print(f"| {detector} | {masking} | {len(group)} | {fmt(median(group, 'person_recall'))} | "
              f"{fmt(median(group, 'state_recall'))} / {fmt(median(group, 'state_precision'))} | "
              f"{fmt(None if ate is None else 1000 * ate, 2)} | {fmt(median(group, 'median_ms'), 1)} | "
              f"{fmt(median(group, 'dynamic_removed'), 4)} | {fmt(median(group, 'static_kept'), 4)} |")


def main():
    rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
    seeds = len({(r["preset"], r["seed"]) for r in rows})
    table(rows, f"All presets ({seeds} sequences), medians")
    for preset in sorted({r["preset"] for r in rows}):
        table([r for r in rows if r["preset"] == preset], f"{preset}, medians over seeds")


if __name__ == "__main__":
    main()
