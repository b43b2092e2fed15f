#!/usr/bin/env python3
"""Per-pixel mover truth for a recording made by a static camera (issue 80;
`../shared/data/real/ist/confusao`), so that `dopslam run` and `dopslam fuse` report
their masks against it (`dense.json` `truth`: movers kept out, static fused, each mask
source's precision) on real images, as they do on the renders.

The camera stands still, so each pixel's background is a high percentile of its depths
over the sequence (the 95th by default: a thin static object that flickers to the wall
behind it in a few frames keeps its own depth). A pixel of a frame is a mover when its
depth lies more than MARGIN in front of the nearest background in a WINDOW x WINDOW
window (so that a static object's edge, a pixel off, is not one) and within MAX_DEPTH.
Pixels without depth are neither (the dense pass counts only pixels it could fuse). A
person who stands in one place through more than 95 % of the frames is background, as
the map should then hold them; a mover touching a surface (feet on the floor) is static
within MARGIN of it.

OUT is a new folder: a link to each entry of SEQUENCE, and `masks/<timestamp>.png`
(8-bit, 1 where a mover is; the timestamps of `rgb.txt`, each frame's depth map the
nearest in `depth.txt`) with `masks/instances.txt`. SEQUENCE is only read.

    data/venv/bin/python tools/static_camera_truth.py SEQUENCE OUT [--settings S.yaml]
        [--percentile 95] [--margin 0.15] [--window 5] [--max-depth 4.0]
    dopslam fuse RUN --sequence OUT     # or dopslam run OUT

Needs numpy and Pillow (data/venv: `data/venv/bin/pip install pillow`).
"""
import argparse
import os
import sys

import static_camera_ghosts as ghosts

try:
    import numpy as np
    from PIL import Image
except ImportError as e:
    sys.exit(f"static_camera_truth.py needs numpy and Pillow ({e}): data/venv/bin/pip install pillow")


def link_sequence(sequence, out):
    if os.path.exists(out) and os.listdir(out):
        sys.exit(f"{out}: exists and is not empty (give a new folder; nothing was written)")
    os.makedirs(os.path.join(out, "masks"))
    for name in os.listdir(sequence):
        if name != "masks":
            os.symlink(os.path.abspath(os.path.join(sequence, name)), os.path.join(out, name))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence")
    parser.add_argument("out")
    parser.add_argument("--settings", help="an ORB-SLAM2 settings file (its DepthMapFactor; default 5000)")
    parser.add_argument("--percentile", type=float, default=95.0)
    parser.add_argument("--margin", type=float, default=0.15)
    parser.add_argument("--window", type=int, default=5)
    parser.add_argument("--max-depth", type=float, default=4.0)
    args = parser.parse_args()
    if not 50.0 <= args.percentile <= 100.0:
        sys.exit(f"--percentile {args.percentile}: must lie within 50-100 (a mover may cover a pixel in up to half the frames)")
    if args.margin <= 0 or args.window < 1 or args.max_depth <= 0:
        sys.exit("--margin, --window and --max-depth must be positive")
    factor = ghosts.settings(args.settings)[4] if args.settings else 5000.0
    depth_list = ghosts.tum_list(os.path.join(args.sequence, "depth.txt"))
    rgb_times = [t for t, _ in ghosts.tum_list(os.path.join(args.sequence, "rgb.txt"))]
    stack = ghosts.depths(args.sequence, factor)
    near = ghosts.nearest_in_window(ghosts.background(stack, args.percentile), args.window)
    link_sequence(args.sequence, args.out)
    depth_times = np.array([t for t, _ in depth_list])
    movers = in_range = 0
    for t in rgb_times:
        d = stack[int(np.argmin(np.abs(depth_times - t)))]
        ok = (d > 0) & (d <= args.max_depth)
        mover = ok & np.isfinite(near) & (d < near - args.margin)
        Image.fromarray(mover.astype(np.uint8)).save(os.path.join(args.out, "masks", f"{t:.6f}.png"))
        movers += int(mover.sum())
        in_range += int(ok.sum())
    with open(os.path.join(args.out, "masks", "instances.txt"), "w") as f:
        f.write("# static_camera_truth.py: every pixel in front of the static background\n1 person\n")
    print(f"{args.out}: {len(rgb_times)} truth masks; movers are {100.0 * movers / max(in_range, 1):.1f} % of "
          f"the pixels with depth within {args.max_depth} m (background: each pixel's "
          f"{args.percentile:g}th percentile, margin {args.margin} m, window {args.window})")


if __name__ == "__main__":
    main()
