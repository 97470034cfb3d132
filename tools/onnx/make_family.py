#!/usr/bin/env python3
"""Builds the ultralytics conformance family: each model of the family and each export option a
user meets, built from its yaml with seeded random weights (nothing downloaded), exported to
ONNX, with onnxruntime's output on a seeded input. tests/onnx_family.rs runs cac on every row
and writes the conformance table (matched and trainable, or refused saying what to do).

Usage: python3 tools/onnx/make_family.py OUTDIR

Writes OUTDIR/<row>.onnx, <row>.input.json (the seeded feed "images"), <row>.expected.json
(onnxruntime's outputs, threads=1) and OUTDIR/family.json: {"rows": [{name, file, yaml,
options, input, noise}], "versions": {...}}. `noise` is how far onnxruntime's own output0 moves
with float rounding (unfused against fused, and a two-ulp input jitter), relative to its
largest magnitude; for an output that is a top-k selection ([1, 300, 6]) it is measured on the
sorted scores.
"""

import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import onnx

sys.dont_write_bytecode = True
sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_models import calibrate_ultralytics, ultralytics_offline_env  # noqa: E402
from ort_run import run_session, session, write_tensors  # noqa: E402

# (row, yaml, export options, after-export step). The family at the default options (imgsz 320,
# opset 17, simplify, static shape), then the options on YOLOv8n.
DEFAULTS = {"imgsz": 320, "opset": 17, "simplify": True, "dynamic": False}
ROWS = [
    ("yolov3u", "yolov3u.yaml", {}, None),
    ("yolov3-tinyu", "yolov3-tinyu.yaml", {}, None),
    ("yolov5nu", "yolov5nu.yaml", {}, None),
    ("yolov6n", "yolov6n.yaml", {}, None),
    ("yolov8n", "yolov8n.yaml", {}, None),
    ("yolov9t", "yolov9t.yaml", {}, None),
    ("yolov10n", "yolov10n.yaml", {}, None),
    ("yolo11n", "yolo11n.yaml", {}, None),
    ("yolo12n", "yolo12n.yaml", {}, None),
    ("yolo26n", "yolo26n.yaml", {}, None),
    ("rtdetr-l", "rtdetr-l.yaml", {}, None),
    ("yolov8n-seg", "yolov8n-seg.yaml", {}, None),
    ("yolov8n-pose", "yolov8n-pose.yaml", {}, None),
    ("yolov8n opset=12", "yolov8n.yaml", {"opset": 12}, None),
    ("yolov8n opset=18", "yolov8n.yaml", {"opset": 18}, None),
    ("yolov8n dynamic", "yolov8n.yaml", {"dynamic": True}, None),
    ("yolov8n simplify=False", "yolov8n.yaml", {"simplify": False}, None),
    ("yolov8n half", "yolov8n.yaml", {"half": True}, None),
    ("yolov8n imgsz=384x640", "yolov8n.yaml", {"imgsz": [384, 640]}, None),
    ("yolov8n nms=True", "yolov8n.yaml", {"nms": True}, None),
    ("yolov10n nms=False", "yolov10n.yaml", {"nms": False}, None),
    ("yolo26n nms=False", "yolo26n.yaml", {"nms": False}, None),
    ("yolov8n int8", "yolov8n.yaml", {}, "int8"),
]


def file_stem(row):
    return row.replace(" ", "_").replace("=", "-")


def selection(out):
    """Whether output0 is a top-k / NMS selection ([1, 300, 6]): its sorted scores, else None."""
    if out.ndim == 3 and out.shape[1:] == (300, 6):
        return np.sort(out[0, :, 4])[::-1]
    return None


def noise(path, feed, want):
    scale = float(np.abs(want).max()) or 1.0
    plain = run_session(session(str(path), threads=1, optimize=False), feed)["output0"]
    x = feed["images"]
    sign = np.where(np.random.default_rng(4321).random(x.shape) < 0.5, 1.0, -1.0)
    moved = run_session(session(str(path), threads=1), {"images": (x * (1 + sign * 2.0 ** -22)).astype(np.float32)})
    moved = moved["output0"]
    sel = selection(want)
    if sel is not None:
        want, plain, moved = sel, selection(plain), selection(moved)
        scale = float(np.abs(want).max()) or 1.0
    return max(float(np.abs(plain - want).max()), float(np.abs(moved - want).max())) / scale


def main():
    outdir = Path(sys.argv[1])
    outdir.mkdir(parents=True, exist_ok=True)
    workdir = Path(tempfile.mkdtemp(prefix="cac-family-"))
    ultralytics_offline_env(workdir)
    import onnxruntime as ort
    import torch
    import ultralytics
    from onnxruntime.quantization import QuantType, quantize_dynamic
    from ultralytics import RTDETR, YOLO, settings

    settings.update({"sync": False, "datasets_dir": str(workdir / "datasets"),
                     "weights_dir": str(workdir / "weights"), "runs_dir": str(workdir / "runs")})
    torch.set_num_threads(1)
    rows = []
    cwd = os.getcwd()
    try:
        os.chdir(workdir)
        for row, yaml, options, after in ROWS:
            opts = {**DEFAULTS, **options}
            imgsz = opts["imgsz"]
            h, w = (imgsz, imgsz) if isinstance(imgsz, int) else imgsz
            image = np.random.default_rng(1234).uniform(0, 1, (1, 3, h, w)).astype(np.float32)
            torch.manual_seed(0)
            model = RTDETR(yaml) if yaml.startswith("rtdetr") else YOLO(yaml)
            if model.task == "detect":
                calibrate_ultralytics(model.model, torch, image)
            path = model.export(format="onnx", batch=1, device="cpu", **opts)
            exported = onnx.load(str(path))
            keep = [p for p in exported.metadata_props if p.key != "date"]
            del exported.metadata_props[:]
            exported.metadata_props.extend(keep)
            stem = file_stem(row)
            out = outdir / f"{stem}.onnx"
            onnx.save(exported, str(out))
            if after == "int8":
                quantize_dynamic(str(out), str(out), weight_type=QuantType.QInt8)
            feed = {"images": image}
            want = run_session(session(str(out), threads=1), feed)
            write_tensors(str(outdir / f"{stem}.input.json"), feed)
            write_tensors(str(outdir / f"{stem}.expected.json"), want)
            rows.append({"name": row, "file": f"{stem}.onnx", "yaml": yaml, "task": model.task,
                         "options": {**opts, **({"quantized": after} if after else {})},
                         "input": [1, 3, h, w], "noise": noise(out, feed, want["output0"])})
            print(f"make_family: {row}: exported", flush=True)
    finally:
        os.chdir(cwd)
        shutil.rmtree(workdir, ignore_errors=True)
    versions = {"torch": torch.__version__, "ultralytics": ultralytics.__version__,
                "onnx": onnx.__version__, "onnxruntime": ort.__version__}
    with open(outdir / "family.json", "w") as f:
        json.dump({"rows": rows, "versions": versions}, f, indent=1)


if __name__ == "__main__":
    main()
