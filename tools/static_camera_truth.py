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

`--without-movers DIR` also writes DIR (a new folder): the recording with the movers'
pixels cleared from every depth map (0: no depth; the colour images keep the people),
links to the rest and to OUT's masks. Fused without masks (`dopslam run DIR --no-dop`),
it is the map of the static scene alone, the reference for a map's figures against the
background: what a perfect mask would leave.

    data/venv/bin/python tools/static_camera_truth.py SEQUENCE OUT [--settings S.yaml]
        [--percentile 95] [--margin 0.15] [--window 5] [--max-depth 4.0]
        [--without-movers DIR]
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


def refuse_filled(out):
    if os.path.exists(out) and os.listdir(out):
        sys.exit(f"{out}: exists and is not empty (give a new folder; nothing was written)")


def link_sequence(sequence, out, own):
    """Links OUT's entries to SEQUENCE's, but for the folder `own` (made empty)."""
    os.makedirs(os.path.join(out, own))
    for name in os.listdir(sequence):
        if name not in ("masks", own):
            os.symlink(os.path.abspath(os.path.join(sequence, name)), os.path.join(out, name))


def check_depth_names(sequence, depth_list):
    """--without-movers writes the depth maps into its own depth/: they must lie there."""
    for _, name in depth_list:
        if os.path.dirname(os.path.normpath(name)) != "depth":
            sys.exit(f"{sequence}/depth.txt: {name} does not lie in depth/ "
                     "(--without-movers writes only there; nothing was written)")


def without_movers(sequence, out, masks, depth_list, movers):
    """Writes OUT: SEQUENCE's depth maps with `movers` (per depth map) cleared."""
    link_sequence(sequence, out, "depth")
    os.symlink(os.path.abspath(masks), os.path.join(out, "masks"))
    for (_, name), mover in zip(depth_list, movers):
        raw = np.array(Image.open(os.path.join(sequence, name)))
        raw[mover] = 0
        Image.fromarray(raw).save(os.path.join(out, name))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence")
    parser.add_argument("out")
    parser.add_argument("--settings", help="an ORB-SLAM2 settings file (its DepthMapFactor; default 5000)")
    parser.add_argument("--percentile", type=float, default=95.0)
    parser.add_argument("--margin", type=float, default=0.15)
    parser.add_argument("--window", type=int, default=5)
    parser.add_argument("--max-depth", type=float, default=4.0)
    parser.add_argument("--without-movers", metavar="DIR",
                        help="also the recording with the movers cleared from its depth maps")
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
    for folder in filter(None, [args.out, args.without_movers]):
        refuse_filled(folder)
    if args.without_movers:
        if os.path.abspath(args.without_movers) == os.path.abspath(args.out):
            sys.exit("--without-movers must name another folder than OUT")
        check_depth_names(args.sequence, depth_list)
    link_sequence(args.sequence, args.out, "masks")
    depth_times = np.array([t for t, _ in depth_list])
    in_range = [(d > 0) & (d <= args.max_depth) for d in stack]
    mover = [ok & np.isfinite(near) & (d < near - args.margin) for d, ok in zip(stack, in_range)]
    movers = pixels = 0
    for t in rgb_times:
        k = int(np.argmin(np.abs(depth_times - t)))
        Image.fromarray(mover[k].astype(np.uint8)).save(os.path.join(args.out, "masks", f"{t:.6f}.png"))
        movers += int(mover[k].sum())
        pixels += int(in_range[k].sum())
    with open(os.path.join(args.out, "masks", "instances.txt"), "w") as f:
        f.write("# static_camera_truth.py: every pixel in front of the static background\n1 person\n")
    if args.without_movers:
        without_movers(args.sequence, args.without_movers, os.path.join(args.out, "masks"), depth_list, mover)
        print(f"{args.without_movers}: the recording without its movers' depth")
    print(f"{args.out}: {len(rgb_times)} truth masks; movers are {100.0 * movers / max(pixels, 1):.1f} % of "
          f"the pixels with depth within {args.max_depth} m (background: each pixel's "
          f"{args.percentile:g}th percentile, margin {args.margin} m, window {args.window})")


if __name__ == "__main__":
    main()
