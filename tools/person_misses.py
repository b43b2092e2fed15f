#!/usr/bin/env python3
"""What the people missed on keyframes were, from run reports (`dopslam run` on a
synthetic sequence writes `detection.person_recall.misses`: each missed person's true
box, its share of the image and the best dynamic box's IoU with it).

    python3 tools/person_misses.py RUN_DIR [RUN_DIR ...] [--width 640 --height 480]

Prints, per run and over all runs, the person recall and the misses by kind:
- border sliver: touches the image border and is under 50 pixels wide (a shoulder or an
  arm of a person walking in or out of view);
- border: touches the border, wider;
- overlapped: a dynamic box covers it with IoU 0.2-0.5 (mostly the visible part of a
  person behind a closer one: the true box is the visible part, the detector's box the
  whole person, or one box holds both);
- other.

Standard library only.
"""
import argparse
import collections
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--width", type=float, default=640)
    ap.add_argument("--height", type=float, default=480)
    args = ap.parse_args()
    total = collections.Counter()
    print("| run | people | found | recall | " + " | ".join(KINDS) + " |")
    print("|---|---|---|---|" + "---|" * len(KINDS))
    for run in args.runs:
        path = os.path.join(run, "report.json")
        try:
            with open(path) as f:
                recall = json.load(f)["detection"].get("person_recall")
        except (OSError, ValueError, KeyError) as e:
            raise SystemExit(f"{path}: cannot read the report ({e})")
        if not recall or "misses" not in recall:
            print(f"| {run} | no person recall in the report (no ground-truth masks?) |")
            continue
        kinds = collections.Counter(kind(m, args.width, args.height) for m in recall["misses"])
        total.update(kinds)
        total["people"] += recall["people"]
        total["found"] += recall["found"]
        print(
            f"| {run} | {recall['people']} | {recall['found']} | {recall['recall']:.3f} | "
            + " | ".join(str(kinds[k]) for k in KINDS)
            + " |"
        )
    if total["people"]:
        print(
            f"| all | {total['people']} | {total['found']} | "
            f"{total['found'] / total['people']:.3f} | "
            + " | ".join(str(total[k]) for k in KINDS)
            + " |"
        )


if __name__ == "__main__":
    main()
