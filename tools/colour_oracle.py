#!/usr/bin/env python3
"""colour-science as the oracle of cac's colour module (tests/printer.rs).

Reads {"pairs": [[[r, g, b], [r, g, b]], ...]} (sRGB display values) on stdin and writes, for
float64 and for float32 arithmetic (colour-science's own float noise), each first colour's
CIELAB (D65) and each pair's CIEDE2000:
{"f64": {"lab": [...], "de2000": [...]}, "f32": {...}, "version": "..."}.

Every step is colour-science's own (the sRGB transfer function, the RGB-to-XYZ matrix derived
from the primaries and the white point, XYZ to CIELAB, CIEDE2000). Its defining constant is the
one the `palette` crate uses: D65 as XYZ (0.95047, 1, 1.08883) rather than colour-science's
default xy (0.3127, 0.3290), which alone moves a* of white by 0.008.
"""
import json
import sys
import warnings

import numpy as np

warnings.filterwarnings("ignore")
import colour  # noqa: E402
from colour.utilities import set_default_float_dtype  # noqa: E402


def run(pairs, dtype):
    set_default_float_dtype(dtype)
    a = np.asarray([p[0] for p in pairs], dtype=dtype)
    b = np.asarray([p[1] for p in pairs], dtype=dtype)
    white = colour.XYZ_to_xy(np.asarray([0.95047, 1.0, 1.08883], dtype=dtype))
    primaries = np.asarray([[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]], dtype=dtype)
    matrix = colour.normalised_primary_matrix(primaries, white)

    def lab(rgb):
        linear = colour.cctf_decoding(rgb, function="sRGB")
        return colour.XYZ_to_Lab(np.einsum("ij,nj->ni", matrix, linear), white)

    la, lb = lab(a), lab(b)
    de = colour.delta_E(la, lb, method="CIE 2000")
    return {"lab": la.astype(float).tolist(), "de2000": np.asarray(de, float).tolist()}


def main():
    pairs = json.load(sys.stdin)["pairs"]
    out = {"f64": run(pairs, np.float64), "f32": run(pairs, np.float32),
           "version": colour.__version__}
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
