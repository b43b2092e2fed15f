#!/usr/bin/env python3
"""Pose-graph benchmark: `dopslam graph optimise` against GTSAM 4.3.0 (PyPI, this
script only) on the same g2o files.

    python3 tools/bench_pose_graph.py [GRAPH.g2o ...] [--runs 3] [--threads 2]

Without files it makes the seeded synthetic sphere (`dopslam graph sphere`, 2500 poses,
4949 edges, like sphere2500). Standard graphs (sphere2500, garage, torus from Carlone's
datasets) can be passed as files. Both solve from the file's initial estimate with
Levenberg-Marquardt and the first pose fixed; both results are scored by GTSAM's own
graph error (half the chi-square, GTSAM's measure), so the costs compare exactly.
Prints the time of each (median of the runs; GTSAM's optimize() call, dopslam's own
timer around its solve, file reading excluded for both), the final cost of each and
their ratios. GTSAM 4.3.0 is installed into data/venv when missing.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VENV_PY = os.path.join(ROOT, "data", "venv", "bin", "python")


def ensure_gtsam():
    try:
        import gtsam  # noqa: F401
        return
    except ImportError:
        pass
    if os.path.exists(VENV_PY) and os.path.realpath(sys.executable) != os.path.realpath(VENV_PY):
        os.execv(VENV_PY, [VENV_PY] + sys.argv)
    if not os.path.exists(VENV_PY):
        subprocess.check_call([sys.executable, "-m", "venv", os.path.join(ROOT, "data", "venv")])
    subprocess.check_call([VENV_PY, "-m", "pip", "install", "-q", "gtsam==4.3.0", "numpy"])
    os.execv(VENV_PY, [VENV_PY] + sys.argv)


def gtsam_solve(path, runs):
    import gtsam
    graph, initial = gtsam.readG2o(path, True)
    first = min(initial.keys())
    graph.add(gtsam.NonlinearEquality(first, initial.atPose3(first)) if hasattr(gtsam, "NonlinearEquality") else
              gtsam.PriorFactorPose3(first, initial.atPose3(first), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    times, result = [], None
    for _ in range(runs):
        params = gtsam.LevenbergMarquardtParams()
        params.setRelativeErrorTol(1e-7)
        params.setAbsoluteErrorTol(1e-9)
        params.setMaxIterations(100)
        start = time.perf_counter()
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        result = optimizer.optimize()
        times.append(time.perf_counter() - start)
        iterations = optimizer.iterations()
    return graph, initial, result, statistics.median(times), iterations


def error_of(graph, path):
    import gtsam
    _, values = gtsam.readG2o(path, True)
    return graph.error(values)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("graphs", nargs="*")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--dopslam", default=os.path.join(ROOT, "target", "release", "dopslam"))
    args = parser.parse_args()
    ensure_gtsam()
    tmp = tempfile.mkdtemp(prefix="bench-graph-")
    graphs = args.graphs
    if not graphs:
        path = os.path.join(tmp, "sphere2500.g2o")
        subprocess.check_call([args.dopslam, "graph", "sphere", path], stdout=subprocess.DEVNULL)
        graphs = [path]
    env = dict(os.environ, RAYON_NUM_THREADS=str(args.threads))
    rows = []
    for path in graphs:
        out = os.path.join(tmp, "ours.g2o")
        ours = []
        for _ in range(args.runs):
            text = subprocess.check_output([args.dopslam, "graph", "optimise", path, "-o", out, "--json"], env=env)
            ours.append(json.loads(text))
        graph, initial, result, gtsam_seconds, gtsam_iterations = gtsam_solve(path, args.runs)
        ours_error = error_of(graph, out)
        row = {
            "graph": os.path.basename(path),
            "poses": ours[0]["poses"],
            "edges": ours[0]["edges"],
            "initial_error": graph.error(initial),
            "gtsam_error": graph.error(result),
            "dopslam_error": ours_error,
            "error_ratio": ours_error / graph.error(result),
            "gtsam_ms": 1e3 * gtsam_seconds,
            "gtsam_iterations": gtsam_iterations,
            "dopslam_ms": statistics.median(o["milliseconds"] for o in ours),
            "dopslam_iterations": ours[0]["iterations"],
        }
        row["time_ratio"] = row["dopslam_ms"] / row["gtsam_ms"]
        rows.append(row)
    print("| graph | poses | edges | GTSAM error | dopslam error | ratio | GTSAM ms (it) | dopslam ms (it) | time ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['graph']} | {r['poses']} | {r['edges']} | {r['gtsam_error']:.4f} | {r['dopslam_error']:.4f} | "
              f"{r['error_ratio']:.5f} | {r['gtsam_ms']:.0f} ({r['gtsam_iterations']}) | {r['dopslam_ms']:.0f} ({r['dopslam_iterations']}) | {r['time_ratio']:.2f} |")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
