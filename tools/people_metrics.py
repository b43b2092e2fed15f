#!/usr/bin/env python3
"""Figures of one `dopslam run` on a synthetic sequence, for the moving-people benchmark
(tools/bench_people.sh): ATE RMSE (from report.json, evo's definition), the one-frame
relative translation error's 95th percentile (evo's RPE, delta 1 frame: E = (Q_i^-1
Q_j)^-1 (P_i^-1 P_j), Q ground truth, P estimate, its translation's norm), the estimated
path length over the true one, keyframes per frame, person recall on keyframes, the
dynamic-state recall against the masks, and the median tracking time.

    python3 tools/people_metrics.py RUN_DIR SEQUENCE_DIR [--json]

Standard library only.
"""
import json
import math
import sys


def quat_to_matrix(qx, qy, qz, qw):
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
    return [
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ]


def read_tum(path):
    poses = {}
    for line in open(path):
        if not line.strip() or line.startswith("#"):
            continue
        v = [float(x) for x in line.split()]
        poses[round(v[0], 4)] = (quat_to_matrix(*v[4:8]), v[1:4])
    return poses


def relative(a, b):
    """a^-1 b for (R, t) poses."""
    ra, ta = a
    rb, tb = b
    rat = [[ra[j][i] for j in range(3)] for i in range(3)]
    d = [tb[i] - ta[i] for i in range(3)]
    r = [[sum(rat[i][k] * rb[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    t = [sum(rat[i][k] * d[k] for k in range(3)) for i in range(3)]
    return r, t


def percentile(values, q):
    values = sorted(values)
    if not values:
        return float("nan")
    pos = (len(values) - 1) * q
    lo, hi = math.floor(pos), math.ceil(pos)
    return values[lo] + (values[hi] - values[lo]) * (pos - lo)


def metrics(run, sequence):
    report = json.load(open(f"{run}/report.json"))
    est = read_tum(f"{run}/trajectory.txt")
    gt = read_tum(f"{sequence}/groundtruth.txt")
    stamps = sorted(s for s in est if s in gt)
    errors, est_length, gt_length = [], 0.0, 0.0
    for a, b in zip(stamps, stamps[1:]):
        q = relative(gt[a], gt[b])
        p = relative(est[a], est[b])
        e = relative(q, p)
        errors.append(math.sqrt(sum(x * x for x in e[1])))
        est_length += math.sqrt(sum(x * x for x in p[1]))
        gt_length += math.sqrt(sum(x * x for x in q[1]))
    totals = report["totals"]
    detection = report["detection"]
    recall = detection.get("person_recall") or {}
    classification = detection.get("classification") or {}
    ate = report.get("ate") or {}
    return {
        "ate_rmse": ate.get("ape", {}).get("statistics", {}).get("rmse", float("nan")),
        "rpe1_p95": percentile(errors, 0.95),
        "path_ratio": est_length / gt_length if gt_length else float("nan"),
        "keyframe_share": totals["keyframes"] / max(totals["frames"], 1),
        "keyframes": totals["keyframes"],
        "coverage": totals["coverage_percent"],
        "person_recall": recall.get("recall") if recall.get("people") else None,
        "missed_large": recall.get("missed_large"),
        "state_recall": classification.get("recall"),
        "state_precision": classification.get("precision"),
        "median_ms": totals["median_tracking_ms"],
        "skipped": detection.get("skipped", 0),
        "detected": detection.get("detected", 0),
    }


if __name__ == "__main__":
    m = metrics(sys.argv[1], sys.argv[2])
    if "--json" in sys.argv:
        print(json.dumps(m))
    else:
        for k, v in m.items():
            print(f"{k:16s} {v}")
