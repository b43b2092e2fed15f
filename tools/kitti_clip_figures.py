#!/usr/bin/env python3
"""Figures of tools/bench_kitti.sh (standard library only).

  kitti_clip_figures.py run BIN KITTI CLIP LABEL RUN_DIR   -> one tab-separated line
  kitti_clip_figures.py table RUNS_TSV...                   -> the markdown table (runs
                                                              of several files pooled),
                                                              then each mode against no-dop

Each mode against no-dop on the same clip: the difference of the ATE medians with a
95 % bootstrap interval (from 8 runs a mode), and the Mann-Whitney test of the two sets
of runs (the share of pairs where the mode's ATE is the larger, and its two-sided p by
permutation; with 3 runs a mode p is never below 0.1). Both are seeded, so the same
runs give the same figures. A variant ("dop, paced as recorded") stands against no-dop
run alike ("no-dop, paced as recorded") where the runs hold it, else against no-dop.
Runs of `bench_kitti.sh --perturbed` ("..., settings varied") pair by settings variant,
which come in the same order in every mode: the last column gives in how many variants
the mode's ATE is the larger, and the median of the differences.
"""
import itertools
import json
import math
import os
import random
import statistics
import subprocess
import sys


def rotation_to_quaternion(m):
    """(qx, qy, qz, qw) of a 3x3 rotation (rows), the largest-diagonal branch."""
    trace = m[0][0] + m[1][1] + m[2][2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        return ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s)
    i = max(range(3), key=lambda k: m[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2.0 * math.sqrt(1.0 + m[i][i] - m[j][j] - m[k][k])
    q = [0.0, 0.0, 0.0, 0.0]
    q[i] = 0.25 * s
    q[j] = (m[j][i] + m[i][j]) / s
    q[k] = (m[k][i] + m[i][k]) / s
    q[3] = (m[k][j] - m[j][k]) / s
    return tuple(q)


def truth_in_tum(kitti, clip, path):
    """The clip's KITTI poses with its times, as a TUM trajectory file at `path`; the
    camera positions."""
    times = [float(t) for t in open(os.path.join(kitti, "sequences", clip, "times.txt"))]
    positions = []
    with open(path, "w") as out:
        for t, line in zip(times, open(os.path.join(kitti, "poses", clip + ".txt"))):
            v = [float(x) for x in line.split()]
            q = rotation_to_quaternion([v[0:3], v[4:7], v[8:11]])
            out.write(f"{t:.6f} {v[3]} {v[7]} {v[11]} {q[0]} {q[1]} {q[2]} {q[3]}\n")
            positions.append((v[3], v[7], v[11]))
    return positions


def path_length(points):
    return sum(math.dist(points[i], points[i + 1]) for i in range(len(points) - 1))


def run_line(binary, kitti, clip, label, run_dir):
    report = json.load(open(os.path.join(run_dir, "report.json")))
    truth_file = os.path.join(run_dir, "truth_tum.txt")
    truth = truth_in_tum(kitti, clip, truth_file)
    estimate = [tuple(float(x) for x in l.split()[1:4])
                for l in open(os.path.join(run_dir, "trajectory.txt")) if not l.startswith("#")]
    sim3 = subprocess.run([binary, "eval", truth_file, os.path.join(run_dir, "trajectory.txt"),
                           "--align", "sim3", "--json"], capture_output=True, text=True)
    ate_sim3 = float("nan")
    if sim3.returncode == 0:
        ate_sim3 = json.loads(sim3.stdout)["ape"]["statistics"]["rmse"]
    ratio = path_length(estimate) / path_length(truth[: len(estimate)])
    totals = report["totals"]
    fields = [clip, label, report["ate"]["ape"]["statistics"]["rmse"], ate_sim3, ratio,
              totals["median_tracking_ms"], totals["tracked"], totals["frames"], totals["keyframes"]]
    print("\t".join(str(f) for f in fields))


def table(tsvs):
    rows = [l.rstrip("\n").split("\t") for tsv in tsvs for l in open(tsv) if l.strip()]
    groups = {}
    for clip, label, ate, sim3, ratio, ms, tracked, frames, keyframes in rows:
        groups.setdefault((clip, label), []).append(
            (float(ate), float(sim3), float(ratio), float(ms), f"{tracked}/{frames}", int(keyframes)))
    print("| clip | mode | runs | ATE RMSE SE(3) (m): median [runs] | ATE Sim(3) (m) | path / true | tracking ms (median) | keyframes (median) | tracked |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (clip, label), runs in groups.items():
        med = lambda k: statistics.median(r[k] for r in runs)
        each = ", ".join(f"{r[0]:.3f}" for r in runs)
        print(f"| KITTI {clip} | {label} | {len(runs)} | {med(0):.3f} [{each}] | {med(1):.3f} | {med(2):.4f} | "
              f"{med(3):.1f} | {med(5):g} | {', '.join(r[4] for r in runs)} |")
    against_no_dop(groups)


def midranks(values):
    """Ranks 1..n of `values`, ties sharing their mean rank."""
    order = sorted(range(len(values)), key=lambda i: values[i])
    ranks = [0.0] * len(values)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and values[order[j + 1]] == values[order[i]]:
            j += 1
        for k in range(i, j + 1):
            ranks[order[k]] = (i + j) / 2 + 1
        i = j + 1
    return ranks


def mann_whitney(a, b, permutations=20000, seed=0):
    """Share of pairs (x in a, y in b) with x > y (ties count a half), and the
    two-sided p of that share over relabellings of the pooled runs: every one when
    there are at most `permutations` (exact), else that many drawn at random."""
    ranks = midranks(a + b)
    na, nb = len(a), len(b)
    offset = na * (na + 1) / 2
    u = sum(ranks[:na]) - offset
    indices = range(na + nb)
    if math.comb(na + nb, na) <= permutations:
        labellings = list(itertools.combinations(indices, na))
    else:
        rng = random.Random(seed)
        labellings = [rng.sample(indices, na) for _ in range(permutations)]
    extreme = sum(abs(sum(ranks[i] for i in picked) - offset - na * nb / 2) >= abs(u - na * nb / 2) - 1e-9
                  for picked in labellings)
    return u / (na * nb), extreme / len(labellings)


# Runs a mode below which no bootstrap interval is given: a bootstrap of a handful of
# runs resamples the same few values, and its interval is too narrow to mean anything.
BOOTSTRAP_RUNS = 8


def bootstrap_interval(a, b, resamples=5000, seed=0):
    """The 95 % bootstrap interval of median(a) - median(b) (each set resampled)."""
    rng = random.Random(seed)
    diffs = sorted(
        statistics.median(rng.choices(a, k=len(a))) - statistics.median(rng.choices(b, k=len(b)))
        for _ in range(resamples))
    return diffs[int(0.025 * resamples)], diffs[int(0.975 * resamples) - 1]


def baseline_of(label, clip, groups):
    """The label `label` stands against: the same variant without DOP (its leading mode,
    `dop` or `mask-boxes`, as `no-dop`) where `groups` holds such runs, else `no-dop`."""
    for mode in ("dop", "mask-boxes"):
        if label.startswith(mode) and label != mode:
            alike = "no-dop" + label[len(mode):]
            if (clip, alike) in groups:
                return alike
    return "no-dop"


def against_no_dop(groups):
    """Each mode's ATE against no-dop's on the same clip (none when a set is too small)."""
    lines = []
    for (clip, label), runs in groups.items():
        against = baseline_of(label, clip, groups)
        base = groups.get((clip, against))
        if label == against or not base or len(runs) < 3 or len(base) < 3:
            continue
        a, b = [r[0] for r in runs], [r[0] for r in base]
        diff = statistics.median(a) - statistics.median(b)
        share, p = mann_whitney(a, b)
        if min(len(a), len(b)) >= BOOTSTRAP_RUNS:
            interval = "[{:+.3f}, {:+.3f}]".format(*bootstrap_interval(a, b))
        else:
            interval = f"(an interval needs {BOOTSTRAP_RUNS} runs a mode)"
        paired = "-"
        if "settings varied" in label and len(a) == len(b):
            worse = sum(x > y for x, y in zip(a, b))
            paired = f"{worse} of {len(a)}, {statistics.median(x - y for x, y in zip(a, b)):+.4f}"
        lines.append(f"| KITTI {clip} | {label} | {against} | {len(a)} / {len(b)} | {diff:+.3f} {interval} | "
                     f"{share:.2f} | {p:.2f} | {paired} |")
    if lines:
        print()
        print("| clip | mode | against | runs | ATE median difference (m) [95 % bootstrap] | "
              "P(mode's ATE > against's) | Mann-Whitney p (two-sided) | "
              "variant by variant: larger in, median difference (m) |")
        print("|---|---|---|---|---|---|---|---|")
        print("\n".join(lines))


if __name__ == "__main__":
    command, rest = (sys.argv[1], sys.argv[2:]) if len(sys.argv) > 1 else ("", [])
    if command in ("-h", "--help"):
        print(__doc__)
    elif command == "run" and len(rest) == 5:
        run_line(*rest)
    elif command == "table" and rest and not rest[0].startswith("-"):
        table(rest)
    else:
        sys.exit(__doc__)
