"""Compares two raw-output dumps of `cac detect --raw` (or the TFJS reference runner's):
per output, max |a-b| and max |a-b| / max |b| (the conformance measure). Usage: raw_cmp.py A B
Exits 1 when a file cannot be read, or the two do not hold the same outputs and shapes."""
import json
import sys

import numpy as np


def load(path):
    try:
        with open(path) as f:
            return json.load(f)["outputs"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        sys.exit(f"{path}: not a raw-output dump ({e!r})")


a, b = (load(p) for p in sys.argv[1:3])
for name, out in a.items():
    if name not in b or b[name]["shape"] != out["shape"]:
        sys.exit(f"{sys.argv[2]}: no output {name} of shape {out['shape']}")
    x = np.asarray(out["values"], np.float32)
    y = np.asarray(b[name]["values"], np.float32)
    d = float(np.abs(x - y).max()) if x.size else 0.0
    rel = d / max(float(np.abs(y).max()) if y.size else 0.0, 1e-12)
    print(f"{name} {out['shape']}: max|a-b| {d:.3e}, max|a-b|/max|b| {rel:.3e}")
