#!/usr/bin/env python3
"""The tables of tools/bench_dense_pass.sh (issue 80): per run and variant, the masks
against the truth (goals: masked pixels <= 1.5 x mover pixels + 2 % of the image,
static fused >= 90 %, mesh vertices on movers <= 0.1 %, movers kept out >= 99.5 %),
each mask source's share of the pixels and precision, and where the dense pass's time
went beside the tracking pass's.

    python3 tools/dense_pass_table.py ROWS.jsonl

Standard library only.
"""
import json
import sys

STAGES = ["inputs_s", "detections_s", "allocation_s", "loading_s", "free_space_s", "masks_s",
          "truth_s", "integration_s", "cloud_frames_s", "mesh_s", "cloud_s", "writing_s"]


def masks(rows):
    print("| run | variant | frames | ATE (mm) | mover px % | masked % (all / with depth) | goal % | "
          "movers kept out | static fused | mesh vertices on movers % | released px |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        goal = 1.5 * r["mover_percent"] + 2.0
        mesh = 100.0 * r["mesh_mover_vertices"] / max(r["mesh_vertices"], 1)
        print(f"| {r['preset']}-{r['seed']} | {r['variant']} | {r['frames']} | {r['ate_mm']:.1f} | "
              f"{r['mover_percent']:.1f} | {r['masked_percent']:.1f} / {r['masked_depth_percent']:.1f} | "
              f"{goal:.1f} | {r['movers_kept_out']:.4f} | {r['static_fused']:.4f} | {mesh:.3f} | "
              f"{r['released']} |")


def sources(rows):
    print()
    print("| run | variant | source | % of pixels | precision | alone % of pixels | alone precision |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        for s in r["sources"]:
            if s["pixels"] == 0:
                continue
            share = s["percent_of_pixels"]
            alone = share * s["only_pixels"] / max(s["pixels"], 1)
            alone_precision = s["only_mover_pixels"] / max(s["only_pixels"], 1)
            print(f"| {r['preset']}-{r['seed']} | {r['variant']} | {s['source']} | {share:.2f} | "
                  f"{s['precision']:.3f} | {alone:.2f} | {alone_precision:.3f} |")


def times(rows):
    print()
    names = [s[:-2].replace("_", " ") for s in STAGES]
    print("| run | variant | recording s | tracking s | dense s | dense / tracking | "
          + " | ".join(names) + " |")
    print("|---|---|---|---|---|---|" + "---|" * len(STAGES))
    for r in rows:
        stages = r.get("stages") or {}
        tracking = r.get("tracking_s")
        ratio = f"{r['dense_s'] / tracking:.2f}" if tracking else "-"
        cells = [f"{stages.get(s, 0.0):.1f}" for s in STAGES]
        recording = r.get("recording_s")
        first = [f"{r['preset']}-{r['seed']}", r["variant"],
                 f"{recording:.1f}" if recording else "-", f"{tracking:.1f}" if tracking else "-",
                 f"{r['dense_s']:.1f}", ratio]
        print("| " + " | ".join(first + cells) + " |")


def main():
    rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
    masks(rows)
    sources(rows)
    times(rows)


if __name__ == "__main__":
    main()
