#!/usr/bin/env python3
"""Checks the loops a run closed against the sequence's ground truth: for each loop in
report.json, the true distance and rotation between the two keyframes' cameras (a
true loop sees the same place: the cameras are close). Prints one line per loop.

    python3 tools/check_loops.py RUN_DIR SEQUENCE_DIR
"""
import json
import math
import sys


def read_tum(path):
    poses = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        t, x, y, z, qx, qy, qz, qw = map(float, line.split()[:8])
        poses[t] = ((x, y, z), (qx, qy, qz, qw))
    return poses


def nearest(poses, t):
    key = min(poses, key=lambda s: abs(s - t))
    return poses[key]


def angle(q1, q2):
    dot = abs(sum(a * b for a, b in zip(q1, q2)))
    return math.degrees(2 * math.acos(min(1.0, dot)))


def main():
    run, seq = sys.argv[1], sys.argv[2]
    report = json.load(open(f"{run}/report.json"))
    gt = read_tum(f"{seq}/groundtruth.txt")
    loops = (report.get("global") or {}).get("loops", [])
    if not loops:
        print("no loops")
    for loop in loops:
        (p1, q1), (p2, q2) = nearest(gt, loop["keyframe_time"]), nearest(gt, loop["matched_time"])
        d = math.dist(p1, p2)
        print(f"keyframe {loop['keyframe']} (t {loop['keyframe_time']:.2f}) -> {loop['matched']} (t {loop['matched_time']:.2f}): "
              f"true distance {d:.3f} m, rotation {angle(q1, q2):.1f} deg, {loop['inliers']} inliers")


if __name__ == "__main__":
    main()
