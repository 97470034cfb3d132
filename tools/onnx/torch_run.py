#!/usr/bin/env python3
"""Times an ONNX model in PyTorch (converted by onnx2torch): the PyTorch column of
`cac bench detect --onnx`.

Usage: python3 tools/onnx/torch_run.py MODEL --shape 1,3,640,640 --threads N --runs K

Converts MODEL with onnx2torch (opset-12 exports convert; opset 18's Split does not), then times
the forward pass (no gradient) and the forward pass plus the backward pass of the first output's
sum to the input, on a seeded uniform [0, 1) input, fastest of K runs after two warm-ups, with N
intra-op threads. Prints one JSON line {"threads": N, "forward_ms": .., "forward_backward_ms": ..},
or {"error": "..."} when the model does not convert or run.
"""

import argparse
import json
import time

import torch


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
    p.add_argument("model")
    p.add_argument("--shape", required=True)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--runs", type=int, default=5)
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    try:
        from onnx2torch import convert

        net = convert(a.model).eval()
        g = torch.Generator().manual_seed(0)
        x = torch.rand([int(s) for s in a.shape.split(",")], generator=g)

        def first(out):
            return out[0] if isinstance(out, (list, tuple)) else out

        with torch.no_grad():
            fwd = fastest(lambda: net(x), a.runs)

        def fwd_bwd():
            xg = x.clone().requires_grad_(True)
            first(net(xg)).sum().backward()
            return xg.grad

        both = fastest(fwd_bwd, a.runs)
    except Exception as e:  # conversion or run failure: the column is n/a, with the reason
        print(json.dumps({"error": f"{type(e).__name__}: {e}"[:300]}))
        return 0
    print(json.dumps({"threads": a.threads, "forward_ms": fwd, "forward_backward_ms": both}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
