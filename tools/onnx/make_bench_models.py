#!/usr/bin/env python3
"""Builds the models the detector benchmark times (`cac bench detect --onnx ...`, the
compute-core table in docs/detectors.md): YOLOv8n and YOLO11n at 320² and 640², from their
yaml with seeded random weights (nothing downloaded; timings do not depend on the values),
exported at opset 12 so that onnx2torch converts them for the PyTorch column.

Usage: python3 tools/onnx/make_bench_models.py OUTDIR   (writes OUTDIR/<model>-<size>.onnx)
"""

import os
import shutil
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True
sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_models import ultralytics_offline_env  # noqa: E402

MODELS = ["yolov8n", "yolo11n"]
SIZES = [320, 640]


def main():
    outdir = Path(sys.argv[1]).resolve()
    outdir.mkdir(parents=True, exist_ok=True)
    workdir = Path(tempfile.mkdtemp(prefix="cac-bench-models-"))
    ultralytics_offline_env(workdir)
    import torch
    from ultralytics import YOLO, settings

    settings.update({"sync": False, "datasets_dir": str(workdir / "datasets"),
                     "weights_dir": str(workdir / "weights"), "runs_dir": str(workdir / "runs")})
    cwd = os.getcwd()
    try:
        os.chdir(workdir)
        for name in MODELS:
            for size in SIZES:
                torch.manual_seed(0)
                path = YOLO(f"{name}.yaml").export(format="onnx", imgsz=size, opset=12, batch=1,
                                                   device="cpu", simplify=True)
                out = outdir / f"{name}-{size}.onnx"
                shutil.copyfile(path, out)
                print(f"make_bench_models: wrote {out}", flush=True)
    finally:
        os.chdir(cwd)
        shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    main()
