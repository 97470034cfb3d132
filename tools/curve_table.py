#!/usr/bin/env python3
"""The knob table of docs/attack.md from run folders' curve.csv (cac train --eval-every).

For each run: the training seconds and iteration at which the curve first reaches the goal
(source P@0.5 <= 0.1 and targeted success >= 0.7 in both viewpoint sets), and the last point's
figures (source and transfer model, FV / RV), with the run's iterations and median iteration time.

    python3 tools/curve_table.py runs/knobs/base runs/knobs/r512 ...
"""
import csv
import json
import statistics
import sys
from collections import defaultdict
from pathlib import Path


def points(run: Path):
    """{(iteration, train_s): {(model, set): (p, target)}} in training order."""
    out = defaultdict(dict)
    with open(run / "curve.csv") as f:
        for r in csv.DictReader(f):
            key = (int(r["iteration"]), float(r["train_s"]))
            out[key][(r["model"], r["set"])] = (float(r["p_at_05"]), float(r["targeted_success"]))
    return sorted(out.items())


def reached(figs, source, p_max=0.1, target_min=0.7):
    return all(
        figs[(source, s)][0] <= p_max and figs[(source, s)][1] >= target_min for s in ("FV", "RV")
    )


def main(runs):
    print("| run | flags | iterations | median ms/iteration | goal reached at (s / iteration) "
          "| source P@0.5 FV / RV at the end | source target FV / RV | transfer P@0.5 FV / RV "
          "| transfer target FV / RV |")
    print("|---|---|---:|---:|---|---|---|---|---|")
    for run in map(Path, runs):
        meta = json.load(open(run / "run.json"))
        pts = points(run)
        models = sorted({m for _, f in pts for (m, _) in f})
        source = meta["attack"]["models"][0]
        transfer = next((m for m in models if m != source), None)
        hit = next(((t, i) for (i, t), f in pts if reached(f, source)), None)
        (i_end, t_end), last = pts[-1]
        ms = statistics.median(
            l["ms_render"] + l["ms_forward"] + l["ms_backward"] + l["ms_optimiser"] for l in meta["log"]
        )
        fmt = lambda m, k: " / ".join(f"{last[(m, s)][k]:.2f}" for s in ("FV", "RV")) if m else "-"
        when = f"{hit[0]:.0f} s / {hit[1]}" if hit else "not reached"
        flags = run.name
        print(f"| {run.name} | {flags} | {i_end} | {ms:.0f} | {when} | {fmt(source, 0)} | "
              f"{fmt(source, 1)} | {fmt(transfer, 0)} | {fmt(transfer, 1)} |")


if __name__ == "__main__":
    main(sys.argv[1:])
