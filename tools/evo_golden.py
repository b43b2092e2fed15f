#!/usr/bin/env python3
"""Computes the golden figures that tests/evo_equivalence.rs checks, with evo itself.

Usage: python3 tools/evo_golden.py [SHARED_DATA_DIR] > tests/golden/evo_1.38.json
Needs `pip install evo==1.38.1` (and TUM's script rule for seconds is ours: evo has no
seconds delta). For every pair of trajectories: APE (translation, SE(3) Umeyama) and
RPE (translation, delta 1 frame), all statistics.
"""
import json
import sys
from pathlib import Path

from evo.core import metrics, sync
from evo.tools import file_interface

data = Path(sys.argv[1] if len(sys.argv) > 1 else "../shared/data")
PAIRS = [
    ("tum", "trajectories/freiburg1_xyz-groundtruth.txt", "trajectories/freiburg1_xyz-rgbdslam.txt"),
    ("tum", "trajectories/freiburg1_xyz-groundtruth.txt", "trajectories/freiburg1_xyz-rgbdslam_drift.txt"),
    ("tum", "trajectories/freiburg1_xyz-groundtruth.txt", "trajectories/freiburg1_xyz-ORB_kf_mono.txt"),
    ("tum", "trajectories/fr2_desk_groundtruth.txt", "trajectories/fr2_desk_ORB.txt"),
    ("tum", "trajectories/fr2_desk_groundtruth.txt", "trajectories/fr2_desk_ORB_kf_mono.txt"),
    ("tum", "trajectories/bonn_clip_groundtruth.txt", "trajectories/bonn_clip_amosslam_estimate.txt"),
    ("kitti", "trajectories/KITTI_00_gt.txt", "trajectories/KITTI_00_ORB.txt"),
    ("kitti", "trajectories/KITTI_00_gt.txt", "trajectories/KITTI_00_SPTAM.txt"),
]
STATS = ["rmse", "mean", "median", "std", "min", "max", "sse"]


def load(fmt, ref, est):
    if fmt == "tum":
        r = file_interface.read_tum_trajectory_file(str(data / ref))
        e = file_interface.read_tum_trajectory_file(str(data / est))
        r, e = sync.associate_trajectories(r, e, max_diff=0.01)
    else:
        r = file_interface.read_kitti_poses_file(str(data / ref))
        e = file_interface.read_kitti_poses_file(str(data / est))
    return r, e


def run(fmt, ref, est, scale):
    r, e = load(fmt, ref, est)
    e.align(r, correct_scale=scale)
    out = {"matched": int(r.num_poses)}
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((r, e))
    out["ape"] = {k: float(v) for k, v in ape.get_all_statistics().items() if k in STATS}
    for relation, key in [(metrics.PoseRelation.translation_part, "rpe_1f"), (metrics.PoseRelation.rotation_angle_deg, "rpe_1f_deg")]:
        rpe = metrics.RPE(relation, delta=1, delta_unit=metrics.Unit.frames, all_pairs=False)
        rpe.process_data((r, e))
        out[key] = {k: float(v) for k, v in rpe.get_all_statistics().items() if k in STATS}
    return out


results = []
for fmt, ref, est in PAIRS:
    for scale in (False, True):
        entry = {"format": fmt, "reference": ref, "estimate": est, "align": "sim3" if scale else "se3"}
        entry.update(run(fmt, ref, est, scale))
        results.append(entry)
json.dump({"evo": "1.38.1", "results": results}, sys.stdout, indent=1)
print()
