#!/usr/bin/env python3
"""Checks a finished `dopslam batch` folder: every successful run's ATE RMSE (run.json,
results) equals `dopslam eval` on the same files and, where evo is installed, `evo_ape`
(nearest-timestamp association within 0.01 s, SE(3) Umeyama alignment, translation).

Usage: python3 tools/check_batch.py OUT [--dopslam target/release/dopslam]
Exit status 1 on a mismatch. evo: `data/venv/bin/pip install evo==1.38.1`, then run
this script with data/venv/bin/python3.
"""
import argparse
import json
import subprocess
import sys
from pathlib import Path

try:
    from evo.core import metrics, sync
    from evo.tools import file_interface
except ImportError:  # evo is optional
    metrics = None


def evo_ape(reference: Path, estimate: Path) -> float:
    r = file_interface.read_tum_trajectory_file(str(reference))
    e = file_interface.read_tum_trajectory_file(str(estimate))
    r, e = sync.associate_trajectories(r, e, max_diff=0.01)
    e.align(r, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((r, e))
    return ape.get_statistic(metrics.StatisticsType.rmse)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out")
    parser.add_argument("--dopslam", default="target/release/dopslam")
    args = parser.parse_args()
    out = Path(args.out)
    checked = mismatches = 0
    print(f"{'run':45s} {'batch':>10s} {'dopslam eval':>13s} {'evo_ape':>10s}")
    for record_path in sorted(out.glob("runs/*/*/r*/run.json")):
        record = json.loads(record_path.read_text())
        ate = (record.get("figures") or {}).get("ate_rmse")
        if record["status"] != "ok" or ate is None:
            continue
        run = record_path.parent
        report = json.loads((run / "report.json").read_text())
        reference = Path(report["sequence_path"]) / "groundtruth.txt"
        estimate = run / "trajectory.txt"
        result = subprocess.run(
            [args.dopslam, "eval", str(reference), str(estimate), "--json", "--min-coverage", "0"],
            check=True, capture_output=True, text=True)
        ours = json.loads(result.stdout)["ape"]["statistics"]["rmse"]
        theirs = evo_ape(reference, estimate) if metrics else float("nan")
        ok = abs(ours - ate) < 1e-12 and (metrics is None or abs(theirs - ate) < 1e-6)
        checked += 1
        mismatches += not ok
        label = str(run.relative_to(out / "runs"))
        print(f"{label:45s} {ate:10.6f} {ours:13.6f} {theirs:10.6f} {'' if ok else 'MISMATCH'}")
    print(f"{checked} runs checked, {mismatches} mismatches"
          + ("" if metrics else " (evo not installed: compared with dopslam eval only)"))
    return 1 if mismatches or not checked else 0


if __name__ == "__main__":
    sys.exit(main())
