#!/usr/bin/env python3
"""Runs an ONNX model with onnxruntime (CPU) on feeds read from JSON: the oracle for the Rust tests.

Usage:
  python3 tools/onnx/ort_run.py MODEL INPUTS.json OUTPUTS.json [--outputs a,b] [--threads N]
                                [--no-optimize]
  python3 tools/onnx/ort_run.py MODEL INPUTS.json --bench K [--threads N]

Tensor JSON schema (inputs and outputs alike): {"<name>": {"shape": [..], "data": [row-major
numbers]}}, with an extra "dtype": "int64" (or another numpy dtype name) for non-float32 tensors.
With --bench K it prints one JSON line {"threads": N, "forward_ms": [K timings]} after two
warm-up runs and writes no outputs file.
"""

import argparse
import json
import sys
import time

import numpy as np
import onnxruntime as ort


def read_tensors(path):
    """Reads the JSON tensor schema into a dict of numpy arrays (float32 unless "dtype" says)."""
    with open(path) as f:
        raw = json.load(f)
    return {name: np.asarray(t["data"], dtype=t.get("dtype", "float32")).reshape(t["shape"])
            for name, t in raw.items()}


def _fmt(v):
    # 9 significant digits round-trip any float32 exactly.
    return "%.9g" % v


def write_tensors(path, tensors):
    """Writes a dict of numpy arrays in the JSON tensor schema (float32 values, ints as floats)."""
    parts = []
    for name, v in tensors.items():
        v = np.asarray(v)
        head = {"shape": list(v.shape)}
        if v.dtype != np.float32:
            head["dtype"] = str(v.dtype)
        flat = v.reshape(-1)
        if v.dtype.kind == "f":
            data = ",".join(map(_fmt, flat.astype(np.float32).tolist()))
        else:
            data = ",".join("%d.0" % x for x in flat.tolist())
        head_json = json.dumps(head)[:-1]  # drop the closing brace to append "data"
        parts.append(f'{json.dumps(name)}: {head_json}, "data": [{data}]}}')
    with open(path, "w") as f:
        f.write("{\n" + ",\n".join(parts) + "\n}\n")


def session(model_path, threads=1, optimize=True):
    """A CPU session with a fixed thread count and all graph optimisations (or none)."""
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = (ort.GraphOptimizationLevel.ORT_ENABLE_ALL if optimize
                                     else ort.GraphOptimizationLevel.ORT_DISABLE_ALL)
    return ort.InferenceSession(model_path, sess_options=opts, providers=["CPUExecutionProvider"])


def _feeds_for(sess, feeds):
    """Casts each feed to the dtype the model declares for it."""
    kinds = {"tensor(float)": np.float32, "tensor(int64)": np.int64, "tensor(double)": np.float64,
             "tensor(int32)": np.int32, "tensor(bool)": np.bool_}
    out = {}
    for inp in sess.get_inputs():
        if inp.name not in feeds:
            raise SystemExit(f"ort_run: no feed for model input {inp.name!r}")
        out[inp.name] = np.ascontiguousarray(feeds[inp.name], dtype=kinds.get(inp.type, np.float32))
    return out


def run_session(sess, feeds, output_names=None):
    """Runs sess on feeds; returns {output name: array} in graph order (or the order asked)."""
    names = output_names or [o.name for o in sess.get_outputs()]
    values = sess.run(names, _feeds_for(sess, feeds))
    return dict(zip(names, values))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model")
    p.add_argument("inputs")
    p.add_argument("outputs_json", nargs="?")
    p.add_argument("--outputs", help="comma-separated output names (default: all graph outputs)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--bench", type=int, metavar="K", help="time K forward passes instead")
    p.add_argument("--no-optimize", action="store_true",
                   help="run the graph as written (no fusions): onnxruntime's own rounding spread")
    args = p.parse_args(argv)

    sess = session(args.model, args.threads, optimize=not args.no_optimize)
    feeds = _feeds_for(sess, read_tensors(args.inputs))
    names = args.outputs.split(",") if args.outputs else None

    if args.bench is not None:
        output_names = names or [o.name for o in sess.get_outputs()]
        for _ in range(2):
            sess.run(output_names, feeds)
        timings = []
        for _ in range(args.bench):
            t0 = time.perf_counter()
            sess.run(output_names, feeds)
            timings.append(round((time.perf_counter() - t0) * 1e3, 4))
        print(json.dumps({"threads": args.threads, "forward_ms": timings}))
        return 0

    if not args.outputs_json:
        p.error("OUTPUTS.json is required unless --bench is given")
    write_tensors(args.outputs_json, run_session(sess, feeds, names))
    return 0


if __name__ == "__main__":
    sys.exit(main())
