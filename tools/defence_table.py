#!/usr/bin/env python3
"""Pools `cac eval --defence ...` runs (one per seed) into docs/eval.md's defence table.

usage: tools/defence_table.py EVAL_DIR [EVAL_DIR ...]

Each EVAL_DIR is the --out of one `cac eval` over the same textures, models and defences (one
seed each). Per texture, detector and defence: P@0.5 and the target's success, FV / RV, pooled
over the runs (images added, not rates averaged), and the defence's clean cost (the first
texture's P@0.5 without the defence minus with it). Prints Markdown.
"""
import csv
import sys
from collections import defaultdict


def main(dirs):
    # (texture, model, set) -> [images, hits, targeted]
    acc = defaultdict(lambda: [0, 0.0, 0.0])
    textures, models = [], []
    for d in dirs:
        with open(f"{d}/summary.csv") as f:
            for r in csv.DictReader(f):
                if r["level"] != "all":
                    continue
                n = int(r["images"])
                a = acc[(r["texture"], r["model"], r["set"])]
                a[0] += n
                a[1] += float(r["p_at_05"]) * n
                a[2] += float(r["targeted_success"]) * n
                if r["texture"] not in textures:
                    textures.append(r["texture"])
                if r["model"] not in models:
                    models.append(r["model"])

    def rate(t, m, s, k):
        a = acc.get((t, m, s))
        return a[k] / a[0] if a and a[0] else float("nan")

    clean = textures[0]
    bases = [m for m in models if "+" not in m]
    heads = ["detector", "defence", f"{clean} P@0.5 FV / RV", "clean cost FV / RV"]
    for t in textures[1:]:
        heads += [f"{t} P@0.5 FV / RV", f"{t} target FV / RV"]
    print("| " + " | ".join(heads) + " |")
    print("|" + "---|" * len(heads))
    for b in bases:
        for m in [x for x in models if x == b or x.startswith(b + "+")]:
            name = m[len(b) + 1:] if m != b else "none"
            row = [b, name]
            p = [rate(clean, m, s, 1) for s in ("FV", "RV")]
            p0 = [rate(clean, b, s, 1) for s in ("FV", "RV")]
            row.append(f"{p[0]:.3f} / {p[1]:.3f}")
            row.append("–" if m == b else f"{p0[0] - p[0]:+.3f} / {p0[1] - p[1]:+.3f}")
            for t in textures[1:]:
                row.append(f"{rate(t, m, 'FV', 1):.3f} / {rate(t, m, 'RV', 1):.3f}")
                row.append(f"{rate(t, m, 'FV', 2):.3f} / {rate(t, m, 'RV', 2):.3f}")
            print("| " + " | ".join(row) + " |")
    n = {s: acc[(clean, bases[0], s)][0] for s in ("FV", "RV")}
    print(f"\n{n['FV']} / {n['RV']} images per texture and detector (FV / RV), {len(dirs)} run(s).")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
