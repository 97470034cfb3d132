#!/usr/bin/env python3
"""PyTorch's side of cac's benchmarks, timed on the CPU with a fixed thread count.

Usage:
  python3 tools/torch_bench.py ops --shape 1,64,160,160 --threads N --runs K
  python3 tools/torch_bench.py onnx MODEL --shape 1,3,640,640 --threads N --runs K

`ops` (the peer column of `cac bench kernels`): torch.sigmoid, F.silu, F.leaky_relu(0.1), a bias
added per channel and dense convolutions of C to C channels (3×3 padded by 1, and 1×1; seeded
weights) on a seeded uniform [-6, 6] float32 tensor. Prints one JSON line
{"sigmoid": [fwd_ms, fwd_bwd_ms], ...}.

`onnx` (the PyTorch columns of `cac bench detect --onnx`): MODEL converted by onnx2torch
(opset-12 exports convert; opset 18's Split does not) on a seeded uniform [0, 1) input. Prints
{"threads": N, "forward_ms": .., "forward_backward_ms": ..}, or {"error": ".."} when the model
does not convert or run.

Both time the forward pass (no gradient) and the forward pass plus the backward pass of the
(first) output's sum to the input (weights take no gradient, as in an attack), fastest of K runs
after two warm-ups.
"""

import argparse
import json
import time

import torch
import torch.nn.functional as F


def fastest(fn, runs):
    for _ in range(2):
        fn()
    best = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return round(best * 1e3, 4)


def forward_backward(f, x, runs):
    """(forward ms, forward + backward ms) of y = f(x), backward of the first output's sum."""

    def first(out):
        return out[0] if isinstance(out, (list, tuple)) else out

    with torch.no_grad():
        fwd = fastest(lambda: f(x), runs)

    def both():
        xg = x.clone().requires_grad_(True)
        first(f(xg)).sum().backward()
        return xg.grad

    return fwd, fastest(both, runs)


def ops(shape, runs, g):
    x = torch.rand(shape, generator=g) * 12 - 6
    c = shape[1]
    w3 = torch.rand([c, c, 3, 3], generator=g) - 0.5
    w1 = torch.rand([c, c, 1, 1], generator=g) - 0.5
    bias = (torch.rand([c], generator=g) - 0.5).view(1, c, 1, 1)
    table = {
        "sigmoid": torch.sigmoid,
        "silu": F.silu,
        "leaky_relu": lambda x: F.leaky_relu(x, 0.1),
        "conv3x3": lambda x: F.conv2d(x, w3, padding=1),
        "conv1x1": lambda x: F.conv2d(x, w1),
        "bias_add": lambda x: x + bias,
    }
    return {name: list(forward_backward(f, x, runs)) for name, f in table.items()}


def onnx(model, shape, runs, g, threads):
    try:
        from onnx2torch import convert

        net = convert(model).eval()
        fwd, both = forward_backward(net, torch.rand(shape, generator=g), runs)
    except Exception as e:  # conversion or run failure: the column is n/a, with the reason
        return {"error": f"{type(e).__name__}: {e}"[:300]}
    return {"threads": threads, "forward_ms": fwd, "forward_backward_ms": both}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=["ops", "onnx"])
    p.add_argument("model", nargs="?")
    p.add_argument("--shape", required=True)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--runs", type=int, default=10)
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    g = torch.Generator().manual_seed(0)
    shape = [int(s) for s in a.shape.split(",")]
    if a.what == "ops":
        out = ops(shape, a.runs, g)
    else:
        if not a.model:
            p.error("onnx needs MODEL")
        out = onnx(a.model, shape, a.runs, g, a.threads)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
