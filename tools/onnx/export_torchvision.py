#!/usr/bin/env python3
"""Exports a torchvision one-stage detector as the dense, pre-NMS ONNX output that cac reads.

torchvision's detection models export their whole post-processing (score threshold, top-k,
NMS, data-dependent shapes); cac runs its own NMS and needs the dense head instead. This
script wraps the model's own modules (backbone, head, anchor generator, box coder) in a
module whose forward takes the network input at a fixed size and returns ONE tensor in cac's
"yolov8" layout `[B, 4 + C, N]`: rows x1, y1, x2, y2 (network-input pixels, decoded and
clipped exactly as `postprocess_detections` does) then C class scores, without NMS. The
background column (index 0 of torchvision's 91 COCO labels) is dropped, so C = 90 and
`classes` in the TOML names them (torchvision's list, with its "N/A" gaps).

Models (random weights, seeded, or your checkpoint with --weights; nothing is downloaded):
  ssdlite   ssdlite320_mobilenet_v3_large, 320x320, softmax over 91 classes: the output holds
            softmax probabilities without the background column -> scores = "probabilities"
  retinanet retinanet_resnet50_fpn at --size (default 320), sigmoid class scores: the Sigmoid
            is in the graph and cac taps its input for exact logits -> scores = "sigmoid"
  fcos      fcos_resnet50_fpn at --size, layout "yolov5" `[B, N, 5 + C]` instead: x1, y1, x2,
            y2, sigmoid(centerness) as objectness, sigmoid class scores. cac ranks
            objectness x class; torchvision ranks sqrt(centerness x class), the same order, so
            a torchvision threshold t is cac's score_threshold t^2.

Pre-processing is written into the TOML, not the graph (exact either way; this keeps the
graph input equal to what the backbone sees): `mean`/`std` are the transform's image_mean and
image_std, applied by cac to the [0, 1] RGB image. torchvision normalises before it resizes,
cac after; bilinear resizing is affine per channel with weights summing to 1, so the order
does not matter beyond float rounding. SSDlite's transform stretches every image to 320x320
(fixed_size), exactly cac's `resize = "stretch"` (bilinear, half-pixel, no antialias in both).
RetinaNet/FCOS keep the aspect ratio (shorter side to min_size) and pad bottom/right with 0
after normalisation; a fixed-size export cannot do that, so the TOML says `resize =
"letterbox"` (aspect kept, centred, pad 0.45 ~ the mean) -- close, not identical; change it
to "stretch" if that suits the data better. The wrapper is built with min_size = max_size =
--size so torchvision's own transform is the identity at that size, and --check compares the
wrapper with torchvision's own post-processed detections.

Usage:
  python3 tools/onnx/export_torchvision.py ssdlite OUT.onnx [--check]
  python3 tools/onnx/export_torchvision.py retinanet OUT.onnx [--size 320] [--check]
  python3 tools/onnx/export_torchvision.py fcos OUT.onnx [--size 320] [--check]
  options: --seed N (default 0), --weights FILE.pth (a state_dict you hold, e.g. torchvision's COCO
           weights saved by torch.save),
           --opset N (default 17)
Writes OUT.onnx and OUT.toml beside it; then:
  cac models inspect OUT.onnx
  cac detect IMG --model onnx:OUT.onnx
The export uses the TorchScript exporter (dynamo=False): torch >= 2.9 defaults to the
torch.export-based exporter, which needs the onnxscript package and is not needed here.
"""

import argparse
import copy
import sys
import warnings
from pathlib import Path

import torch
import torchvision
from torch import nn
from torchvision.models.detection.image_list import ImageList

sys.dont_write_bytecode = True


def coco_categories():
    """torchvision's 91 COCO labels ("__background__", "person", ..., with "N/A" gaps)."""
    from torchvision.models._meta import _COCO_CATEGORIES

    return list(_COCO_CATEGORIES)


class PlainGroupNorm(nn.Module):
    """nn.GroupNorm in elementary ops (ReduceMean, Sub, Mul, Sqrt, Div): the exporter writes a
    GroupNorm at opset 17 as InstanceNormalization, which cac does not run (FCOS's head and the
    *_v2 RetinaNet use GroupNorm). Same arithmetic: biased variance, eps inside the root."""

    def __init__(self, gn):
        super().__init__()
        self.groups, self.eps = gn.num_groups, gn.eps
        self.weight, self.bias = gn.weight, gn.bias

    def forward(self, x):
        shape = x.shape
        g = x.reshape(shape[0], self.groups, -1)
        d = g - g.mean(dim=-1, keepdim=True)
        g = d / torch.sqrt((d * d).mean(dim=-1, keepdim=True) + self.eps)
        x = g.reshape(shape)
        if self.weight is not None:
            x = x * self.weight[:, None, None] + self.bias[:, None, None]
        return x


def plain_group_norms(module):
    """Replaces every nn.GroupNorm under module by a PlainGroupNorm (in place)."""
    for name, child in module.named_children():
        if isinstance(child, nn.GroupNorm):
            setattr(module, name, PlainGroupNorm(child))
        else:
            plain_group_norms(child)
    return module


class DenseDetector(nn.Module):
    """A torchvision one-stage detector without post-processing: one dense tensor.

    forward(x): x is [B, 3, H, W], already resized and normalised (cac does both, as the TOML
    says); returns [B, 4 + C, N] ("yolov8": boxes x1 y1 x2 y2 in input pixels, then class
    scores) or, for FCOS, [B, N, 5 + C] ("yolov5": boxes, centerness, class scores).
    """

    def __init__(self, kind, model, size):
        super().__init__()
        self.kind = kind
        self.backbone = model.backbone
        self.head = model.head
        if any(isinstance(m, nn.GroupNorm) for m in self.modules()):
            # Copies, so that the torchvision model itself (used by --check) keeps nn.GroupNorm.
            self.backbone = plain_group_norms(copy.deepcopy(self.backbone))
            self.head = plain_group_norms(copy.deepcopy(self.head))
        self.height, self.width = size
        if kind == "fcos":
            self.box_coder = model.box_coder  # BoxLinearCoder(normalize_by_size=True)
        else:
            self.weights = model.box_coder.weights
            self.clip = model.box_coder.bbox_xform_clip
        # Anchors depend only on the (fixed) input and feature sizes: compute them once with
        # the model's own generator and keep them as a constant.
        with torch.no_grad():
            x = torch.zeros(1, 3, self.height, self.width)
            feats = self._features(x)
            images = ImageList(x, [(self.height, self.width)])
            anchors = model.anchor_generator(images, feats)[0]  # [N, 4] x1 y1 x2 y2
        self.register_buffer("anchors", anchors.float(), persistent=False)

    def _features(self, x):
        f = self.backbone(x)
        return [f] if isinstance(f, torch.Tensor) else list(f.values())

    def _decode(self, rel):
        """BoxCoder.decode_single over a batch: rel [B, N, 4] -> [B, N, 4] x1 y1 x2 y2."""
        a = self.anchors
        widths = a[:, 2] - a[:, 0]
        heights = a[:, 3] - a[:, 1]
        ctr_x = a[:, 0] + 0.5 * widths
        ctr_y = a[:, 1] + 0.5 * heights
        wx, wy, ww, wh = self.weights
        dx = rel[..., 0] / wx
        dy = rel[..., 1] / wy
        dw = torch.clamp(rel[..., 2] / ww, max=self.clip)
        dh = torch.clamp(rel[..., 3] / wh, max=self.clip)
        cx = dx * widths + ctr_x
        cy = dy * heights + ctr_y
        w = torch.exp(dw) * widths
        h = torch.exp(dh) * heights
        return torch.stack((cx - 0.5 * w, cy - 0.5 * h, cx + 0.5 * w, cy + 0.5 * h), dim=-1)

    def _clip_to_image(self, boxes):
        """box_ops.clip_boxes_to_image, as postprocess_detections applies it."""
        x = boxes[..., 0::2].clamp(min=0, max=self.width)
        y = boxes[..., 1::2].clamp(min=0, max=self.height)
        return torch.stack((x[..., 0], y[..., 0], x[..., 1], y[..., 1]), dim=-1)

    def forward(self, x):
        out = self.head(self._features(x))
        logits = out["cls_logits"]  # [B, N, 91]
        if self.kind == "fcos":
            boxes = self.box_coder.decode(out["bbox_regression"], self.anchors)
        else:
            boxes = self._decode(out["bbox_regression"])
        boxes = self._clip_to_image(boxes)
        if self.kind == "ssdlite":
            scores = torch.softmax(logits, dim=-1)[..., 1:]  # SSD.postprocess_detections
            return torch.cat((boxes, scores), dim=-1).transpose(1, 2)
        if self.kind == "retinanet":
            scores = torch.sigmoid(logits)[..., 1:]  # RetinaNet.postprocess_detections
            return torch.cat((boxes, scores), dim=-1).transpose(1, 2)
        ctr = torch.sigmoid(out["bbox_ctrness"])  # [B, N, 1]
        return torch.cat((boxes, ctr, torch.sigmoid(logits)[..., 1:]), dim=-1)


def build(kind, size, weights):
    """The torchvision model (eval mode, the state_dict at `weights` when given) and its fixed
    input size (H, W)."""
    tv = torchvision.models.detection
    w = None
    if kind == "ssdlite":
        m = tv.ssdlite320_mobilenet_v3_large(weights=w, weights_backbone=None)
        hw = (320, 320)
    elif kind == "retinanet":
        m = tv.retinanet_resnet50_fpn(weights=w, weights_backbone=None, min_size=size, max_size=size)
        hw = (size, size)
    elif kind == "fcos":
        m = tv.fcos_resnet50_fpn(weights=w, weights_backbone=None, min_size=size, max_size=size)
        hw = (size, size)
    else:
        raise SystemExit(f"unknown model {kind!r}")
    if weights is not None:
        try:
            m.load_state_dict(torch.load(weights, map_location="cpu", weights_only=True))
        except Exception as e:  # a clear message naming the file, not a traceback
            raise SystemExit(f"{weights}: not a {kind} state_dict ({e})")
    return m.eval(), hw


def toml_text(kind, model, hw):
    t = model.transform
    f3 = lambda v: "[" + ", ".join("%.6g" % float(x) for x in v) + "]"  # noqa: E731
    names = coco_categories()[1:]
    lines = [
        f"# cac ONNX detector config for torchvision {kind} (tools/onnx/export_torchvision.py)",
        f'head = "{"yolov5" if kind == "fcos" else "yolov8"}"',
        f"input_size = [{hw[1]}, {hw[0]}]",
        f'resize = "{"stretch" if kind == "ssdlite" else "letterbox"}"',
    ]
    if kind != "ssdlite":
        lines.append("pad_value = 0.45")
    lines += [
        f"mean = {f3(t.image_mean)}",
        f"std = {f3(t.image_std)}",
        f'scores = "{"probabilities" if kind == "ssdlite" else "sigmoid"}"',
        'box_format = "xyxy"',
        "classes = [" + ", ".join('"%s"' % n for n in names) + "]",
    ]
    if kind == "fcos":
        lines.append("score_threshold = 0.04  # torchvision's 0.2 on sqrt(centerness x class)")
    return "\n".join(lines) + "\n"


def check(kind, model, wrapper, hw):
    """torchvision's own detections (NMS output) must be rows of the dense output."""
    g = torch.Generator().manual_seed(1)
    img = torch.rand(3, *hw, generator=g)
    model.score_thresh = 0.0
    with torch.no_grad():
        det = model([img])[0]
        x = (img - torch.tensor(model.transform.image_mean)[:, None, None]) / torch.tensor(
            model.transform.image_std
        )[:, None, None]
        dense = wrapper(x[None])[0]
    if kind != "fcos":
        dense = dense.T
    boxes = dense[:, :4]
    scores = dense[:, 5:] if kind == "fcos" else dense[:, 4:]
    if kind == "fcos":
        scores = torch.sqrt(scores * dense[:, 4:5])
    worst_box = worst_score = 0.0
    keep = det["labels"] > 0  # the background column is not exported (RetinaNet/FCOS score it)
    n = min(int(keep.sum()), 50)
    for b, s, lab in zip(det["boxes"][keep][:n], det["scores"][keep][:n], det["labels"][keep][:n]):
        col = scores[:, int(lab) - 1]
        d = (boxes - b).abs().amax(dim=1) + (col - s).abs() * 1e3
        j = int(d.argmin())
        worst_box = max(worst_box, float((boxes[j] - b).abs().max()))
        worst_score = max(worst_score, float((col[j] - s).abs()))
    print(f"check: {n} torchvision detections matched; max |box diff| {worst_box:.3g} px, "
          f"max |score diff| {worst_score:.3g}")
    return worst_box < 1e-3 * max(hw) and worst_score < 1e-5


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model", choices=["ssdlite", "retinanet", "fcos"])
    p.add_argument("out", type=Path, help="OUT.onnx (OUT.toml is written beside it)")
    p.add_argument("--size", type=int, default=320, help="RetinaNet/FCOS square input (multiple of 32)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--opset", type=int, default=17)
    p.add_argument("--weights", type=Path, help="a state_dict (.pth) to load instead of random weights")
    p.add_argument("--check", action="store_true", help="compare with torchvision's own detections")
    args = p.parse_args(argv)

    torch.manual_seed(args.seed)
    model, hw = build(args.model, args.size, args.weights)
    wrapper = DenseDetector(args.model, model, hw).eval()
    if args.check and not check(args.model, model, wrapper, hw):
        raise SystemExit("check failed: the dense output does not hold torchvision's detections")

    args.out.parent.mkdir(parents=True, exist_ok=True)
    x = torch.zeros(1, 3, *hw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy exporter's deprecation and tracer warnings
        torch.onnx.export(
            wrapper, (x,), str(args.out), input_names=["images"], output_names=["output"],
            opset_version=args.opset, dynamo=False, do_constant_folding=True,
        )
    toml = args.out.with_suffix(".toml")
    toml.write_text(toml_text(args.model, model, hw))
    with torch.no_grad():
        shape = tuple(wrapper(x).shape)
    print(f"wrote {args.out} (input images [1, 3, {hw[0]}, {hw[1]}], output {list(shape)}) and {toml}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
