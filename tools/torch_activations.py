#!/usr/bin/env python3
"""PyTorch's time for the detectors' hot ops: the peer column of `cac bench kernels`.

Usage: python3 tools/torch_activations.py --shape 1,64,160,160 --threads N --runs K

Times torch.sigmoid, F.silu, F.leaky_relu(0.1), a bias added per channel and dense convolutions of C to C channels (3×3
padded by 1, and 1×1; seeded weights, not trained) forward, and forward + backward of y.sum() to
the input (the weights take no gradient, as in an attack), on a seeded uniform [-6, 6] float32
tensor, fastest of K runs after two warm-ups, with N intra-op threads. Prints one JSON line
{"sigmoid": [fwd_ms, fwd_bwd_ms], ...}.
"""

import argparse
import json
import time

import torch
import torch.nn.functional as F

OPS = {
    "sigmoid": torch.sigmoid,
    "silu": F.silu,
    "leaky_relu": lambda x: F.leaky_relu(x, 0.1),
}


def fastest(fn, runs):
    for _ in range(2):
        fn()
    best = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return round(best * 1e3, 4)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shape", default="1,64,160,160")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--runs", type=int, default=10)
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    g = torch.Generator().manual_seed(0)
    shape = [int(s) for s in a.shape.split(",")]
    x = torch.rand(shape, generator=g) * 12 - 6
    c = shape[1]
    w3 = torch.rand([c, c, 3, 3], generator=g) - 0.5
    w1 = torch.rand([c, c, 1, 1], generator=g) - 0.5
    ops = dict(OPS)
    ops["conv3x3"] = lambda x: F.conv2d(x, w3, padding=1)
    ops["conv1x1"] = lambda x: F.conv2d(x, w1)
    bias = (torch.rand([c], generator=g) - 0.5).view(1, c, 1, 1)
    ops["bias_add"] = lambda x: x + bias
    out = {}
    for name, f in ops.items():
        with torch.no_grad():
            fwd = fastest(lambda: f(x), a.runs)

        def fwd_bwd():
            xg = x.clone().requires_grad_(True)
            f(xg).sum().backward()
            return xg.grad

        out[name] = [fwd, fastest(fwd_bwd, a.runs)]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
