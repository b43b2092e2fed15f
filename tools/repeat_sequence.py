#!/usr/bin/env python3
"""Makes a longer KITTI-layout sequence that drives a rendered one again and again, by
links (for tools/bench_memory.sh's `laps`: three laps of KITTI 00 cost one lap and
one join to render, not three laps and two joins).

The path must repeat: tools/laps_path.py drives each lap and each join pose for pose,
so frame i of the long drive is frame i % PERIOD of the rendered one (PERIOD: a lap
and a join). The path file is read to check that, pose for pose, before anything is
written. The rendered movers repeat with the images: every lap shows the same cars
and people at the same places, which is what a memory benchmark of revisits needs
and no more.

    python3 tools/repeat_sequence.py PATH_FILE --period
    python3 tools/repeat_sequence.py PATH_FILE RENDERED_KITTI_ROOT OUT

The first prints the period (the fewest frames after which the path repeats), the
frames to render; the second links.

RENDERED_KITTI_ROOT is the `kitti` folder of a `dopslam synth` output (sequences/00
with image_0, image_1, times.txt, calib.txt, masks, detections_oracle; poses/00.txt).
OUT must not exist; the second gets OUT/kitti/sequences/00 (links, and times.txt written anew
at the rendered frame rate) and OUT/kitti/poses/00.txt. Nothing is written into the
rendered sequence.
"""

import argparse
import os
import sys


def read_rows(path):
    try:
        with open(path) as f:
            return [line.split() for line in f if line.strip()]
    except OSError as e:
        sys.exit(f"{path}: {e.strerror}")


def period_of(path_rows):
    """The fewest frames after which every pose equals the one that many earlier (the
    same numbers); exits when the path does not repeat at least once."""
    poses = [tuple(float(x) for x in row) for row in path_rows]
    for period in range(1, len(poses)):
        if all(poses[i] == poses[i - period] for i in range(period, len(poses))):
            return period
    sys.exit("the path does not repeat: nothing to link")


def stamp(t):
    return f"{t:.6f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", help="the KITTI pose file the long drive follows")
    parser.add_argument("rendered", nargs="?", help="the synth output's kitti folder")
    parser.add_argument("out", nargs="?")
    parser.add_argument("--period", action="store_true", help="print the period and stop")
    args = parser.parse_args()
    path_rows = read_rows(args.path)
    period = period_of(path_rows)
    if args.period:
        print(period)
        return
    if args.out is None:
        parser.error("RENDERED and OUT are needed to link")
    source = os.path.abspath(os.path.join(args.rendered, "sequences", "00"))
    times = [float(r[0]) for r in read_rows(os.path.join(source, "times.txt"))]
    truth = read_rows(os.path.join(args.rendered, "poses", "00.txt"))
    if len(times) < period or len(truth) < period:
        sys.exit(f"{args.rendered}: {len(times)} frames rendered, fewer than the period {period}")
    if os.path.exists(args.out):
        sys.exit(f"{args.out}: exists; give a new folder")
    frames = len(path_rows)
    step = times[1] - times[0]
    out = os.path.join(args.out, "kitti", "sequences", "00")
    for sub in ("image_0", "image_1", "masks", "detections_oracle"):
        os.makedirs(os.path.join(out, sub))
    os.makedirs(os.path.join(args.out, "kitti", "poses"))
    os.symlink(os.path.join(source, "calib.txt"), os.path.join(out, "calib.txt"))
    with open(os.path.join(out, "times.txt"), "w") as f:
        f.writelines(f"{i * step:e}\n" for i in range(frames))
    with open(os.path.join(args.out, "kitti", "poses", "00.txt"), "w") as f:
        f.writelines(" ".join(truth[i % period]) + "\n" for i in range(frames))
    for i in range(frames):
        j = i % period
        for sub in ("image_0", "image_1"):
            name = f"{j:06d}.png"
            os.symlink(os.path.join(source, sub, name), os.path.join(out, sub, f"{i:06d}.png"))
        for sub, ext in (("masks", "png"), ("detections_oracle", "json")):
            target = os.path.join(source, sub, f"{stamp(times[j])}.{ext}")
            if os.path.exists(target):
                os.symlink(target, os.path.join(out, sub, f"{stamp(i * step)}.{ext}"))
    for name in ("instances.txt",):
        target = os.path.join(source, "masks", name)
        if os.path.exists(target):
            os.symlink(target, os.path.join(out, "masks", name))
    print(f"{frames} frames ({frames / period:.2f} periods of {period}) linked into {out}")


if __name__ == "__main__":
    main()
