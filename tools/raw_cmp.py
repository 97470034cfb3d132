"""Compares two raw-output dumps of `cac detect --raw` (or the TFJS reference runner's):
per output, max |a-b| and max |a-b| / max |b| (the conformance measure). Usage: raw_cmp.py A B"""
import json
import sys

import numpy as np

a, b = (json.load(open(p)) for p in sys.argv[1:3])
for name, out in a["outputs"].items():
    x = np.asarray(out["values"], np.float32)
    y = np.asarray(b["outputs"][name]["values"], np.float32)
    d = np.abs(x - y).max() if x.size else 0.0
    rel = d / max(float(np.abs(y).max()) if y.size else 0.0, 1e-12)
    print(f"{name} {out['shape']}: max|a-b| {d:.3e}, max|a-b|/max|b| {rel:.3e}")
