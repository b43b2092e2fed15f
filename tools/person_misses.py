#!/usr/bin/env python3
"""What the people missed on keyframes were, from run reports (`dopslam run` on a
synthetic sequence writes `detection.person_recall.misses`: each missed person's true
box, its share of the image and the best dynamic box's IoU with it).

    python3 tools/person_misses.py RUN_DIR [RUN_DIR ...] [--width 640 --height 480]
                                   [--motion [SECONDS]]

Prints, per run and over all runs, the person recall and the misses by kind:
- border sliver: touches the image border and is under 50 pixels wide (a shoulder or an
  arm of a person walking in or out of view);
- border: touches the border, wider;
- overlapped: a dynamic box covers it with IoU 0.2-0.5 (mostly the visible part of a
  person behind a closer one: the true box is the visible part, the detector's box the
  whole person, or one box holds both);
- other.

With --motion, each miss at the border under 80 pixels wide is also looked up in the
sequence's oracle boxes (`detections_oracle/`, by instance) SECONDS (default 2) either
side: entering (seen whole, away from the border, only after), leaving (only before),
both, or neither. A person entering was seen by no keyframe before, so no followed
object can give it a box in the tracking pass.

Standard library only.
"""
import argparse
import bisect
import collections
import functools
import glob
import json
import os

KINDS = ("border sliver", "border", "overlapped", "other")


def kind(miss, width, height):
    x1, y1, x2, y2 = miss["person"]
    border = x1 <= 1 or y1 <= 1 or x2 >= width - 1 or y2 >= height - 1
    if border and x2 - x1 < 50:
        return "border sliver"
    if miss["best_iou"] >= 0.2:
        return "overlapped"
    return "border" if border else "other"


MOTIONS = ("entering", "leaving", "both", "neither")


def oracle(sequence):
    """The oracle boxes of a sequence: (sorted timestamps, their files)."""
    files = sorted(glob.glob(os.path.join(sequence, "detections_oracle", "*.json")))
    return [float(os.path.basename(f)[:-5]) for f in files], files


@functools.lru_cache(maxsize=4096)
def people_in(path):
    """The oracle person boxes of one frame (each read once: the windows of nearby
    misses overlap)."""
    with open(path) as f:
        return [d for d in json.load(f)["detections"] if d["class"] == "person"]


def motion(miss, frames, seconds, width):
    """How the person of a border miss moves: see the module doc; None when it is not
    such a miss or its oracle box is not found."""
    x1, _, x2, _ = miss["person"]
    if not (x1 <= 1 or x2 >= width - 1) or x2 - x1 >= 80:
        return None
    times, files = frames
    t = miss["timestamp"]
    i = bisect.bisect_left(times, t - 1e-4)
    if i >= len(files):
        return None
    same = [
        d.get("instance")
        for d in people_in(files[i])
        if abs(d["box"][0] - x1) < 3 and abs(d["box"][2] - x2) < 3
    ]
    if not same:
        return "neither"

    def whole(j):
        return any(
            d.get("instance") == same[0]
            and d["box"][0] > 5
            and d["box"][2] < width - 5
            and d["box"][2] - d["box"][0] > 80
            for d in people_in(files[j])
        )

    before = any(whole(j) for j in range(bisect.bisect_left(times, t - seconds), i))
    after = any(whole(j) for j in range(i + 1, bisect.bisect_right(times, t + seconds)))
    return {(True, True): "both", (True, False): "leaving", (False, True): "entering"}.get(
        (before, after), "neither"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--width", type=float, default=640)
    ap.add_argument("--height", type=float, default=480)
    ap.add_argument("--motion", type=float, nargs="?", const=2.0, default=None)
    args = ap.parse_args()
    columns = KINDS + (MOTIONS if args.motion is not None else ())
    total = collections.Counter()
    print("| run | people | found | recall | " + " | ".join(columns) + " |")
    print("|---|---|---|---|" + "---|" * len(columns))
    for run in args.runs:
        path = os.path.join(run, "report.json")
        try:
            with open(path) as f:
                report = json.load(f)
            recall = report["detection"].get("person_recall")
        except (OSError, ValueError, KeyError) as e:
            raise SystemExit(f"{path}: cannot read the report ({e})")
        if not recall or "misses" not in recall:
            print(f"| {run} | no person recall in the report (no ground-truth masks?) |")
            continue
        kinds = collections.Counter(kind(m, args.width, args.height) for m in recall["misses"])
        if args.motion is not None:
            frames = oracle(report.get("sequence_path", ""))
            if not frames[1]:
                raise SystemExit(f"{path}: no oracle boxes under its sequence_path")
            kinds.update(
                m for m in (motion(x, frames, args.motion, args.width) for x in recall["misses"]) if m
            )
        total.update(kinds)
        total["people"] += recall["people"]
        total["found"] += recall["found"]
        print(
            f"| {run} | {recall['people']} | {recall['found']} | {recall['recall']:.3f} | "
            + " | ".join(str(kinds[k]) for k in columns)
            + " |"
        )
    if total["people"]:
        print(
            f"| all | {total['people']} | {total['found']} | "
            f"{total['found'] / total['people']:.3f} | "
            + " | ".join(str(total[k]) for k in columns)
            + " |"
        )


if __name__ == "__main__":
    main()
