#!/usr/bin/env python3
"""The table of tools/bench_masks.sh: medians over seeds of each preset, and over every
run, with the free-space evidence off, near (the frames within 0.5 s only) and on
(near and far neighbours; issue 35's dense goals: movers' pixels
kept out >= 99.5 %, static pixels fused >= 90 %, a cloud without carving with <= 0.1 %
of its points on movers, >= 98 % of the unknown movers' pixels kept out).

    python3 tools/masks_table.py ROWS.jsonl

Standard library only.
"""
import json
import statistics
import sys

COLUMNS = [
    ("runs", None),
    ("ATE (mm)", "ate_mm"),
    ("person recall", "person_recall"),
    ("tracking ms", "median_tracking_ms"),
    ("movers kept out", "movers_kept_out"),
    ("static fused", "static_fused"),
    ("unknown kept out", "unknown_kept_out"),
    ("cloud mover points %", "cloud_mover_percent"),
    ("dense s", "dense_seconds"),
]


def median(rows, key):
    values = [r[key] for r in rows if r.get(key) is not None]
    return statistics.median(values) if values else None


def cell(value, key):
    if value is None:
        return "-"
    if key in ("movers_kept_out", "static_fused", "unknown_kept_out", "person_recall"):
        return f"{value:.4f}"
    if key == "cloud_mover_percent":
        return f"{value:.3f}"
    return f"{value:.1f}"


def table(groups):
    print("| preset | free space | " + " | ".join(name for name, _ in COLUMNS) + " |")
    print("|---|---|" + "---|" * len(COLUMNS))
    for (preset, variant), rows in groups:
        cells = [str(len(rows))] + [cell(median(rows, key), key) for _, key in COLUMNS[1:]]
        print(f"| {preset} | {variant} | " + " | ".join(cells) + " |")


def main():
    rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
    for r in rows:
        r["cloud_mover_percent"] = 100.0 * r["cloud_mover_points"] / max(r["cloud_points"], 1)
    presets = sorted({r["preset"] for r in rows}, key=lambda p: (p.startswith("unknown"), p))
    groups = []
    for preset in presets:
        for variant in ("off", "near", "on"):
            chosen = [r for r in rows if r["preset"] == preset and r["free_space"] == variant]
            if chosen:
                groups.append(((preset, variant), chosen))
    for variant in ("off", "near", "on"):
        cutouts = [r for r in rows if r["preset"].startswith("cutout_") and r["free_space"] == variant]
        if cutouts:
            groups.append((("all cut-out presets", variant), cutouts))
    table(groups)


if __name__ == "__main__":
    main()
