#!/usr/bin/env python3
"""Checks the loops a run closed against the sequence's ground truth: for each loop in
report.json, the true distance and rotation between the two keyframes' cameras (a
true loop sees the same place: the cameras are close). Prints one line per loop.

    python3 tools/check_loops.py RUN_DIR SEQUENCE_DIR

SEQUENCE_DIR is a TUM-layout folder (groundtruth.txt) or a KITTI sequence folder
(dataset/sequences/NN with times.txt; the poses are read from dataset/poses/NN.txt).
"""
import json
import math
import os
import sys


def read_tum(path):
    poses = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        t, x, y, z, qx, qy, qz, qw = map(float, line.split()[:8])
        poses[t] = ((x, y, z), (qx, qy, qz, qw))
    return poses


def quaternion(r):
    """(qx, qy, qz, qw) of a rotation matrix given as rows."""
    trace = r[0][0] + r[1][1] + r[2][2]
    if trace > 0:
        s = 2 * math.sqrt(1 + trace)
        return ((r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s, s / 4)
    i = max(range(3), key=lambda k: r[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2 * math.sqrt(1 + r[i][i] - r[j][j] - r[k][k])
    q = [0.0, 0.0, 0.0, (r[k][j] - r[j][k]) / s]
    q[i] = s / 4
    q[j] = (r[j][i] + r[i][j]) / s
    q[k] = (r[k][i] + r[i][k]) / s
    return tuple(q)


def read_kitti(folder):
    """Poses by time of a KITTI sequence folder: times.txt and ../../poses/NN.txt."""
    folder = os.path.normpath(folder)
    name = os.path.basename(folder)
    poses_path = os.path.join(os.path.dirname(os.path.dirname(folder)), "poses", f"{name}.txt")
    times = [float(line) for line in open(os.path.join(folder, "times.txt")) if line.strip()]
    poses = {}
    for t, line in zip(times, open(poses_path)):
        m = list(map(float, line.split()))
        rows = [m[0:3], m[4:7], m[8:11]]
        poses[t] = ((m[3], m[7], m[11]), quaternion(rows))
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
    if os.path.exists(os.path.join(seq, "times.txt")):
        gt = read_kitti(seq)
    else:
        gt = read_tum(os.path.join(seq, "groundtruth.txt"))
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
