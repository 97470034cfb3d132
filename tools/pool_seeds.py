#!/usr/bin/env python3
"""Pools `cac eval` summaries of several view seeds (same textures and models): per texture,
model and set, P@0.5, drop against the first texture, and targeted success over all images.

    python3 tools/pool_seeds.py runs/eval31 runs/eval1234
"""
import csv
import sys
from collections import defaultdict


def main(dirs):
    tally = defaultdict(lambda: [0, 0.0, 0.0])  # images, hits, targeted
    order = []
    for d in dirs:
        for r in csv.DictReader(open(f"{d}/summary.csv")):
            if r["level"] != "all":
                continue
            key = (r["texture"], r["model"], r["set"])
            if key not in tally:
                order.append(key)
            n = int(r["images"])
            t = tally[key]
            t[0] += n
            t[1] += float(r["p_at_05"]) * n
            t[2] += float(r["targeted_success"]) * n
    base = order[0][0]
    print("| texture | model | P@0.5 FV / RV | drop FV / RV | targeted FV / RV | images per set |")
    print("|---|---|---|---|---|---|")
    textures = list(dict.fromkeys(k[0] for k in order))
    models = list(dict.fromkeys(k[1] for k in order))
    for tex in textures:
        for m in models:
            p = {s: tally[(tex, m, s)][1] / tally[(tex, m, s)][0] for s in ("FV", "RV")}
            o = {s: tally[(base, m, s)][1] / tally[(base, m, s)][0] for s in ("FV", "RV")}
            g = {s: tally[(tex, m, s)][2] / tally[(tex, m, s)][0] for s in ("FV", "RV")}
            print(f"| {tex} | {m} | {p['FV']:.3f} / {p['RV']:.3f} | {o['FV'] - p['FV']:.3f} / "
                  f"{o['RV'] - p['RV']:.3f} | {g['FV']:.3f} / {g['RV']:.3f} | {tally[(tex, m, 'FV')][0]} |")


if __name__ == "__main__":
    main(sys.argv[1:])
