#!/usr/bin/env python3
"""Compares the runs of one synthetic preset made by tools/bench_dop.sh.

    python3 tools/dop_compare.py SEQUENCE_DIR RUN_PREFIX [--large 0.2]

Reads RUN_PREFIX-{no-dop,mask-boxes,dop}/report.json and the sequence's oracle boxes
(detections_oracle/, the exact boxes of the movers), and prints one line per mode:
ATE RMSE, keyframes, and over the frames whose dynamic boxes cover at least
--large of the image (by union area): the mean number of keypoints on the static scene
and on movers that took part in the pose, and the mean static keypoints the DOP model
removed. Per-frame counts come from the report's `truth` fields (ground-truth masks).
"""
import argparse
import json
import pathlib
import statistics

DYNAMIC = {"person", "bicycle", "car", "motorcycle", "bus", "truck"}
CELL = 8  # pixels per cell of the coverage raster


def coverage(path, width, height):
    """Fraction of the image covered by the union of the dynamic boxes in `path`."""
    frame = json.loads(path.read_text())
    cols, rows = width // CELL, height // CELL
    covered = set()
    for d in frame["detections"]:
        if d["class"] not in DYNAMIC:
            continue
        x1, y1, x2, y2 = d["box"]
        for r in range(max(0, int(y1 // CELL)), min(rows, int(-(-y2 // CELL)))):
            for c in range(max(0, int(x1 // CELL)), min(cols, int(-(-x2 // CELL)))):
                covered.add((r, c))
    return len(covered) / (cols * rows)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", type=pathlib.Path)
    parser.add_argument("prefix")
    parser.add_argument("--large", type=float, default=0.2)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    args = parser.parse_args()
    oracle = args.sequence / "detections_oracle"
    large = set()
    for path in sorted(oracle.glob("*.json")):
        if coverage(path, args.width, args.height) >= args.large:
            large.add(f"{float(path.stem):.6f}")
    print(f"{args.sequence.name}: {len(large)} frames with dynamic boxes over "
          f"{100 * args.large:.0f} % of the image")
    print(f"  {'mode':11s} {'ATE (m)':>8s} {'kfs':>5s} {'static in pose':>15s} "
          f"{'movers in pose':>15s} {'static removed':>15s}")
    for mode in ("no-dop", "mask-boxes", "dop"):
        report = json.loads(pathlib.Path(f"{args.prefix}-{mode}/report.json").read_text())
        frames = [f for f in report["frames"]
                  if f.get("truth") and f"{f['timestamp']:.6f}" in large]
        ate = (report.get("ate") or {}).get("ape", {}).get("statistics", {}).get("rmse")

        def mean(key):
            return statistics.mean(f["truth"][key] for f in frames) if frames else float("nan")

        ate_text = f"{ate:8.4f}" if ate is not None else f"{'-':>8s}"
        print(f"  {mode:11s} {ate_text} {report['totals']['keyframes']:5d} "
              f"{mean('static_in_pose'):15.1f} {mean('mover_in_pose'):15.1f} "
              f"{mean('static_removed'):15.1f}")


if __name__ == "__main__":
    main()
