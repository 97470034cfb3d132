#!/usr/bin/env python3
"""Builds the ONNX fixtures and their onnxruntime oracle outputs for the Rust ONNX front end.

Usage: python3 tools/onnx/make_models.py OUTDIR [--skip-ultralytics]

Writes, all deterministic (fixed numpy / torch seeds):
  OUTDIR/ops/<case>.onnx          one op or a short chain per case, float32, built with onnx.helper
  OUTDIR/yolov5_anchor.onnx       a small anchor-based YOLOv5-style detector (classic Detect decode)
  OUTDIR/yolov8n.onnx             ultralytics YOLOv8n, random weights (only when ultralytics imports)
  OUTDIR/yolov5su.onnx            ultralytics anchor-free YOLOv5su, random weights (idem)
  OUTDIR/yolov6n.onnx             ultralytics YOLOv6n (ReLU, ConvTranspose upsampling), random weights (idem)
  OUTDIR/yolov8n_own.onnx         YOLOv8n with 3 classes of its own (forklift, dog, pallet in its
                                  `names` metadata), random weights (idem; no oracle: for the CLI)
  OUTDIR/yolov8n_half.onnx        YOLOv8n exported with half=True (fp16 weights and arithmetic;
                                  ultralytics writes its nodes out of topological order), with
                                  onnxruntime's output optimised and not (its own fp16 spread),
                                  and on the file widened to f32 (yolov8n_half.widened.*)
  OUTDIR/rtdetr_l.onnx, yolov10n_e2e.onnx, yolo26n_e2e.onnx
                                  files that select their boxes inside with top-k (RT-DETR-l;
                                  YOLOv10n / YOLO26n with nms=False), random weights (idem)
  OUTDIR/yolov8n_nms.onnx         YOLOv8n exported with nms=True (NMS inside; cac refuses it)
and next to every model <stem>.input.json (the seeded feeds) and <stem>.expected.json
(onnxruntime's CPU outputs for all graph outputs), plus OUTDIR/manifest.json.

Tensor JSON schema: {"<name>": {"shape": [..], "data": [row-major floats]}}; integer tensors
carry their values as floats plus "dtype": "int64".
"""

import argparse
import json
import os
import shutil
import sys
import tempfile
import zlib
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

sys.dont_write_bytecode = True  # leave no __pycache__ in the source tree
sys.path.insert(0, str(Path(__file__).resolve().parent))
from ort_run import read_tensors, run_session, session, write_tensors  # noqa: E402

F = TensorProto.FLOAT
I64 = TensorProto.INT64
INT64_MAX = np.iinfo(np.int64).max


# ----------------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------------


def rng_for(name):
    """A numpy generator seeded from the case name, so each case is independent of the others."""
    return np.random.default_rng(zlib.crc32(name.encode()))


def const(name, value, dtype=np.float32):
    """An initializer tensor."""
    return numpy_helper.from_array(np.asarray(value, dtype=dtype), name)


def i64(name, value):
    return const(name, value, np.int64)


class Case:
    """One op-level fixture: a graph plus the feeds it is run on."""

    def __init__(self, name, opset, nodes, feeds, outputs, inits=(), out_types=None):
        self.name = name
        self.opset = opset
        self.nodes = nodes
        self.feeds = feeds  # dict name -> np.ndarray (float32)
        self.outputs = outputs  # list of output names
        self.inits = list(inits)
        self.out_types = out_types or {}

    def model(self):
        inputs = [helper.make_tensor_value_info(k, F, list(v.shape)) for k, v in self.feeds.items()]
        outputs = [helper.make_tensor_value_info(o, self.out_types.get(o, F), None) for o in self.outputs]
        graph = helper.make_graph(self.nodes, self.name, inputs, outputs, initializer=self.inits)
        opsets = [helper.make_opsetid("", self.opset)]
        m = helper.make_model(graph, opset_imports=opsets, producer_name="cac-tests")
        m.ir_version = helper.find_min_ir_version_for(opsets)
        # Fill in the outputs' shapes (left open above) from ONNX's shape inference, or where that
        # cannot follow a computed shape (Shape -> ... -> Reshape), from an onnxruntime run.
        m = onnx.shape_inference.infer_shapes(m, check_type=True, strict_mode=True, data_prop=True)
        unknown = [o for o in m.graph.output if not o.type.tensor_type.HasField("shape")]
        if unknown:
            shapes = {k: v.shape for k, v in run_session(session(m.SerializeToString()), self.feeds).items()}
            for o in unknown:
                o.CopyFrom(helper.make_tensor_value_info(o.name, o.type.tensor_type.elem_type, shapes[o.name]))
        return m


def unary(name, opset, op, shape=(1, 4, 5, 6), low=None, high=None, **attrs):
    r = rng_for(name)
    x = r.uniform(low, high, shape) if low is not None else r.standard_normal(shape)
    return Case(name, opset, [helper.make_node(op, ["x"], ["out"], **attrs)],
                {"x": x.astype(np.float32)}, ["out"])


def normal(r, *shape):
    return r.standard_normal(shape).astype(np.float32)


# ----------------------------------------------------------------------------------------------
# Op cases
# ----------------------------------------------------------------------------------------------


def conv_cases():
    cases = []

    def conv(name, opset, cin, cout, k, hw, bias=True, group=1, **attrs):
        r = rng_for(name)
        w = normal(r, cout, cin // group, k, k) * np.float32(np.sqrt(2.0 / (cin // group * k * k)))
        inits = [const("w", w)]
        ins = ["x", "w"]
        if bias:
            inits.append(const("b", normal(r, cout) * 0.1))
            ins.append("b")
        node = helper.make_node("Conv", ins, ["out"], group=group, **attrs)
        cases.append(Case(name, opset, [node], {"x": normal(r, 1, cin, hw[0], hw[1])}, ["out"], inits))

    conv("conv_bias", 13, 3, 8, 3, (16, 16), kernel_shape=[3, 3], pads=[1, 1, 1, 1])
    conv("conv_stride2_asym_pads", 11, 4, 6, 3, (15, 16), bias=False,
         kernel_shape=[3, 3], strides=[2, 2], pads=[0, 1, 1, 2])
    conv("conv_depthwise", 17, 8, 8, 3, (12, 12), group=8, pads=[1, 1, 1, 1])
    conv("conv_dilation2", 18, 4, 5, 3, (14, 13), dilations=[2, 2], pads=[2, 2, 2, 2])
    conv("conv_1x1", 21, 16, 8, 1, (7, 9))
    # No kernel_shape / pads attributes at all: inferred from the weights, pads default to 0.
    conv("conv_defaults_stride2", 13, 3, 4, 2, (9, 9), strides=[2, 2])
    return cases


def batchnorm_cases():
    r = rng_for("batchnorm")
    c = 6
    inits = [const("scale", r.uniform(0.5, 1.5, c)), const("bias", normal(r, c) * 0.1),
             const("mean", normal(r, c) * 0.2), const("var", r.uniform(0.2, 2.0, c))]
    node = helper.make_node("BatchNormalization", ["x", "scale", "bias", "mean", "var"], ["out"],
                            epsilon=1e-3, momentum=0.97)
    bn = Case("batchnorm", 17, [node], {"x": normal(r, 1, c, 5, 7)}, ["out"], inits)

    # A short chain as ultralytics' unfused Conv block would be: Conv -> BatchNormalization -> SiLU.
    r = rng_for("conv_bn_silu")
    w = normal(r, 8, 3, 3, 3) * np.float32(np.sqrt(2.0 / 27))
    inits = [const("w", w), const("scale", r.uniform(0.5, 1.5, 8)), const("bias", normal(r, 8) * 0.1),
             const("mean", normal(r, 8) * 0.2), const("var", r.uniform(0.2, 2.0, 8))]
    nodes = [
        helper.make_node("Conv", ["x", "w"], ["c"], kernel_shape=[3, 3], pads=[1, 1, 1, 1], strides=[2, 2]),
        helper.make_node("BatchNormalization", ["c", "scale", "bias", "mean", "var"], ["bn"], epsilon=1e-3),
        helper.make_node("Sigmoid", ["bn"], ["s"]),
        helper.make_node("Mul", ["bn", "s"], ["out"]),
    ]
    chain = Case("conv_bn_silu", 13, nodes, {"x": normal(r, 1, 3, 12, 12)}, ["out"], inits)
    return [bn, chain]


def activation_cases():
    cases = [
        unary("relu", 11, "Relu"),
        unary("sigmoid", 13, "Sigmoid", low=-8.0, high=8.0),
        unary("leaky_relu", 13, "LeakyRelu", alpha=0.1),
        unary("hard_swish", 17, "HardSwish", low=-5.0, high=5.0),
        unary("hard_sigmoid", 13, "HardSigmoid", low=-5.0, high=5.0, alpha=0.2, beta=0.5),
        unary("tanh", 18, "Tanh"),
        unary("exp", 21, "Exp"),
        unary("sqrt", 13, "Sqrt", low=0.01, high=4.0),
        unary("neg", 11, "Neg"),
    ]
    r = rng_for("silu")
    nodes = [helper.make_node("Sigmoid", ["x"], ["s"]), helper.make_node("Mul", ["x", "s"], ["out"])]
    cases.append(Case("silu", 17, nodes, {"x": normal(r, 1, 4, 5, 6) * 3}, ["out"]))

    # Clip: opset 11+ takes min/max as (optional) inputs; an empty name skips one.
    r = rng_for("clip_min_max")
    cases.append(Case("clip_min_max", 11, [helper.make_node("Clip", ["x", "lo", "hi"], ["out"])],
                      {"x": normal(r, 1, 4, 5, 6) * 3}, ["out"],
                      [const("lo", 0.0), const("hi", 6.0)]))
    r = rng_for("clip_max_only")
    cases.append(Case("clip_max_only", 13, [helper.make_node("Clip", ["x", "", "hi"], ["out"])],
                      {"x": normal(r, 1, 4, 5, 6) * 3}, ["out"], [const("hi", 0.5)]))
    return cases


def binary_cases():
    cases = []

    def binary(name, opset, op, a, b, b_const):
        inits, feeds = [], {"a": a}
        if b_const:
            inits.append(const("b", b))
        else:
            feeds["b"] = b
        cases.append(Case(name, opset, [helper.make_node(op, ["a", "b"], ["out"])], feeds, ["out"], inits))

    r = rng_for("binary")
    binary("add_const_rank1", 13, "Add", normal(r, 1, 4, 5, 6), normal(r, 6), True)
    binary("sub_scalar", 11, "Sub", normal(r, 1, 4, 5, 6), np.float32(0.75), True)
    binary("mul_two_bcast", 17, "Mul", normal(r, 1, 4, 5, 6), normal(r, 1, 4, 1, 6), False)
    binary("div_bcast", 13, "Div", normal(r, 1, 4, 5, 6), r.uniform(0.5, 2.0, (4, 1, 1)).astype(np.float32), False)
    binary("div_scalar_lhs", 18, "Div", r.uniform(0.5, 2.0, (1, 3, 4)).astype(np.float32), np.float32(2.0), True)
    binary("pow_scalar", 13, "Pow", normal(r, 1, 4, 5, 6), np.float32(2.0), True)
    binary("pow_two", 21, "Pow", r.uniform(0.1, 3.0, (1, 4, 5, 6)).astype(np.float32),
           r.uniform(-1.5, 2.5, (5, 1)).astype(np.float32), False)
    binary("add_two_bcast_both", 11, "Add", normal(r, 2, 1, 6), normal(r, 1, 5, 1), False)
    return cases


def concat_split_cases():
    cases = []
    r = rng_for("concat")
    for name, axis, shapes in [("concat_axis1", 1, [(1, 2, 4, 5), (1, 3, 4, 5), (1, 1, 4, 5)]),
                               ("concat_axis_neg1", -1, [(1, 3, 4, 2), (1, 3, 4, 5)]),
                               ("concat_axis0", 0, [(1, 3, 4), (2, 3, 4)])]:
        feeds = {f"x{i}": normal(r, *s) for i, s in enumerate(shapes)}
        opset = {1: 13, -1: 11, 0: 18}[axis]
        cases.append(Case(name, opset, [helper.make_node("Concat", list(feeds), ["out"], axis=axis)],
                          feeds, ["out"]))

    r = rng_for("split")
    x = normal(r, 1, 8, 3, 4)
    outs = ["o0", "o1", "o2"]
    cases.append(Case("split_op11_attr", 11, [helper.make_node("Split", ["x"], outs, axis=1, split=[2, 3, 3])],
                      {"x": x}, outs))
    cases.append(Case("split_op13_input", 13, [helper.make_node("Split", ["x", "sizes"], ["o0", "o1"], axis=-1)],
                      {"x": x}, ["o0", "o1"], [i64("sizes", [1, 3])]))
    cases.append(Case("split_op13_equal", 13, [helper.make_node("Split", ["x"], ["o0", "o1"], axis=1)],
                      {"x": x}, ["o0", "o1"]))
    cases.append(Case("split_op18_num_outputs", 18,
                      [helper.make_node("Split", ["x"], ["o0", "o1", "o2", "o3"], axis=1, num_outputs=4)],
                      {"x": x}, ["o0", "o1", "o2", "o3"]))
    return cases


def shape_op_cases():
    cases = []
    r = rng_for("slice")
    x = normal(r, 1, 4, 10, 9)
    cases.append(Case("slice_neg_indices_steps", 13, [helper.make_node("Slice", ["x", "st", "en", "ax", "sp"], ["out"])],
                      {"x": x}, ["out"],
                      [i64("st", [1, -5]), i64("en", [INT64_MAX, -1]), i64("ax", [2, -1]), i64("sp", [2, 1])]))
    cases.append(Case("slice_no_axes", 11, [helper.make_node("Slice", ["x", "st", "en"], ["out"])],
                      {"x": x}, ["out"], [i64("st", [0, 1, 0, 2]), i64("en", [1, 3, 7, 100])]))
    # As classic YOLOv5's Focus layer: every second pixel (step 2), starting at 0 or 1.
    cases.append(Case("slice_step2", 17, [helper.make_node("Slice", ["x", "st", "en", "ax", "sp"], ["out"])],
                      {"x": x}, ["out"],
                      [i64("st", [1, 0]), i64("en", [INT64_MAX, INT64_MAX]), i64("ax", [2, 3]), i64("sp", [2, 2])]))

    r = rng_for("reshape")
    cases.append(Case("reshape_zero_neg1", 13, [helper.make_node("Reshape", ["x", "shape"], ["out"])],
                      {"x": normal(r, 1, 6, 4, 5)}, ["out"], [i64("shape", [0, -1, 4])]))
    cases.append(Case("reshape_plain", 21, [helper.make_node("Reshape", ["x", "shape"], ["out"])],
                      {"x": normal(r, 2, 3, 4)}, ["out"], [i64("shape", [4, 6])]))
    cases.append(Case("transpose", 13, [helper.make_node("Transpose", ["x"], ["out"], perm=[0, 2, 3, 1])],
                      {"x": normal(r, 1, 3, 4, 5)}, ["out"]))
    cases.append(Case("transpose_5d", 11, [helper.make_node("Transpose", ["x"], ["out"], perm=[0, 1, 3, 4, 2])],
                      {"x": normal(r, 1, 3, 7, 2, 4)}, ["out"]))
    cases.append(Case("flatten", 13, [helper.make_node("Flatten", ["x"], ["out"], axis=1)],
                      {"x": normal(r, 2, 3, 4, 5)}, ["out"]))

    # Unsqueeze / Squeeze: axes attribute up to opset 12, an input from opset 13.
    r = rng_for("squeeze")
    cases.append(Case("unsqueeze_op11_attr", 11, [helper.make_node("Unsqueeze", ["x"], ["out"], axes=[0, 3])],
                      {"x": normal(r, 3, 4, 5)}, ["out"]))
    cases.append(Case("unsqueeze_op13_input", 13, [helper.make_node("Unsqueeze", ["x", "axes"], ["out"])],
                      {"x": normal(r, 3, 4, 5)}, ["out"], [i64("axes", [-1, 1])]))
    cases.append(Case("squeeze_op11_attr", 11, [helper.make_node("Squeeze", ["x"], ["out"], axes=[1, 3])],
                      {"x": normal(r, 2, 1, 4, 1)}, ["out"]))
    cases.append(Case("squeeze_op13_input", 13, [helper.make_node("Squeeze", ["x", "axes"], ["out"])],
                      {"x": normal(r, 2, 1, 4, 1)}, ["out"], [i64("axes", [-1])]))
    cases.append(Case("squeeze_op13_all", 13, [helper.make_node("Squeeze", ["x"], ["out"])],
                      {"x": normal(r, 1, 3, 1, 4)}, ["out"]))
    r = rng_for("expand")
    cases.append(Case("expand", 13, [helper.make_node("Expand", ["x", "shape"], ["out"])],
                      {"x": normal(r, 1, 4, 1)}, ["out"], [i64("shape", [2, 4, 5])]))
    return cases


def resize_cases():
    cases = []
    r = rng_for("resize")
    x = normal(r, 1, 3, 5, 6)

    def resize(name, opset, ins, inits, **attrs):
        cases.append(Case(name, opset, [helper.make_node("Resize", ["x"] + ins, ["out"], **attrs)],
                          {"x": x}, ["out"], inits))

    nearest = dict(mode="nearest", coordinate_transformation_mode="asymmetric", nearest_mode="floor")
    # Opset 11 requires the roi input (an empty tensor is fine); from opset 13 it may be skipped by "".
    resize("resize_nearest_scales_op11", 11, ["roi", "scales"],
           [const("roi", np.zeros(0)), const("scales", [1, 1, 2, 2])], **nearest)
    resize("resize_nearest_scales_op13", 13, ["", "scales"], [const("scales", [1, 1, 2, 2])], **nearest)
    resize("resize_linear_half_pixel", 13, ["", "scales"], [const("scales", [1, 1, 2, 2])],
           mode="linear", coordinate_transformation_mode="half_pixel")
    resize("resize_linear_half_pixel_frac", 18, ["", "scales"], [const("scales", [1, 1, 1.5, 0.5])],
           mode="linear", coordinate_transformation_mode="half_pixel")
    resize("resize_linear_align_corners_sizes", 18, ["", "", "sizes"], [i64("sizes", [1, 3, 11, 13])],
           mode="linear", coordinate_transformation_mode="align_corners")
    resize("resize_nearest_sizes", 17, ["", "", "sizes"], [i64("sizes", [1, 3, 10, 12])], **nearest)
    return cases


def pool_cases():
    r = rng_for("pool")
    x = normal(r, 1, 3, 9, 9)

    def pool(name, opset, op, **attrs):
        return Case(name, opset, [helper.make_node(op, ["x"], ["out"], **attrs)], {"x": x}, ["out"])

    return [
        pool("maxpool_k5_s1_p2", 13, "MaxPool", kernel_shape=[5, 5], strides=[1, 1], pads=[2, 2, 2, 2]),
        pool("maxpool_k2_s2", 11, "MaxPool", kernel_shape=[2, 2], strides=[2, 2]),
        pool("maxpool_k3_s2_ceil0", 17, "MaxPool", kernel_shape=[3, 3], strides=[2, 2], pads=[1, 1, 1, 1],
             ceil_mode=0),
        pool("avgpool_k2_s2", 13, "AveragePool", kernel_shape=[2, 2], strides=[2, 2]),
        pool("avgpool_k3_s1_p1_exclude_pad", 11, "AveragePool", kernel_shape=[3, 3], strides=[1, 1],
             pads=[1, 1, 1, 1], count_include_pad=0),
        pool("global_avgpool", 13, "GlobalAveragePool"),
    ]


def softmax_reduce_cases():
    cases = []
    r = rng_for("softmax")
    x = normal(r, 1, 4, 3, 5) * 2
    cases.append(Case("softmax_axis1", 13, [helper.make_node("Softmax", ["x"], ["out"], axis=1)], {"x": x}, ["out"]))
    cases.append(Case("softmax_axis_neg1", 11, [helper.make_node("Softmax", ["x"], ["out"], axis=-1)],
                      {"x": x}, ["out"]))
    # Before opset 13 Softmax flattens to 2-D at `axis` ([1, 4*3*5] here): the normalisation runs
    # over all of dims 1.. together, not over dim 1 alone.
    cases.append(Case("softmax_axis1_op11_coerced", 11, [helper.make_node("Softmax", ["x"], ["out"], axis=1)],
                      {"x": x}, ["out"]))

    r = rng_for("reduce")
    x = normal(r, 1, 4, 5, 6)
    cases.append(Case("reducemax_keep_attr", 13,
                      [helper.make_node("ReduceMax", ["x"], ["out"], axes=[1], keepdims=1)], {"x": x}, ["out"]))
    cases.append(Case("reducemean_nokeep_attr", 13,
                      [helper.make_node("ReduceMean", ["x"], ["out"], axes=[2, 3], keepdims=0)], {"x": x}, ["out"]))
    cases.append(Case("reducemean_keep_input", 18,
                      [helper.make_node("ReduceMean", ["x", "axes"], ["out"], keepdims=1)], {"x": x}, ["out"],
                      [i64("axes", [-1])]))
    cases.append(Case("reducemax_nokeep_input", 18,
                      [helper.make_node("ReduceMax", ["x", "axes"], ["out"], keepdims=0)], {"x": x}, ["out"],
                      [i64("axes", [1, 2])]))
    return cases


def gather_shape_cases():
    cases = []
    r = rng_for("gather")
    x = normal(r, 1, 5, 4, 3)
    cases.append(Case("gather_axis1", 13, [helper.make_node("Gather", ["x", "idx"], ["out"], axis=1)],
                      {"x": x}, ["out"], [i64("idx", [4, 0, 2, 2])]))
    cases.append(Case("gather_scalar_neg", 13, [helper.make_node("Gather", ["x", "idx"], ["out"], axis=2)],
                      {"x": x}, ["out"], [i64("idx", -1)]))

    # Shape -> Gather -> Unsqueeze -> Concat -> Reshape, as exporters write `x.view(x.shape[0], c, -1)`.
    r = rng_for("shape_chain")
    nodes = [
        helper.make_node("Shape", ["x"], ["s"]),
        helper.make_node("Gather", ["s", "i0"], ["n"], axis=0),
        helper.make_node("Gather", ["s", "i1"], ["c"], axis=0),
        helper.make_node("Unsqueeze", ["n", "ax0"], ["n1"]),
        helper.make_node("Unsqueeze", ["c", "ax0"], ["c1"]),
        helper.make_node("Concat", ["n1", "c1", "minus1"], ["shape"], axis=0),
        helper.make_node("Reshape", ["x", "shape"], ["out"]),
    ]
    cases.append(Case("shape_gather_reshape", 13, nodes, {"x": normal(r, 1, 8, 4, 6)}, ["out"],
                      [i64("i0", 0), i64("i1", 1), i64("ax0", [0]), i64("minus1", [-1])]))

    r = rng_for("constant")
    value = numpy_helper.from_array(normal(r, 1, 4, 1, 1), "cval")
    nodes = [helper.make_node("Constant", [], ["c"], value=value),
             helper.make_node("Constant", [], ["k"], value_float=0.5),
             helper.make_node("Mul", ["x", "k"], ["xk"]),
             helper.make_node("Add", ["xk", "c"], ["out"])]
    cases.append(Case("constant", 13, nodes, {"x": normal(r, 1, 4, 3, 3)}, ["out"]))

    r = rng_for("constant_of_shape")
    fill = numpy_helper.from_array(np.array([0.25], dtype=np.float32), "fill")
    nodes = [helper.make_node("Shape", ["x"], ["s"]),
             helper.make_node("ConstantOfShape", ["s"], ["z"], value=fill),
             helper.make_node("Add", ["x", "z"], ["out"])]
    cases.append(Case("constant_of_shape", 13, nodes, {"x": normal(r, 1, 2, 3, 4)}, ["out"]))

    r = rng_for("cast")
    cases.append(Case("cast_float", 13, [helper.make_node("Cast", ["x"], ["out"], to=F)],
                      {"x": normal(r, 2, 3)}, ["out"]))
    nodes = [helper.make_node("Shape", ["x"], ["s"]),
             helper.make_node("Cast", ["s"], ["sf"], to=F),
             helper.make_node("Slice", ["sf", "st", "en"], ["sf_tail"]),
             helper.make_node("ReduceMax", ["x"], ["m"], axes=[2, 3], keepdims=0),
             helper.make_node("Mul", ["m", "sf_tail"], ["out"])]
    cases.append(Case("cast_shape_int64", 13, nodes, {"x": normal(r, 1, 4, 3, 5)}, ["out", "sf"],
                      [i64("st", [3]), i64("en", [4])]))
    cases.append(Case("identity", 13, [helper.make_node("Identity", ["x"], ["out"])],
                      {"x": normal(r, 2, 3)}, ["out"]))

    r = rng_for("where")
    a, b = normal(r, 1, 3, 4), normal(r, 1, 3, 4)
    nodes = [helper.make_node("Greater", ["a", "b"], ["g"]), helper.make_node("Where", ["g", "a", "b"], ["out"])]
    cases.append(Case("where_greater", 13, nodes, {"a": a, "b": b}, ["out"]))
    nodes = [helper.make_node("Less", ["a", "zero"], ["l"]),
             helper.make_node("Where", ["l", "fill", "a"], ["out"])]
    cases.append(Case("where_less_scalar", 17, nodes, {"a": a}, ["out"],
                      [const("zero", 0.0), const("fill", -1.0)]))
    return cases


def matmul_topk_cases():
    cases = []
    # DFL-like projection: softmax over 16 bins, then a dot with [0, 1, ..., 15].
    r = rng_for("matmul_dfl")
    nodes = [helper.make_node("Softmax", ["x"], ["p"], axis=-1),
             helper.make_node("MatMul", ["p", "proj"], ["out"])]
    cases.append(Case("matmul_dfl", 13, nodes, {"x": normal(r, 1, 4, 10, 16) * 2}, ["out"],
                      [const("proj", np.arange(16, dtype=np.float32).reshape(16, 1))]))
    r = rng_for("matmul_batched")
    cases.append(Case("matmul_batched", 13, [helper.make_node("MatMul", ["a", "b"], ["out"])],
                      {"a": normal(r, 1, 2, 3, 4), "b": normal(r, 2, 4, 5)}, ["out"]))

    r = rng_for("topk")
    cases.append(Case("topk", 11, [helper.make_node("TopK", ["x", "k"], ["values", "indices"], axis=-1,
                                                    largest=1, sorted=1)],
                      {"x": normal(r, 2, 20)}, ["values", "indices"], [i64("k", [5])],
                      out_types={"indices": I64}))
    return cases


def conv_transpose_cases():
    cases = []

    def convt(name, opset, cin, cout, k, hw, bias=True, group=1, **attrs):
        r = rng_for(name)
        w = normal(r, cin, cout // group, k, k) * np.float32(np.sqrt(2.0 / (cin // group * k * k)))
        inits = [const("w", w)]
        ins = ["x", "w"]
        if bias:
            inits.append(const("b", normal(r, cout) * 0.1))
            ins.append("b")
        node = helper.make_node("ConvTranspose", ins, ["out"], group=group, **attrs)
        cases.append(Case(name, opset, [node], {"x": normal(r, 1, cin, hw[0], hw[1])}, ["out"], inits))

    # As YOLOv6 and ultralytics' segmentation heads upsample: kernel 2, stride 2.
    convt("convt_k2_s2", 13, 8, 6, 2, (5, 6), kernel_shape=[2, 2], strides=[2, 2])
    convt("convt_k3_s2_pads_outpad", 11, 4, 5, 3, (6, 5), strides=[2, 2], pads=[1, 1, 1, 1],
          output_padding=[1, 1])
    convt("convt_asym_pads_no_bias", 17, 3, 4, 3, (5, 7), bias=False, strides=[2, 1], pads=[0, 2, 1, 0])
    convt("convt_depthwise", 18, 6, 6, 4, (5, 5), group=6, strides=[2, 2], pads=[1, 1, 1, 1])
    convt("convt_group2_dilation2", 13, 4, 6, 3, (6, 6), group=2, dilations=[2, 2], pads=[1, 0, 1, 2])
    convt("convt_output_shape", 11, 3, 4, 3, (5, 5), strides=[2, 2], output_shape=[10, 9])
    convt("convt_same_upper", 13, 3, 2, 3, (4, 5), strides=[2, 2], auto_pad="SAME_UPPER")
    convt("convt_same_lower", 21, 3, 2, 4, (4, 5), bias=False, strides=[3, 2], auto_pad="SAME_LOWER")
    return cases


def transformer_cases():
    """The ops RT-DETR's decoder brings: Erf (GELU), LayerNormalization, GridSample (deformable
    attention), GatherElements (query selection), Xor (masks)."""
    cases = [unary("erf", 13, "Erf", low=-3.0, high=3.0)]
    r = rng_for("gelu")
    nodes = [helper.make_node("Div", ["x", "sqrt2"], ["xs"]), helper.make_node("Erf", ["xs"], ["e"]),
             helper.make_node("Add", ["e", "one"], ["e1"]), helper.make_node("Mul", ["x", "e1"], ["xe"]),
             helper.make_node("Mul", ["xe", "half"], ["out"])]
    cases.append(Case("gelu_erf", 17, nodes, {"x": normal(r, 2, 7, 16) * 2}, ["out"],
                      [const("sqrt2", np.sqrt(2.0)), const("one", 1.0), const("half", 0.5)]))

    def layer_norm(name, shape, axis, outputs=("out",), bias=True, **attrs):
        r = rng_for(name)
        norm = shape[axis:]
        inits = [const("scale", r.uniform(0.5, 1.5, norm))]
        ins = ["x", "scale"]
        if bias:
            inits.append(const("b", normal(r, *norm) * 0.2))
            ins.append("b")
        node = helper.make_node("LayerNormalization", ins, list(outputs), axis=axis, **attrs)
        x = normal(r, *shape) * 2 + np.float32(0.5)
        cases.append(Case(name, 17, [node], {"x": x}, list(outputs), inits))

    layer_norm("layernorm_last", (2, 6, 16), -1)
    layer_norm("layernorm_middle_axis", (2, 3, 4, 5), 1, bias=False, epsilon=1e-3)
    layer_norm("layernorm_stats", (3, 5, 8), 2, outputs=("out", "mean", "inv_std"))

    def grid_sample(name, opset, x_shape, grid_shape, wrt="x", spread=1.2, **attrs):
        r = rng_for(name)
        x = normal(r, *x_shape)
        grid = r.uniform(-spread, spread, grid_shape).astype(np.float32)
        node = helper.make_node("GridSample", ["x", "grid"], ["out"], **attrs)
        # One input fed (the other an initializer), so the gradient test checks either.
        feeds, inits = ({"x": x}, [const("grid", grid)]) if wrt == "x" else ({"grid": grid}, [const("x", x)])
        cases.append(Case(name, opset, [node], feeds, ["out"], inits))

    grid_sample("gridsample_bilinear_zeros", 16, (1, 3, 5, 6), (1, 4, 3, 2))
    grid_sample("gridsample_bilinear_zeros_align", 16, (2, 2, 4, 5), (2, 3, 3, 2), align_corners=1)
    grid_sample("gridsample_bilinear_border", 16, (1, 2, 6, 4), (1, 5, 2, 2), padding_mode="border")
    grid_sample("gridsample_linear_border_align", 20, (1, 3, 4, 4), (1, 3, 4, 2), mode="linear",
                padding_mode="border", align_corners=1)
    grid_sample("gridsample_bilinear_reflection", 16, (1, 2, 5, 5), (1, 4, 4, 2), spread=2.5,
                padding_mode="reflection")
    grid_sample("gridsample_linear_reflection_align", 20, (1, 2, 4, 6), (1, 3, 5, 2), spread=2.5,
                mode="linear", padding_mode="reflection", align_corners=1)
    grid_sample("gridsample_nearest_zeros", 16, (1, 3, 5, 6), (1, 4, 5, 2), mode="nearest")
    grid_sample("gridsample_nearest_border_align", 20, (1, 2, 4, 5), (1, 3, 3, 2), mode="nearest",
                padding_mode="border", align_corners=1)
    grid_sample("gridsample_nearest_reflection", 20, (1, 2, 4, 5), (1, 3, 4, 2), spread=2.5,
                mode="nearest", padding_mode="reflection")
    # With respect to the grid (the input a constant): deformable attention's sampling offsets.
    grid_sample("gridsample_grid_bilinear_zeros", 16, (1, 3, 5, 6), (1, 3, 4, 2), wrt="grid")
    grid_sample("gridsample_grid_linear_border_align", 20, (1, 2, 6, 5), (1, 2, 3, 2), wrt="grid",
                mode="linear", padding_mode="border", align_corners=1)
    grid_sample("gridsample_grid_bilinear_reflection", 16, (1, 2, 5, 5), (1, 2, 3, 2), wrt="grid",
                spread=2.0, padding_mode="reflection")

    r = rng_for("gather_elements")
    x = normal(r, 3, 4, 5)
    cases.append(Case("gather_elements_axis0", 13, [helper.make_node("GatherElements", ["x", "idx"], ["out"], axis=0)],
                      {"x": x}, ["out"], [i64("idx", r.integers(-3, 3, (2, 4, 5)))]))
    cases.append(Case("gather_elements_last_smaller", 11,
                      [helper.make_node("GatherElements", ["x", "idx"], ["out"], axis=-1)],
                      {"x": x}, ["out"], [i64("idx", r.integers(-5, 5, (3, 2, 7)))]))
    # As RT-DETR selects its top queries: TopK indices, tiled, gather the query features.
    nodes = [helper.make_node("ReduceMax", ["x"], ["m"], axes=[2], keepdims=0),
             helper.make_node("TopK", ["m", "k"], ["v", "i"], axis=1),
             helper.make_node("Unsqueeze", ["i", "ax2"], ["i3"]),
             helper.make_node("Tile", ["i3", "reps"], ["it"]),
             helper.make_node("GatherElements", ["x", "it"], ["out"], axis=1)]
    cases.append(Case("topk_gather_elements", 13, nodes, {"x": normal(r, 1, 12, 6)}, ["out"],
                      [i64("k", [4]), i64("ax2", [2]), i64("reps", [1, 1, 6])]))

    r = rng_for("xor")
    nodes = [helper.make_node("Greater", ["a", "zero"], ["pa"]), helper.make_node("Greater", ["b", "zero"], ["pb"]),
             helper.make_node("Xor", ["pa", "pb"], ["x"]), helper.make_node("Cast", ["x"], ["out"], to=F)]
    cases.append(Case("xor", 16, nodes, {"a": normal(r, 2, 3, 4), "b": normal(r, 3, 1)}, ["out"],
                      [const("zero", 0.0)]))
    # Host booleans: Xor of shape comparisons (exported mask arithmetic).
    nodes = [helper.make_node("Shape", ["a"], ["s"]), helper.make_node("Greater", ["s", "two"], ["g"]),
             helper.make_node("Less", ["s", "five"], ["l"]), helper.make_node("Xor", ["g", "l"], ["x"]),
             helper.make_node("Cast", ["x"], ["xf"], to=F), helper.make_node("Mul", ["a", "xf"], ["out"])]
    cases.append(Case("xor_host", 13, nodes, {"a": normal(r, 2, 3, 5, 4)}, ["out"],
                      [i64("two", 2), i64("five", 5)]))
    return cases


def op_cases():
    return (conv_cases() + batchnorm_cases() + activation_cases() + binary_cases() + concat_split_cases()
            + shape_op_cases() + resize_cases() + pool_cases() + softmax_reduce_cases()
            + gather_shape_cases() + matmul_topk_cases() + conv_transpose_cases() + transformer_cases())


# ----------------------------------------------------------------------------------------------
# Hand-built anchor-based YOLOv5 detector
# ----------------------------------------------------------------------------------------------

ANCHORS = {8: [10, 13, 16, 30, 33, 23], 16: [30, 61, 62, 45, 59, 119], 32: [116, 90, 156, 198, 373, 326]}
NUM_CLASSES = 80
# Conf biases, tuned once so that ~100 candidates (a few above 0.5) have objectness * class > 0.3
# on the seeded input (asserted in main).
OBJ_BIAS = 0.0
CLS_BIAS = -4.0
# The head's weights are scaled up so that its logits spread (std ~1) like a trained model's.
HEAD_GAIN = 3.0


def split_head(opset=17, size=64, cells=4):
    """Boxes and class scores in two outputs, as mmdeploy's dense export (`with_nms=False`)
    writes them: `boxes` [1, N, 4] (x1, y1, x2, y2 in input pixels) and `scores` [1, N, 80]
    (sigmoid probabilities), N = (size / cells)^2 cells of a strided convolution."""
    r = np.random.default_rng(9)
    n = (size // cells) ** 2
    w = r.standard_normal((4 + NUM_CLASSES, 3, cells, cells)) * np.sqrt(2.0 / (3 * cells * cells))
    b = np.concatenate([np.zeros(4), np.full(NUM_CLASSES, -1.0)])
    grid = np.stack(np.meshgrid(np.arange(size // cells), np.arange(size // cells)), -1).reshape(-1, 2)
    centre = ((grid + 0.5) * cells).astype(np.float32)  # [N, 2] (x, y)
    inits = [const("w", w), const("b", b), i64("flat", [1, 4 + NUM_CLASSES, n]),
             const("centre", np.concatenate([centre, centre], 1)[None]),
             const("half", np.array([-1, -1, 1, 1], np.float32) * cells),
             i64("s0", [0]), i64("s4", [4]), i64("send", [4 + NUM_CLASSES]), i64("ax2", [2])]
    nodes = [
        helper.make_node("Conv", ["images", "w", "b"], ["y"], kernel_shape=[cells, cells], strides=[cells, cells]),
        helper.make_node("Reshape", ["y", "flat"], ["yf"]),
        helper.make_node("Transpose", ["yf"], ["yt"], perm=[0, 2, 1]),
        helper.make_node("Slice", ["yt", "s0", "s4", "ax2"], ["raw_box"]),
        helper.make_node("Exp", ["raw_box"], ["tb"]),
        helper.make_node("Mul", ["tb", "half"], ["off"]),
        helper.make_node("Add", ["centre", "off"], ["boxes"]),
        helper.make_node("Slice", ["yt", "s4", "send", "ax2"], ["logits"]),
        helper.make_node("Sigmoid", ["logits"], ["scores"]),
    ]
    graph = helper.make_graph(
        nodes, "split_head",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [1, n, 4]),
         helper.make_tensor_value_info("scores", TensorProto.FLOAT, [1, n, NUM_CLASSES])],
        inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)], ir_version=8)


def yolov5_anchor(opset=17, size=320):
    """Conv+SiLU stride-2 backbone, three 1x1 heads at strides 8/16/32 and the classic Detect decode."""
    r = np.random.default_rng(5)
    no = 5 + NUM_CLASSES
    nodes, inits = [], []

    def conv(x, cin, cout, k, stride, name, act=True, bias=None, gain=1.0):
        w = r.standard_normal((cout, cin, k, k)) * (gain * np.sqrt(2.0 / (cin * k * k)))
        b = r.standard_normal(cout) * 0.05 if bias is None else bias
        inits.extend([const(f"{name}.weight", w), const(f"{name}.bias", b)])
        y = f"{name}.conv"
        nodes.append(helper.make_node("Conv", [x, f"{name}.weight", f"{name}.bias"], [y], name=f"{name}/Conv",
                                      kernel_shape=[k, k], strides=[stride, stride], pads=[k // 2] * 4,
                                      dilations=[1, 1], group=1))
        if not act:
            return y
        nodes.append(helper.make_node("Sigmoid", [y], [f"{name}.sig"], name=f"{name}/Sigmoid"))
        nodes.append(helper.make_node("Mul", [y, f"{name}.sig"], [f"{name}.out"], name=f"{name}/Mul"))
        return f"{name}.out"

    x = "images"
    widths = [16, 32, 48, 64, 96]
    cin, feats = 3, {}
    for i, c in enumerate(widths):
        x = conv(x, cin, c, 3, 2, f"model.{i}")
        cin = c
        feats[2 ** (i + 1)] = (x, c)

    inits += [i64("split_sizes", [2, 2, no - 4]), const("two", 2.0), i64("flat", [1, -1, no])]
    flat_outs = []
    for stride in (8, 16, 32):
        feat, c = feats[stride]
        n = size // stride
        head_bias = np.concatenate([[0.0, 0.0, 0.0, 0.0, OBJ_BIAS], np.full(NUM_CLASSES, CLS_BIAS)])
        head_bias = np.tile(head_bias, 3) + r.standard_normal(3 * no) * 0.1
        p = f"head{stride}"
        y = conv(feat, c, 3 * no, 1, 1, p, act=False, bias=head_bias, gain=HEAD_GAIN)
        shape = f"{p}.shape"
        inits.append(i64(shape, [1, 3, no, n, n]))
        # grid holds (x - 0.5, y - 0.5) per cell; anchor_grid the anchors in pixels.
        gy, gx = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        grid = np.broadcast_to(np.stack([gx, gy], -1)[None, None] - 0.5, (1, 3, n, n, 2))
        anchors = np.array(ANCHORS[stride], dtype=np.float32).reshape(1, 3, 1, 1, 2)
        inits += [const(f"{p}.grid", grid), const(f"{p}.anchor_grid", np.broadcast_to(anchors, (1, 3, n, n, 2))),
                  const(f"{p}.stride", float(stride))]
        nodes += [
            helper.make_node("Reshape", [y, shape], [f"{p}.r"], name=f"{p}/Reshape"),
            helper.make_node("Transpose", [f"{p}.r"], [f"{p}.t"], name=f"{p}/Transpose", perm=[0, 1, 3, 4, 2]),
            helper.make_node("Sigmoid", [f"{p}.t"], [f"{p}.s"], name=f"{p}/Sigmoid"),
            helper.make_node("Split", [f"{p}.s", "split_sizes"], [f"{p}.xy", f"{p}.wh", f"{p}.conf"],
                             name=f"{p}/Split", axis=4),
            helper.make_node("Mul", [f"{p}.xy", "two"], [f"{p}.xy2"], name=f"{p}/Mul_xy"),
            helper.make_node("Add", [f"{p}.xy2", f"{p}.grid"], [f"{p}.xyg"], name=f"{p}/Add_grid"),
            helper.make_node("Mul", [f"{p}.xyg", f"{p}.stride"], [f"{p}.xyo"], name=f"{p}/Mul_stride"),
            helper.make_node("Mul", [f"{p}.wh", "two"], [f"{p}.wh2"], name=f"{p}/Mul_wh"),
            helper.make_node("Pow", [f"{p}.wh2", "two"], [f"{p}.whp"], name=f"{p}/Pow"),
            helper.make_node("Mul", [f"{p}.whp", f"{p}.anchor_grid"], [f"{p}.who"], name=f"{p}/Mul_anchor"),
            helper.make_node("Concat", [f"{p}.xyo", f"{p}.who", f"{p}.conf"], [f"{p}.cat"], name=f"{p}/Concat",
                             axis=4),
            helper.make_node("Reshape", [f"{p}.cat", "flat"], [f"{p}.flat"], name=f"{p}/Reshape_out"),
        ]
        flat_outs.append(f"{p}.flat")
    nodes.append(helper.make_node("Concat", flat_outs, ["output0"], name="Detect/Concat", axis=1))
    total = 3 * sum((size // s) ** 2 for s in (8, 16, 32))
    graph = helper.make_graph(
        nodes, "yolov5_anchor",
        [helper.make_tensor_value_info("images", F, [1, 3, size, size])],
        [helper.make_tensor_value_info("output0", F, [1, total, no])], initializer=inits)
    opsets = [helper.make_opsetid("", opset)]
    m = helper.make_model(graph, opset_imports=opsets, producer_name="cac-tests")
    m.ir_version = helper.find_min_ir_version_for(opsets)
    return m


# ----------------------------------------------------------------------------------------------
# Ultralytics exports (random weights, nothing downloaded)
# ----------------------------------------------------------------------------------------------

# (stem, model yaml, opset). 18 is what ultralytics picks by itself (opset=None) with torch >= 2.4,
# 17 what it picked with torch 1.13-2.3. Both exports are simplified by onnxslim (ultralytics' default).
ULTRALYTICS_MODELS = [("yolov8n", "yolov8n.yaml", 18), ("yolov5su", "yolov5su.yaml", 17),
                      ("yolov6n", "yolov6n.yaml", 17)]
# Exports checked on their raw output alone (manifest kind "export", not "detector"): none now.
# YOLOv6n (ConvTranspose upsampling in its neck) was, while cac's class-aware NMS moved boxes by
# class x 1e5 in f32: its scores do not saturate, and the quarter-pixel rounding at class 28 flipped
# an NMS decision that the test's decoder (and ultralytics) kept.
RAW_ONLY = set()
ULTRALYTICS_SIMPLIFY = True
# A freshly built ultralytics model's activations vanish through its depth (torch's default conv
# init) and its head outputs are nearly constant, a weak oracle. So, still with random weights:
# BatchNorm gammas/betas are randomised and their running stats set from a seeded calibration
# batch (as a trained model's would be), and the head's last convs are scaled so their outputs
# spread (box logits std 2, class logits std 1, class bias -5.5: ~50 cells score above 0.3).
BOX_LOGIT_STD, CLS_LOGIT_STD, CLS_LOGIT_BIAS = 2.0, 1.0, -5.5
CALIB_BATCH = 8
# A model trained on a user's own classes, as ultralytics writes it: nc = 3 and their names.
OWN_CLASSES = ["forklift", "dog", "pallet"]


def ultralytics_offline_env(workdir):
    """Environment that keeps ultralytics away from the network and out of the user's settings."""
    os.environ["YOLO_OFFLINE"] = "true"
    os.environ["YOLO_CONFIG_DIR"] = str(workdir / "config")
    os.environ["YOLO_AUTOINSTALL"] = "false"  # never pip-install at run time (.ci/run installs)
    os.environ["YOLO_VERBOSE"] = "false"
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def calibrate_ultralytics(net, torch, image):
    """Makes a random-weight DetectionModel's activations and outputs realistic (see above).

    BatchNorm statistics come from a batch of seeded noise images that includes `image` (the
    oracle's input); the head's scales are measured on `image` alone, so its scores are controlled.
    """
    nn = torch.nn
    others = np.random.default_rng(99).uniform(0, 1, (CALIB_BATCH - 1, *image.shape[1:])).astype(np.float32)
    calib = torch.from_numpy(np.concatenate([image, others]))
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.weight.uniform_(0.5, 1.5)
                m.bias.normal_(0.0, 0.1)
                m.reset_running_stats()
                m.momentum = 1.0  # running stats := this batch's stats
        net.train()
        net.predict(calib) if hasattr(net.model[-1], "dec_score_head") else net(calib)
        net.eval()
        for m in net.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.momentum = 0.03

        detect = net.model[-1]
        if hasattr(detect, "dec_score_head"):
            # RT-DETR: the class logits of the encoder's query selection and of the decoder.
            heads = [(detect.enc_score_head, CLS_LOGIT_STD, CLS_LOGIT_BIAS)]
            heads += [(lin, CLS_LOGIT_STD, CLS_LOGIT_BIAS) for lin in detect.dec_score_head]
        else:
            # The one-to-many head, and the one-to-one head of the end-to-end models.
            box = [*detect.cv2, *(getattr(detect, "one2one_cv2", None) or [])]
            cls = [*detect.cv3, *(getattr(detect, "one2one_cv3", None) or [])]
            heads = [(seq[-1], BOX_LOGIT_STD, None) for seq in box]
            heads += [(seq[-1], CLS_LOGIT_STD, CLS_LOGIT_BIAS) for seq in cls]
        stds = {}
        hooks = [conv.register_forward_hook(lambda mod, i, o: stds.__setitem__(mod, float(o.std())))
                 for conv, _, _ in heads]
        net(torch.from_numpy(image))
        for h in hooks:
            h.remove()
        for conv, target, bias in heads:
            if conv not in stds:
                continue  # not run at inference (RT-DETR's decoder scores its last layer only)
            conv.weight.mul_(target / stds[conv])
            if bias is not None:
                conv.bias.fill_(bias)


def export_own_classes(outdir, image, torch, YOLO):
    """YOLOv8n built with nc = len(OWN_CLASSES) and those names, exported as yolov8n_own.onnx."""
    from ultralytics.nn.tasks import DetectionModel

    torch.manual_seed(0)
    model = YOLO("yolov8n.yaml")
    net = DetectionModel("yolov8n.yaml", nc=len(OWN_CLASSES), verbose=False)
    net.args, net.task = model.model.args, model.model.task
    net.names = dict(enumerate(OWN_CLASSES))
    model.model = net
    calibrate_ultralytics(net, torch, image)
    path = model.export(format="onnx", imgsz=320, opset=17, simplify=ULTRALYTICS_SIMPLIFY,
                        dynamic=False, batch=1, device="cpu")
    exported = onnx.load(str(path))
    keep = [p for p in exported.metadata_props if p.key != "date"]
    del exported.metadata_props[:]
    exported.metadata_props.extend(keep)
    names = next(p.value for p in exported.metadata_props if p.key == "names")
    assert all(n in names for n in OWN_CLASSES), f"yolov8n_own: names metadata {names!r}"
    onnx.save(exported, str(outdir / "yolov8n_own.onnx"))


def export_half(outdir, image, torch, YOLO):
    """The calibrated YOLOv8n exported with half=True as yolov8n_half.onnx (not checked by
    onnx.checker, which rejects its node order), and onnxruntime's outputs on `image`."""
    torch.manual_seed(0)
    model = YOLO("yolov8n.yaml")
    calibrate_ultralytics(model.model, torch, image)
    path = model.export(format="onnx", imgsz=320, opset=17, simplify=ULTRALYTICS_SIMPLIFY,
                        dynamic=False, batch=1, device="cpu", half=True)
    exported = onnx.load(str(path))
    keep = [p for p in exported.metadata_props if p.key != "date"]
    del exported.metadata_props[:]
    exported.metadata_props.extend(keep)
    out = outdir / "yolov8n_half.onnx"
    onnx.save(exported, str(out))
    feeds = {"images": image}
    write_tensors(str(outdir / "yolov8n_half.input.json"), feeds)
    write_tensors(str(outdir / "yolov8n_half.expected.json"), run_session(session(str(out), threads=1), feeds))
    write_tensors(str(outdir / "yolov8n_half.unoptimised.json"),
                  run_session(session(str(out), threads=1, optimize=False), feeds))
    # The same file computed in f32: f16 initializers, constants and casts widened (exact on the
    # weights), the oracle for cac, which runs an fp16 file in f32 arithmetic.
    wide = onnx.load(str(out))
    for t in list(wide.graph.initializer):
        if t.data_type == TensorProto.FLOAT16:
            t.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(t).astype(np.float32), t.name))
    for n in wide.graph.node:
        for a in n.attribute:
            if a.name == "to" and a.i == TensorProto.FLOAT16:
                a.i = TensorProto.FLOAT
            if a.type == onnx.AttributeProto.TENSOR and a.t.data_type == TensorProto.FLOAT16:
                a.t.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(a.t).astype(np.float32), a.t.name))
    for v in list(wide.graph.value_info) + list(wide.graph.input) + list(wide.graph.output):
        if v.type.tensor_type.elem_type == TensorProto.FLOAT16:
            v.type.tensor_type.elem_type = TensorProto.FLOAT
    wide_path = outdir / "yolov8n_half.widened.onnx"
    onnx.save(wide, str(wide_path))
    write_tensors(str(outdir / "yolov8n_half.widened.json"), run_session(session(str(wide_path), threads=1), feeds))


# Exports that select their boxes inside: (stem, yaml, export options, what selects). RT-DETR's
# ultralytics export always ends in its top-k post-processing; nms=False picks YOLOv10's and
# YOLO26's end-to-end (one-to-one) head with the same post-processing; nms=True embeds NMS.
SELECTING = [
    ("rtdetr_l", "rtdetr-l.yaml", {}, "topk"),
    ("yolov10n_e2e", "yolov10n.yaml", {"nms": False}, "topk"),
    ("yolo26n_e2e", "yolo26n.yaml", {"nms": False}, "topk"),
    ("yolov8n_nms", "yolov8n.yaml", {"nms": True}, "nms"),
]


def class0_logit_gradient(net, torch, image):
    """PyTorch's gradient, w.r.t. the input, of the mean class-0 logit over the dense rows a
    selecting export picks from (RT-DETR's decoder queries; the one-to-one head's anchors).

    Every submodule's output gradient is made contiguous on its way back. Measured with torch
    2.15 on the random RT-DETR-l: the gradient of `sum(r * y.flatten(2).permute(0, 2, 1))` and of
    `sum(r^T * y.flatten(2))` (the same function; equal values and equal gradients w.r.t. `y`) at
    the AIFI input `y` reach the image with cosine 0.013 to each other, in float64 too and with
    oneDNN off, though a BatchNorm2d, a Conv2d or the two alone agree between layouts. The
    second agrees with cac's gradient (cosine 0.9997). The loss's gradient, which reaches the
    backbone through permutes, agrees with cac's (cosine 0.9997, norms 207.09 and 207.06) once
    the gradients at BatchNorm2d outputs are made contiguous (0.016 without).

    Returns the loss, the gradient and the gradient's own float spread: how far it moves,
    relative to its norm, when the input moves by about two ulps (the random transformer
    amplifies rounding: its 300-of-2,100 query selection and ReLUs switch).
    """
    class Contiguous(torch.autograd.Function):
        @staticmethod
        def forward(ctx, t):
            return t.clone()

        @staticmethod
        def backward(ctx, g):
            return g.contiguous()

    def gradient(x0):
        x = torch.from_numpy(x0.copy()).requires_grad_(True)
        _, raw = net(x)
        if isinstance(raw, dict):  # Detect: {"one2many": ..., "one2one": {"scores": [B, C, N], ...}}
            logits = raw["one2one"]["scores"][:, 0, :]
        else:  # RTDETRDecoder: (dec_bboxes, dec_scores [1, B, Q, C], enc_bboxes, enc_scores, dn_meta)
            logits = raw[1].squeeze(0)[..., 0]
        loss = logits.mean()
        loss.backward()
        return float(loss.detach()), x.grad.numpy().astype(np.float64)

    hooks = [m.register_forward_hook(lambda m, i, o: Contiguous.apply(o) if torch.is_tensor(o) else None)
             for m in net.modules()]
    try:
        net.eval()
        loss, grad = gradient(image)
        # The gradient's own float spread: the input moved by about two ulps (as float_noise).
        sign = np.where(np.random.default_rng(4321).random(image.shape) < 0.5, 1.0, -1.0)
        _, moved = gradient((image * (1 + sign * 2.0 ** -22)).astype(np.float32))
    finally:
        for h in hooks:
            h.remove()
    noise = float(np.linalg.norm(moved - grad) / np.linalg.norm(grad))
    return loss, grad.astype(np.float32), noise


def export_selecting(outdir, image, torch, YOLO, RTDETR):
    """The SELECTING exports with onnxruntime's output0 ([1, 300, 6]: box, score, class) on
    `image`; returns their manifest entries."""
    entries = []
    for stem, yaml, options, selects in SELECTING:
        torch.manual_seed(0)
        model = RTDETR(yaml) if yaml.startswith("rtdetr") else YOLO(yaml)
        calibrate_ultralytics(model.model, torch, image)
        if selects == "topk":
            loss, grad, noise = class0_logit_gradient(model.model, torch, image)
            write_tensors(str(outdir / f"{stem}.grad.json"),
                          {"loss": np.array([loss], np.float32), "images": grad,
                           "noise": np.array([noise], np.float32)})
        path = model.export(format="onnx", imgsz=320, opset=17, simplify=ULTRALYTICS_SIMPLIFY,
                            dynamic=False, batch=1, device="cpu", **options)
        exported = onnx.load(str(path))
        keep = [p for p in exported.metadata_props if p.key != "date"]
        del exported.metadata_props[:]
        exported.metadata_props.extend(keep)
        out = outdir / f"{stem}.onnx"
        onnx.save(exported, str(out))
        outs = write_oracle(out, {"images": image}, outdir / stem)
        entries.append({"name": stem, "file": f"{stem}.onnx", "opset": model_opset(exported),
                        "inputs": ["images"], "outputs": outs, "kind": "selecting", "selects": selects,
                        "export": {"yaml": yaml, "imgsz": 320, **options}})
    return entries


def export_ultralytics(outdir, image):
    """Exports the ultralytics models to outdir; returns their stems ([] when unavailable)."""
    workdir = Path(tempfile.mkdtemp(prefix="cac-ultralytics-"))
    ultralytics_offline_env(workdir)
    try:
        import torch
        import ultralytics
        from ultralytics import RTDETR, YOLO, settings
    except ImportError as e:
        shutil.rmtree(workdir, ignore_errors=True)
        print(f"make_models: ultralytics not importable ({e}); skipping yolov8n / yolov5su / yolov6n")
        return [], {}, []
    # No analytics / integrations, and every directory ultralytics might write to inside workdir.
    wanted = {"sync": False, "clearml": False, "comet": False, "dvc": False, "mlflow": False, "raytune": False,
              "tensorboard": False, "wandb": False, "vscode_msg": False, "openvino_msg": False,
              "datasets_dir": str(workdir / "datasets"), "weights_dir": str(workdir / "weights"),
              "runs_dir": str(workdir / "runs")}
    stems = []
    cwd = os.getcwd()
    try:
        settings.update({k: v for k, v in wanted.items() if k in settings})
        torch.set_num_threads(1)
        os.chdir(workdir)
        for stem, yaml, opset in ULTRALYTICS_MODELS:
            torch.manual_seed(0)
            model = YOLO(yaml)  # built from the yaml: random weights, nothing downloaded
            calibrate_ultralytics(model.model, torch, image)
            path = model.export(format="onnx", imgsz=320, opset=opset, simplify=ULTRALYTICS_SIMPLIFY,
                                dynamic=False, batch=1, device="cpu")
            # Drop the export timestamp so that reruns write byte-identical files.
            exported = onnx.load(str(path))
            keep = [p for p in exported.metadata_props if p.key != "date"]
            del exported.metadata_props[:]
            exported.metadata_props.extend(keep)
            onnx.save(exported, str(outdir / f"{stem}.onnx"))
            stems.append(stem)
        export_own_classes(outdir, image, torch, YOLO)
        export_half(outdir, image, torch, YOLO)
        selecting = export_selecting(outdir, image, torch, YOLO, RTDETR)
    finally:
        os.chdir(cwd)
        shutil.rmtree(workdir, ignore_errors=True)
    return stems, {"torch": torch.__version__, "ultralytics": ultralytics.__version__}, selecting


# ----------------------------------------------------------------------------------------------
# Oracle outputs and manifest
# ----------------------------------------------------------------------------------------------


def write_oracle(model_path, feeds, stem_path):
    """Checks the model, writes its feeds and onnxruntime's outputs; returns the output names."""
    onnx.checker.check_model(str(model_path), full_check=True)
    sess = session(str(model_path), threads=1)
    outs = run_session(sess, feeds)
    for name, v in outs.items():
        if v.dtype.kind == "f" and not np.all(np.isfinite(v)):
            raise SystemExit(f"{model_path}: non-finite values in output {name}")
    write_tensors(f"{stem_path}.input.json", feeds)
    write_tensors(f"{stem_path}.expected.json", outs)
    return list(outs)


def float_noise(path, want):
    """How far onnxruntime's own output0 moves on the seeded detector input, relative to its largest
    magnitude: the graph unfused against fused, and the input moved by about two ulps (seeded
    +-2^-22 relative). The random-weight networks amplify rounding, some (YOLOv6n) past 1e-4."""
    feeds = {"images": read_tensors(f"{path.with_suffix('')}.input.json")["images"]}
    scale = float(np.abs(want).max())
    plain = run_session(session(str(path), threads=1, optimize=False), feeds)["output0"]
    x = feeds["images"]
    sign = np.where(np.random.default_rng(4321).random(x.shape) < 0.5, 1.0, -1.0)
    moved = run_session(session(str(path), threads=1), {"images": (x * (1 + sign * 2.0 ** -22)).astype(np.float32)})
    return max(float(np.abs(plain - want).max()), float(np.abs(moved["output0"] - want).max())) / scale


def model_opset(model):
    return next(o.version for o in model.opset_import if o.domain in ("", "ai.onnx"))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("outdir", type=Path)
    p.add_argument("--skip-ultralytics", action="store_true", help="build only the hand-made models")
    args = p.parse_args()
    outdir = args.outdir
    (outdir / "ops").mkdir(parents=True, exist_ok=True)
    manifest = []

    for case in op_cases():
        path = outdir / "ops" / f"{case.name}.onnx"
        onnx.save(case.model(), str(path))
        outs = write_oracle(path, case.feeds, outdir / "ops" / case.name)
        manifest.append({"name": case.name, "file": f"ops/{case.name}.onnx", "opset": case.opset,
                         "inputs": list(case.feeds), "outputs": outs, "kind": "op"})

    detector_feed = {"images": np.random.default_rng(1234).uniform(0, 1, (1, 3, 320, 320)).astype(np.float32)}

    # Detectors. "layout" says how output0 is laid out: "anchor" [1, N, 5 + classes] with
    # (cx, cy, w, h, objectness, class probabilities); "anchor_free" [1, 4 + classes, N] with
    # (cx, cy, w, h, class probabilities). Boxes in input pixels, probabilities post-sigmoid.
    path = outdir / "yolov5_anchor.onnx"
    model = yolov5_anchor()
    onnx.save(model, str(path))
    outs = write_oracle(path, detector_feed, outdir / "yolov5_anchor")
    pred = read_tensors(outdir / "yolov5_anchor.expected.json")["output0"]
    score = pred[0, :, 4] * pred[0, :, 5:].max(-1)
    counts = {"yolov5_anchor": int((score > 0.3).sum())}
    assert 3 <= counts["yolov5_anchor"] <= 300, f"yolov5_anchor: {counts} candidates above 0.3, retune CLS_BIAS"
    manifest.append({"name": "yolov5_anchor", "file": "yolov5_anchor.onnx", "opset": model_opset(model),
                     "inputs": ["images"], "outputs": outs, "kind": "detector", "layout": "anchor"})

    # Boxes and scores in separate outputs (cac's head = "split").
    path = outdir / "split_head.onnx"
    model = split_head()
    onnx.save(model, str(path))
    feed = {"images": np.random.default_rng(77).uniform(0, 1, (1, 3, 64, 64)).astype(np.float32)}
    outs = write_oracle(path, feed, outdir / "split_head")
    manifest.append({"name": "split_head", "file": "split_head.onnx", "opset": model_opset(model),
                     "inputs": ["images"], "outputs": outs, "kind": "split_detector"})

    stems, extra_versions, selecting = (([], {}, []) if args.skip_ultralytics
                                        else export_ultralytics(outdir, detector_feed["images"]))
    for stem in stems:
        path = outdir / f"{stem}.onnx"
        model = onnx.load(str(path))
        outs = write_oracle(path, detector_feed, outdir / stem)
        pred = read_tensors(outdir / f"{stem}.expected.json")["output0"]
        counts[stem] = int((pred[0, 4:].max(0) > 0.3).sum())
        assert 3 <= counts[stem] <= 300, f"{stem}: {counts[stem]} cells score above 0.3, retune CLS_LOGIT_BIAS"
        manifest.append({"name": stem, "file": f"{stem}.onnx", "opset": model_opset(model),
                         "inputs": [i.name for i in model.graph.input], "outputs": outs,
                         "kind": "export" if stem in RAW_ONLY else "detector", "noise": float_noise(path, pred),
                         "layout": "anchor_free", "export": {"imgsz": 320, "simplify": ULTRALYTICS_SIMPLIFY,
                                                             "dynamic": False}})

    manifest.extend(selecting)
    versions = {"onnx": onnx.__version__, "onnxruntime": ort.__version__, "numpy": np.__version__, **extra_versions}
    with open(outdir / "manifest.json", "w") as f:
        json.dump({"models": manifest, "versions": versions}, f, indent=1)
    print(f"make_models: {len(manifest)} models in {outdir}; detections scoring above 0.3: {counts}")


if __name__ == "__main__":
    main()
