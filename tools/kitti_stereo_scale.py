#!/usr/bin/env python3
"""Benchmark (not a test): what a real KITTI clip's own stereo geometry says about its
scale, independently of dopslam. For each frame pair (t, t+1): OpenCV's SGBM depth at t,
OpenCV ORB matches from t to t+1 (ratio 0.8), solvePnPRansac + solvePnPRefineLM; the
estimated translation over the ground truth's. A constant disparity error makes this
ratio grow with the depth of the points used (docs/design.md, "Stereo on real images").

  python3 -m venv /tmp/scale && /tmp/scale/bin/pip install numpy opencv-python-headless
  /tmp/scale/bin/python tools/kitti_stereo_scale.py [--clips 01 06] [--max-depth 12 20 30 0]

Reads ../shared/data/real/kitti (or DOPSLAM_SHARED_DATA/real/kitti); the calibration from
each clip's calib.txt (P0: fx, cx, cy; P1: -fx b). --max-depth 0: every point.
"""
import argparse
import os

import cv2
import numpy as np


def calibration(clip_dir):
    rows = {}
    for line in open(os.path.join(clip_dir, "calib.txt")):
        key, _, rest = line.partition(":")
        rows[key.strip()] = [float(x) for x in rest.split()]
    p0, p1 = rows["P0"], rows["P1"]
    return p0[0], p0[2], p0[6], -p1[3]


def ratios(kitti, clip, max_depth):
    clip_dir = os.path.join(kitti, "sequences", clip)
    fx, cx, cy, bf = calibration(clip_dir)
    camera = np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1.0]])
    truth = [np.vstack([np.array([float(x) for x in l.split()]).reshape(3, 4), [0, 0, 0, 1]])
             for l in open(os.path.join(kitti, "poses", clip + ".txt"))]
    image = lambda c, i: cv2.imread(os.path.join(clip_dir, f"image_{c}", f"{i:06d}.png"), 0)
    sgbm = cv2.StereoSGBM_create(0, 128, 5, 8 * 25, 32 * 25, 1, 0, 10, 100, 2, cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    orb = cv2.ORB_create(3000)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    out = []
    for i in range(len(truth) - 1):
        left, right, following = image(0, i), image(1, i), image(0, i + 1)
        disparity = sgbm.compute(left, right).astype(np.float32) / 16
        k0, d0 = orb.detectAndCompute(left, None)
        k1, d1 = orb.detectAndCompute(following, None)
        points, pixels = [], []
        for m in matcher.knnMatch(d0, d1, k=2):
            if len(m) < 2 or m[0].distance > 0.8 * m[1].distance:
                continue
            x, y = k0[m[0].queryIdx].pt
            d = disparity[int(round(y)), int(round(x))]
            if d <= 1:
                continue
            z = bf / d
            if max_depth > 0 and z > max_depth:
                continue
            points.append([(x - cx) * z / fx, (y - cy) * z / fx, z])
            pixels.append(k1[m[0].trainIdx].pt)
        points, pixels = np.array(points), np.array(pixels)
        if len(points) < 6:
            continue  # too few points that near: the pair is left out (see the count)
        found, rvec, tvec, inliers = cv2.solvePnPRansac(points, pixels, camera, None, reprojectionError=1.0,
                                                        iterationsCount=500, flags=cv2.SOLVEPNP_ITERATIVE)
        if not found or inliers is None:
            continue
        inliers = inliers[:, 0]
        rvec, tvec = cv2.solvePnPRefineLM(points[inliers], pixels[inliers], camera, None, rvec, tvec)
        relative = np.linalg.inv(truth[i + 1]) @ truth[i]
        out.append(np.linalg.norm(tvec) / np.linalg.norm(relative[:3, 3]))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", nargs="+", default=["01", "06"])
    parser.add_argument("--max-depth", nargs="+", type=float, default=[12, 20, 30, 0])
    args = parser.parse_args()
    shared = os.environ.get("DOPSLAM_SHARED_DATA", os.path.join(os.path.dirname(__file__), "../../shared/data"))
    kitti = os.path.join(shared, "real/kitti")
    print("| clip | points nearer than | frame pairs | translation / truth (median) |")
    print("|---|---|---|---|")
    for clip in args.clips:
        for max_depth in args.max_depth:
            r = ratios(kitti, clip, max_depth)
            limit = f"{max_depth:g} m" if max_depth > 0 else "all"
            print(f"| KITTI {clip} | {limit} | {len(r)} | {np.median(r):.3f} |")


if __name__ == "__main__":
    main()
