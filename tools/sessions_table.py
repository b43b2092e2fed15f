"""The table of tools/bench_sessions.sh: for each run of the second recording, its
ATE in the first recording's world frame without alignment (the ground truth of the
second moved by the inverse of the first's first pose: the map's world is the first
recording's first camera), the first frame placed, keyframes, tracking time per frame,
and the map file's size and load time.

    python tools/sessions_table.py FIRST_SEQ SECOND_SEQ RUN_DIR...
"""
import json
import sys

import numpy as np


def read_tum(path):
    rows = [l.split() for l in open(path) if l.strip() and not l.startswith("#")]
    return {round(float(r[0]), 4): pose(list(map(float, r[1:8]))) for r in rows}


def pose(v):
    t, (x, y, z, w) = v[:3], v[3:]
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


def main():
    first, second, runs = sys.argv[1], sys.argv[2], sys.argv[3:]
    origin = np.linalg.inv(min(read_tum(f"{first}/groundtruth.txt").items())[1])
    in_map = {
        seq: {t: origin @ p for t, p in read_tum(f"{seq}/groundtruth.txt").items()}
        for seq in (first, second)
    }
    print(f"{'run':<28} {'ATE in map frame':>16} {'aligned ATE':>11} {'placed at':>9} "
          f"{'keyframes':>9} {'new kfs':>7} {'ms/frame':>8} {'map MB':>7} {'load s':>6} {'s/1000 kf':>9}")
    for run in runs:
        est = read_tum(f"{run}/trajectory.txt")
        report = json.load(open(f"{run}/report.json"))
        # The first recording's run makes the map: its frame is the map's.
        makes_map = report["sequence_path"].rstrip("/").endswith(first.rstrip("/").split("/")[-1])
        truth = in_map[first if makes_map else second]
        errors = [np.linalg.norm(p[:3, 3] - truth[t][:3, 3]) for t, p in est.items() if t in truth]
        totals = report["totals"]
        loaded = (report.get("slam_map") or {}).get("loaded")
        aligned = (report.get("ate") or {}).get("ape", {}).get("statistics", {}).get("rmse")
        placed = loaded["placed_at_frame"] if loaded else "-"
        own = len([l for l in open(f"{run}/keyframes.txt") if not l.startswith("#")])
        size = f"{loaded['bytes'] / 1e6:.1f}" if loaded else "-"
        load = f"{loaded['load_s']:.3f}" if loaded else "-"
        per_k = f"{loaded['load_s'] / loaded['keyframes'] * 1000:.3f}" if loaded else "-"
        # A run on its own has its own world frame: the first column is not its.
        ate = f"{np.sqrt(np.mean(np.square(errors))):.4f}" if errors and (loaded or makes_map) else "-"
        print(f"{run:<28} {ate:>14} m {aligned or float('nan'):>9.4f} m {placed!s:>9} "
              f"{totals['keyframes']:>9} {own:>7} {totals['median_tracking_ms']:>8.1f} {size:>7} {load:>6} {per_k:>9}")


if __name__ == "__main__":
    main()
