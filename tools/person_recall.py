#!/usr/bin/env python3
"""Person recall of a detector against a synthetic sequence's oracle boxes.

    python3 tools/person_recall.py ORACLE_DIR FOUND_DIR [--log DETECT_LOG] [--min-area 0.01]
        [--width 640 --height 480] [--misses N]

ORACLE_DIR is a sequence's `detections_oracle/` (tight boxes from the true masks), FOUND_DIR
the `detections/` that `dopslam detect` wrote for the same frames (several folders, comma
separated: the union of their boxes, as an ensemble would give). A person counts when its
box covers at least MIN_AREA of the image; it is found when a person detection overlaps it
with IoU >= 0.5 (the issue's measure, as `detection.person_recall` in a run's report).
Prints the recall overall, by box size, by box height (< 40, 40-80, 80-160, > 160 px)
and for boxes cut by the image border, the person
boxes found on no true person (IoU under 0.1 with every oracle person, of any size: false
alarms), the median inference time read from the detect log, and the largest misses.
"""
import argparse
import json
import os
import re
import statistics


def iou(a, b):
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h
    return w * h / union if union > 0 else 0.0


def people(path):
    with open(path) as f:
        return [d["box"] for d in json.load(f)["detections"] if d["class"] == "person"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("oracle")
    ap.add_argument("found")
    ap.add_argument("--log", help="the `dopslam detect` output, for the inference times")
    ap.add_argument("--min-area", type=float, default=0.01)
    ap.add_argument("--width", type=float, default=640)
    ap.add_argument("--height", type=float, default=480)
    ap.add_argument("--misses", type=int, default=0, help="list the N largest misses")
    ap.add_argument("--label", default="")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = ap.parse_args()
    image_area = args.width * args.height
    bins = [(0.01, 0.05), (0.05, 0.2), (0.2, 1.01)]
    hits = total = 0
    by_bin = {b: [0, 0] for b in bins}
    heights = [(0, 40), (40, 80), (80, 160), (160, 1e9)]
    by_height = {b: [0, 0] for b in heights}
    border = [0, 0]
    misses = []
    boxes = false_alarms = 0
    for name in sorted(os.listdir(args.found.split(",")[0])):
        oracle = os.path.join(args.oracle, name)
        if not os.path.isfile(oracle):
            continue
        found = [b for d in args.found.split(",") if os.path.isfile(os.path.join(d, name))
                 for b in people(os.path.join(d, name))]
        truth = people(oracle)
        boxes += len(found)
        false_alarms += sum(all(iou(t, f) < 0.1 for t in truth) for f in found)
        for t in truth:
            share = (t[2] - t[0]) * (t[3] - t[1]) / image_area
            if share < args.min_area:
                continue
            ok = any(iou(t, f) >= 0.5 for f in found)
            total += 1
            hits += ok
            for b in bins:
                if b[0] <= share < b[1]:
                    by_bin[b][0] += ok
                    by_bin[b][1] += 1
            for lo, hi in heights:
                if lo <= t[3] - t[1] < hi:
                    by_height[(lo, hi)][0] += ok
                    by_height[(lo, hi)][1] += 1
            cut = t[0] <= 1 or t[1] <= 1 or t[2] >= args.width - 1 or t[3] >= args.height - 1
            if cut:
                border[0] += ok
                border[1] += 1
            if not ok:
                best = max((iou(t, f) for f in found), default=0.0)
                misses.append((share, name, [round(v) for v in t], round(best, 2)))

    def rate(h, n):
        return f"{h}/{n} = {h / n:.3f}" if n else "-"

    if args.json:
        print(json.dumps(dict(
            label=args.label, recall=hits / total if total else None, people=total,
            by_height={f"{lo}-{hi if hi < 1e9 else ''}": (h / n if n else None, n)
                       for (lo, hi), (h, n) in by_height.items()},
            false_alarms=false_alarms, boxes=boxes)))
        return
    line = f"{args.label:24s} person recall {rate(hits, total)}"
    line += "; by share of the image: " + ", ".join(
        f"{int(100 * lo)}-{min(100, int(100 * hi))} % {rate(*by_bin[(lo, hi)])}" for lo, hi in bins)
    line += "; by height: " + ", ".join(
        f"{lo}-{hi if hi < 1e9 else ''} px {rate(*by_height[(lo, hi)])}" for lo, hi in heights)
    line += f"; cut by the border {rate(*border)}"
    line += f"; person boxes on no person {false_alarms} of {boxes}"
    if args.log:
        with open(args.log) as f:
            times = [float(m) for m in re.findall(r"\(([0-9.]+) ms\)", f.read())]
        if times:
            line += f"; median inference {statistics.median(times):.1f} ms"
    print(line)
    for share, name, box, best in sorted(misses, reverse=True)[: args.misses]:
        print(f"  missed {name}: {100 * share:.0f} % of the image, box {box}, best IoU {best}")


if __name__ == "__main__":
    main()
