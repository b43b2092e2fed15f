#!/usr/bin/env python3
"""The table of tools/bench_far_people.sh: one row per preset, seed and variant, then
the medians over seeds per preset and variant (issue 47's goals: mesh vertices on
movers <= 0.1 %, cloud without carving <= 0.1 %, movers' pixels kept out >= 99.5 %,
static pixels fused >= 90 %; the dense pass's time at most 2x "before").

    python3 tools/far_people_table.py ROWS.jsonl

Standard library only.
"""
import json
import statistics
import sys

BANDS = ["0-40", "40-80", "80-160", "160-"]


def figures(row):
    share = lambda a, b: 100.0 * row[a] / row[b] if row[b] else float("nan")
    out = {
        "ATE mm": row["ate_mm"],
        "mesh on movers %": share("mesh_mover_vertices", "mesh_vertices"),
        "cloud on movers %": share("cloud_mover_points", "cloud_points"),
        "movers kept out %": 100.0 * row["movers_kept_out"],
        "static fused %": 100.0 * row["static_fused"],
        "dense recall": row["dense_recall"],
    }
    for band in BANDS:
        value = row["dense_recall_by_height"].get(band, [None, 0])
        out[f"recall {band} px"] = value[0]
    out["detect ms"] = row["dense_detection_ms"]
    out["dense s"] = row["dense_seconds"]
    return out


def cell(value, digits=3):
    if value is None or value != value:
        return "-"
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def main():
    rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
    if not rows:
        sys.exit("no rows")
    names = list(figures(rows[0]).keys())
    print("| preset | seed | variant | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 3) + "|")
    for row in rows:
        f = figures(row)
        print(f"| {row['preset']} | {row['seed']} | {row['variant']} | "
              + " | ".join(cell(f[n]) for n in names) + " |")
    print()
    print("Medians over seeds:")
    print()
    print("| preset | variant | seeds | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 3) + "|")
    groups = {}
    for row in rows:
        groups.setdefault((row["preset"], row["variant"]), []).append(figures(row))
    for (preset, variant), group in groups.items():
        medians = []
        for n in names:
            values = [g[n] for g in group if g[n] is not None and g[n] == g[n]]
            medians.append(statistics.median(values) if values else None)
        print(f"| {preset} | {variant} | {len(group)} | " + " | ".join(cell(m) for m in medians) + " |")


if __name__ == "__main__":
    main()
