#!/usr/bin/env python3
"""Benchmark (not a test): the image statistics that tell a render from a real stereo
clip, per sequence in the KITTI layout (image_0 left, image_1 right, calib.txt), so
that a synthetic preset can be set against the real clips it should fail like.

Per sequence, medians over every `--every`-th frame of the left images:
  mean      mean grey level (0-255)
  sky       share of pixels at 230 or brighter (sky, glare)
  flat      share of 16x16 blocks whose grey levels have a standard deviation under 3
            (smooth asphalt, sky: where no corner can be)
  noise     the sensor noise's standard deviation in grey levels (Immerkaer, 1996:
            the image convolved with a mask that cancels smooth structure; edges left
            out)
  sharp     mean absolute Laplacian (focus and motion blur lower it)
  fast20    FAST corners at threshold 20 (ORB-SLAM2's first try), whole image
  fast7     FAST corners at threshold 7 (its fallback in cells that have none)
  dmean     median absolute change of the mean grey level from frame to frame (auto
            exposure)
  disp      OpenCV SGBM disparity (left-right checked): the 10th, 50th and 90th
            percentile of the valid disparities in pixels, and the valid share

  python3 -m venv /tmp/scale && /tmp/scale/bin/pip install numpy opencv-python-headless
  /tmp/scale/bin/python tools/image_stats.py SEQ_DIR [SEQ_DIR ...] [--every 5]

SEQ_DIR is a folder with image_0/ and image_1/ (a KITTI sequence, or a `dopslam synth`
output's kitti/sequences/00). Prints one markdown table row per sequence.
"""
import argparse
import glob
import os

import cv2
import numpy as np


def noise_sigma(image):
    """Immerkaer's fast noise estimate, edges (Sobel magnitude in the top tenth) left
    out."""
    g = image.astype(np.float64)
    mask = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float64)
    response = np.abs(cv2.filter2D(g, -1, mask, borderType=cv2.BORDER_REFLECT))[1:-1, 1:-1]
    edges = np.hypot(cv2.Sobel(g, cv2.CV_64F, 1, 0), cv2.Sobel(g, cv2.CV_64F, 0, 1))[1:-1, 1:-1]
    keep = edges < np.percentile(edges, 90)
    return np.sqrt(np.pi / 2.0) * response[keep].mean() / 6.0


def flat_share(image, block=16, threshold=3.0):
    h, w = (image.shape[0] // block) * block, (image.shape[1] // block) * block
    blocks = image[:h, :w].astype(np.float64).reshape(h // block, block, w // block, block)
    return float((blocks.std(axis=(1, 3)) < threshold).mean())


def disparities(left, right):
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=128, blockSize=5,
                                 P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
                                 disp12MaxDiff=1, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    d = sgbm.compute(left, right).astype(np.float64) / 16.0
    valid = d > 0.5
    return d[valid], float(valid.mean())


def frame_stats(left, right):
    fast = {t: cv2.FastFeatureDetector_create(threshold=t, nonmaxSuppression=True) for t in (20, 7)}
    values, valid = disparities(left, right)
    return {
        "mean": float(left.mean()),
        "sky": float((left >= 230).mean()),
        "flat": flat_share(left),
        "noise": noise_sigma(left),
        "sharp": float(np.abs(cv2.Laplacian(left.astype(np.float64), cv2.CV_64F)).mean()),
        "fast20": len(fast[20].detect(left)),
        "fast7": len(fast[7].detect(left)),
        "d10": float(np.percentile(values, 10)) if values.size else float("nan"),
        "d50": float(np.percentile(values, 50)) if values.size else float("nan"),
        "d90": float(np.percentile(values, 90)) if values.size else float("nan"),
        "valid": valid,
    }


def sequence_stats(folder, every):
    lefts = sorted(glob.glob(os.path.join(folder, "image_0", "*.png")))
    if not lefts:
        raise SystemExit(f"{folder}: no image_0/*.png")
    rows, means = [], []
    for i, path in enumerate(lefts):
        left = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if left is None:
            raise SystemExit(f"{path}: not an image")
        means.append(float(left.mean()))
        if i % every:
            continue
        right = cv2.imread(path.replace("image_0", "image_1"), cv2.IMREAD_GRAYSCALE)
        if right is None:
            raise SystemExit(f"{path}: no right image under image_1")
        rows.append(frame_stats(left, right))
    median = {k: float(np.median([r[k] for r in rows])) for k in rows[0]}
    median["dmean"] = float(np.median(np.abs(np.diff(means)))) if len(means) > 1 else 0.0
    median["frames"] = len(lefts)
    return median


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folders", nargs="+")
    parser.add_argument("--every", type=int, default=5)
    args = parser.parse_args()
    print("| sequence | frames | mean | sky | flat | noise | sharp | fast20 | fast7 | dmean | disp 10/50/90 % (px) | disp valid |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for folder in args.folders:
        s = sequence_stats(folder, max(1, args.every))
        print(f"| {folder} | {s['frames']} | {s['mean']:.0f} | {s['sky']:.3f} | {s['flat']:.3f} | "
              f"{s['noise']:.2f} | {s['sharp']:.1f} | {s['fast20']:.0f} | {s['fast7']:.0f} | "
              f"{s['dmean']:.2f} | {s['d10']:.1f} / {s['d50']:.1f} / {s['d90']:.1f} | {s['valid']:.2f} |")


if __name__ == "__main__":
    main()
