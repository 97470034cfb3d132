#!/usr/bin/env python3
"""Oracle for cac's Faster R-CNN (src/detect/frcnn): torchvision's own models on deterministic
weights, run on the reference images, written as small files under tests/data/frcnn/.

Dev-only (needs `pip install torch torchvision numpy pillow`; CI does not run it).

Every parameter and buffer is set from a formula that tests/frcnn_conformance.rs reproduces in
Rust without Python: `v = 2 * (splitmix64(fnv1a64(name) + (i + 1) * GOLDEN) >> 40) / 2^24 - 1`
for the flat index `i`, then scaled by the parameter's role (see `value`). Written:

* `<model>-<image>.json`: configuration, sizes, final detections (torchvision's output), and
  `noise`: how far torchvision's own outputs move with float rounding (see `noise`), from which
  tests/frcnn_conformance.rs derives its bounds;
* `<model>-<image>-{proposals,class_logits,box_regression}.npy` (float32; box regression of
  the first 200 proposals only, to keep the files small);
* `subset.pth`: a real `torch.save` state_dict (the 320 model's first blocks + RPN predictors);
* `bad.pth`: the same with one mis-shaped key and one unexpected key (reader error tests).

Usage: python3 tools/torchvision_oracle.py [--out tests/data/frcnn] [--images ../shared/reference/images]
       python3 tools/torchvision_oracle.py --noise-only   (re-measures `noise` into the json files,
                                                           leaving every other value as it is)
       python3 tools/torchvision_oracle.py --bench MODEL --threads 2 --iters 3   (used by `cac bench detect`)
"""
import argparse
import json
import math
import os
import time

import numpy as np
import torch
import torchvision
from torchvision.models import detection

M64 = (1 << 64) - 1
GOLDEN = 0x9E3779B97F4A7C15

# name -> (constructor, kwargs used by the oracle, images)
MODELS = {
    "frcnn-mobilenet-v3-320": (detection.fasterrcnn_mobilenet_v3_large_320_fpn, {}, ["chelsea", "astronaut"]),
    "frcnn-mobilenet-v3": (detection.fasterrcnn_mobilenet_v3_large_fpn, {"min_size": 400}, ["chelsea"]),
    "frcnn-resnet50": (detection.fasterrcnn_resnet50_fpn, {"min_size": 320}, ["chelsea"]),
}
BOX_REGRESSION_ROWS = 200


def fnv1a64(name: str) -> int:
    h = 0xCBF29CE484222325
    for b in name.encode():
        h ^= b
        h = (h * 0x100000001B3) & M64
    return h


def uniform(name: str, n: int) -> np.ndarray:
    """n values in [-1, 1) (float64, exact multiples of 2^-23)."""
    with np.errstate(over="ignore"):
        i = np.arange(n, dtype=np.uint64)
        z = np.uint64(fnv1a64(name)) + (i + np.uint64(1)) * np.uint64(GOLDEN)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(40)).astype(np.float64) / float(1 << 24) * 2.0 - 1.0


def value(name: str, shape, keys) -> np.ndarray:
    """The deterministic value of one state_dict entry (mirrored in the Rust test)."""
    n = int(np.prod(shape)) if len(shape) else 1
    base, last = name.rsplit(".", 1)
    v = uniform(name, n)
    if last == "num_batches_tracked":
        return np.zeros(shape, dtype=np.int64)
    if base + ".running_mean" in keys:  # BatchNorm
        if last == "weight":
            # ResNet's residual branch ends (bn3) scaled down so the 16 blocks do not blow up.
            x = (v * 0.2 + 1.0) * (0.25 if base.endswith(".bn3") else 1.0)
        elif last == "bias":
            x = v * 0.2
        elif last == "running_mean":
            x = v * 0.2
        else:  # running_var in [1, 1.5)
            x = v * 0.25 + 1.25
    elif last == "weight":
        fan_in = int(np.prod(shape[1:]))
        gain = 6.0
        if "cls_score" in name:
            # A peaked softmax (detections above the 0.05 score threshold) that stays below
            # 1.0 in f32 (no score ties): ResNet's box features are larger.
            gain = 6.0 if "backbone.body.conv1.weight" in keys else 6.0 * 4.0
        elif "rpn.head.cls_logits" in name:
            gain = 6.0 * 0.1  # objectness logits that do not saturate the f32 sigmoid (ties)
        elif "bbox_pred" in name:
            gain = 6.0 * 0.001  # small box deltas
        x = v * math.sqrt(gain / fan_in)
    else:  # conv / linear bias
        x = v * 0.1
    return x.astype(np.float32).reshape(shape)


def set_weights(model):
    sd = model.state_dict()
    keys = set(sd.keys())
    new = {k: torch.from_numpy(value(k, tuple(t.shape), keys)) for k, t in sd.items()}
    model.load_state_dict(new)
    return model


def build(name, **extra):
    ctor, kwargs, _ = MODELS[name]
    kwargs = dict(kwargs, **extra)
    m = ctor(weights=None, weights_backbone=None, **kwargs)
    return set_weights(m).eval()


def load_image(path):
    from PIL import Image

    img = np.array(Image.open(path).convert("RGB"))
    return torch.from_numpy(img).permute(2, 0, 1).float() / 255.0


@torch.no_grad()
def run(m, img, check=True):
    images, _ = m.transform([img])
    features = m.backbone(images.tensors)
    proposals, _ = m.rpn(images, features)
    rh = m.roi_heads
    bf = rh.box_roi_pool(features, proposals, images.image_sizes)
    bf = rh.box_head(bf)
    class_logits, box_regression = rh.box_predictor(bf)
    boxes, scores, labels = rh.postprocess_detections(class_logits, box_regression, proposals, images.image_sizes)
    dets = [{"boxes": boxes[0], "scores": scores[0], "labels": labels[0]}]
    dets = m.transform.postprocess(dets, images.image_sizes, [tuple(img.shape[-2:])])[0]
    if not check:
        return images, features, proposals[0], class_logits, box_regression, dets
    ref = m([img])[0]
    assert torch.equal(ref["labels"], dets["labels"]) and torch.allclose(ref["boxes"], dets["boxes"])
    return images, features, proposals[0], class_logits, box_regression, dets


# ---- torchvision's own float noise ----

# A two-ulp relative jitter of every input value (a value in [0.5, 1) has an ulp of 6e-8).
JITTER = 2.4e-7
NOISE_METHOD = ("max over three re-runs of torchvision on this machine of the output's distance "
                "to the first run: the input jittered by two ulps (seeded), one thread instead of "
                "two, the model in channels-last memory format (other convolution kernels); with "
                "--noise-only also the first run against the files' values. Box and proposal "
                "coordinates relative to the box's larger side (at least 1 px), logits and "
                "regression relative to their largest magnitude, scores absolute.")


def outputs(run_result, img):
    """The comparable outputs of one `run` (numpy, detections in the original image's pixels)."""
    _, _, props, logits, regs, dets = run_result
    return {"proposals": props.numpy(), "logits": logits.numpy(), "regression": regs.numpy(),
            "boxes": dets["boxes"].numpy(), "scores": dets["scores"].numpy(),
            "labels": dets["labels"].numpy()}


def size(box):
    return max(box[2] - box[0], box[3] - box[1], 1.0)


def proposal_order(mine, want):
    """For each of `mine`'s proposals, the nearest unused one of `want` within 4 places."""
    used, order = np.zeros(len(want), bool), []
    for i, a in enumerate(mine):
        near = [j for j in range(max(0, i - 4), min(len(want), i + 5)) if not used[j]]
        j = min(near, key=lambda j: np.abs(a - want[j]).max())
        used[j] = True
        order.append(j)
    return order


def rel(a, b):
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30)) if len(b) else 0.0


def distance(got, want):
    """How far `got`'s outputs are from `want`'s, on the measures of `NOISE_METHOD`."""
    n = min(len(got["proposals"]), len(want["proposals"]))
    order = proposal_order(got["proposals"][:n], want["proposals"][:n])
    pairs = [(i, j) for i, j in enumerate(order)]
    prop = max(np.abs(got["proposals"][i] - want["proposals"][j]).max() / size(want["proposals"][j])
               for i, j in pairs)
    rows = [(i, j) for i, j in pairs if i < len(got["regression"]) and j < len(want["regression"])]
    logits = rel(got["logits"][[i for i, _ in pairs]], want["logits"][[j for _, j in pairs]])
    regs = rel(got["regression"][[i for i, _ in rows]], want["regression"][[j for _, j in rows]])
    boxes, scores, unmatched = 0.0, 0.0, 0
    for b, s, l in zip(want["boxes"], want["scores"], want["labels"]):
        cand = [(np.abs(gb - b).max() / size(b), abs(float(gs - s)))
                for gb, gs, gl in zip(got["boxes"], got["scores"], got["labels"]) if gl == l]
        best = min(cand, default=None)
        if best is None or best[0] > 1e-3:  # dropped at the score threshold or the 100 cap
            unmatched += 1
            continue
        boxes, scores = max(boxes, best[0]), max(scores, best[1])
    return {"proposals_size_rel": float(prop), "logits_rel": logits, "regression_rel": regs,
            "boxes_size_rel": float(boxes), "scores_abs": float(scores),
            "detections_unmatched": unmatched}


def noise(name, img, first, files=None):
    """torchvision's own float noise around `first` (the outputs of `run` at two threads)."""
    reruns = {}
    u = torch.from_numpy(uniform("jitter", img.numel()).astype(np.float32)).reshape(img.shape)
    reruns["jitter"] = outputs(run(build(name), img + img * u * JITTER, check=False), img)
    torch.set_num_threads(1)
    reruns["one thread"] = outputs(run(build(name), img, check=False), img)
    torch.set_num_threads(2)
    cl = build(name).to(memory_format=torch.channels_last)
    reruns["channels last"] = outputs(run(cl, img, check=False), img)
    if files is not None:
        reruns["files"] = files
    by = {k: distance(v, first) for k, v in reruns.items()}
    out = {k: max(d[k] for d in by.values()) for k in next(iter(by.values()))}
    out["method"] = NOISE_METHOD
    out["by_rerun"] = by
    return out


def files_outputs(base, meta):
    d = meta["detections"]
    return {"proposals": np.load(base + "-proposals.npy"),
            "logits": np.load(base + "-class_logits.npy"),
            "regression": np.load(base + "-box_regression.npy"),
            "boxes": np.array(d["boxes"], np.float32).reshape(-1, 4),
            "scores": np.array(d["scores"], np.float32),
            "labels": np.array(d["labels"])}


def noise_only(out, image_dir):
    """Re-measures `noise` into the existing json files, every other value kept."""
    for name, (_, _, images) in MODELS.items():
        m = build(name)
        for stem in images:
            img = load_image(os.path.join(image_dir, stem + ".png"))
            base = os.path.join(out, f"{name}-{stem}")
            with open(base + ".json") as f:
                meta = json.load(f)
            first = outputs(run(m, img), img)
            meta["noise"] = noise(name, img, first, files_outputs(base, meta))
            with open(base + ".json", "w") as f:
                json.dump(meta, f)
            print(f"{name} {stem}: noise " + json.dumps({k: v for k, v in meta["noise"].items()
                                                         if k != "method"}))


def oracle(out, image_dir):
    os.makedirs(out, exist_ok=True)
    for name, (_, kwargs, images) in MODELS.items():
        m = build(name)
        t = m.transform
        for stem in images:
            img = load_image(os.path.join(image_dir, stem + ".png"))
            result = run(m, img)
            images_t, feats, props, logits, regs, dets = result
            base = os.path.join(out, f"{name}-{stem}")
            np.save(base + "-proposals.npy", props.numpy().astype(np.float32))
            np.save(base + "-class_logits.npy", logits.numpy().astype(np.float32))
            np.save(base + "-box_regression.npy", regs[:BOX_REGRESSION_ROWS].numpy().astype(np.float32))
            meta = {
                "model": name,
                "image": stem + ".png",
                "torch": torch.__version__,
                "torchvision": torchvision.__version__,
                "min_size": t.min_size[0],
                "max_size": t.max_size,
                "image_size": list(img.shape[-2:]),
                "resized_size": list(images_t.image_sizes[0]),
                "padded_size": list(images_t.tensors.shape[-2:]),
                "features": {k: list(v.shape) for k, v in feats.items()},
                "num_proposals": int(props.shape[0]),
                "detections": {
                    "boxes": dets["boxes"].tolist(),
                    "scores": dets["scores"].tolist(),
                    "labels": dets["labels"].tolist(),
                },
                "noise": noise(name, img, outputs(result, img)),
            }
            with open(base + ".json", "w") as f:
                json.dump(meta, f)
            print(f"{name} {stem}: {img.shape[-2:]} -> {images_t.image_sizes[0]}, "
                  f"{props.shape[0]} proposals, {len(dets['labels'])} detections, "
                  f"logit range [{logits.min():.2f}, {logits.max():.2f}], "
                  f"features {[tuple(v.shape) for v in feats.values()]}")
    # Gradient of the class logits summed over the (fixed) proposals, on a small image.
    m = build("frcnn-mobilenet-v3-320")
    h, w = 40, 56
    yy, xx = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    img = np.stack([0.5 + 0.4 * np.sin(xx * 0.3 + c) * np.cos(yy * 0.2) for c in range(3)]).astype(np.float32)
    x = torch.from_numpy(img).requires_grad_(True)
    images, _ = m.transform([x])
    feats = m.backbone(images.tensors)
    props, _ = m.rpn(images, feats)
    bf = m.roi_heads.box_roi_pool(feats, props, images.image_sizes)
    logits, _ = m.roi_heads.box_predictor(m.roi_heads.box_head(bf))
    logits.sum().backward()
    np.save(os.path.join(out, "grad-image.npy"), img)
    np.save(os.path.join(out, "grad-proposals.npy"), props[0].detach().numpy())
    np.save(os.path.join(out, "grad-image-grad.npy"), x.grad.numpy().astype(np.float32))
    print(f"gradient: {props[0].shape[0]} proposals, |grad| max {x.grad.abs().max():.3f}")
    # A real torch.save state_dict for the reader tests.
    m = build("frcnn-mobilenet-v3-320")
    sd = m.state_dict()
    subset = {k: v for k, v in sd.items()
              if k.startswith(("backbone.body.0.", "backbone.body.1.", "rpn.head.cls_logits", "rpn.head.bbox_pred"))}
    torch.save(subset, os.path.join(out, "subset.pth"))
    bad = dict(subset)
    bad["backbone.body.0.0.weight"] = torch.zeros(16, 3, 5, 5)
    bad["extra.unexpected.weight"] = torch.zeros(2, 2)
    torch.save(bad, os.path.join(out, "bad.pth"))


def bench(name, threads, iters, size, device="cpu"):
    """Forward and forward+backward (to the image) ms on `device` (cpu, or cuda), printed as one
    JSON line. On CUDA each timed run ends with a synchronisation."""
    torch.set_num_threads(threads)
    ctor = MODELS[name][0]
    m = set_weights(ctor(weights=None, weights_backbone=None)).eval().to(device)  # default sizes
    h, w = size
    x = torch.rand(3, h, w, device=device)
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    with torch.no_grad():
        m([x])
    fwd = []
    for _ in range(iters):
        sync()
        t0 = time.perf_counter()
        with torch.no_grad():
            m([x])
        sync()
        fwd.append((time.perf_counter() - t0) * 1e3)
    bwd = []
    for _ in range(iters):
        xi = x.clone().requires_grad_(True)
        sync()
        t0 = time.perf_counter()
        images, _ = m.transform([xi])
        feats = m.backbone(images.tensors)
        with torch.no_grad():
            props, _ = m.rpn(images, feats)
        bf = m.roi_heads.box_roi_pool(feats, props, images.image_sizes)
        logits, _ = m.roi_heads.box_predictor(m.roi_heads.box_head(bf))
        logits.sum().backward()
        sync()
        bwd.append((time.perf_counter() - t0) * 1e3)
    print(json.dumps({"model": name, "threads": threads, "forward_ms": min(fwd), "backward_ms": min(bwd),
                      "device": device, "torch": torch.__version__}))


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="tests/data/frcnn")
    ap.add_argument("--images", default="../shared/reference/images")
    ap.add_argument("--bench")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--iters", type=int, default=3)
    ap.add_argument("--size", default="480x640", help="bench image HxW")
    ap.add_argument("--device", default="cpu", help="bench device: cpu or cuda")
    ap.add_argument("--noise-only", action="store_true",
                    help="re-measure torchvision's float noise into the existing json files")
    a = ap.parse_args()
    if a.noise_only:
        torch.set_num_threads(2)
        noise_only(a.out, a.images)
    elif a.bench:
        bench(a.bench, a.threads, a.iters, tuple(int(s) for s in a.size.split("x")), a.device)
    else:
        torch.set_num_threads(2)
        oracle(a.out, a.images)
