//! TensorFlow op semantics on burn tensors, for the ops the TFJS graph executor supports.
//!
//! Each op follows TF exactly where it matters for parity: SAME padding is asymmetric
//! (extra pad at the end), ResizeBilinear uses the tfjs-cpu index formula, MaxPool pads with
//! -inf, depthwise channel order is `c * multiplier + m`. Float ops are burn ops (so autodiff
//! reaches the graph input); integer/shape ops run on the host. An op outside this list is an
//! error naming the op.

use super::model::{HostData, HostTensor};
use super::value::{pad4, FloatValue, Node, Value};
use crate::activation as fast;
use crate::broadcast;
use crate::conv::conv2d;
use crate::kernels::{broadcast_shape, pad_constant};
use crate::preprocess::resize_bilinear;
use anyhow::{anyhow, bail, ensure, Context, Result};
use burn::tensor::activation;
use burn::tensor::module::max_pool2d;
use burn::tensor::ops::{ConvOptions, MaxPoolOptions};
use burn::tensor::{Device, Tensor, TensorData};
use std::collections::HashMap;

/// Evaluates `node` on its input values on `dev`; `conv_weight` is the node's filter as
/// [`prepare_conv_weights`] arranged it (convolutions only).
pub fn eval(
    node: &Node,
    conv_weight: Option<&Tensor<4>>,
    dev: &Device,
    args: &[&Value],
) -> Result<Vec<Value>> {
    let one = |v: FloatValue| Ok(vec![Value::Float(v)]);
    match node.op() {
        "Identity" | "StopGradient" | "Snapshot" => Ok(vec![arg(args, 0)?.clone()]),
        "Conv2D" | "_FusedConv2D" | "DepthwiseConv2dNative" | "FusedDepthwiseConv2dNative" => {
            one(conv(node, conv_weight, dev, args)?)
        }
        "Relu" => unary(dev, args, fast::relu),
        "Relu6" => unary(dev, args, fast::relu6),
        // Made by `fuse::hard_swish` from Mul(Mul(x, c), Relu6(Add(x, 3))); scale = 6c.
        "HardSwish" => {
            let scale = attr_f(node, "scale").context("HardSwish without scale")?;
            unary(dev, args, |t| fast::hard_swish(t, scale as f32))
        }
        "Sigmoid" => unary(dev, args, fast::sigmoid),
        "Tanh" => unary(dev, args, activation::tanh),
        "Exp" => unary(dev, args, |t| t.exp()),
        "Neg" => unary(dev, args, |t| t.neg()),
        "LeakyRelu" => {
            let alpha = attr_f(node, "alpha").unwrap_or(0.2);
            unary(dev, args, |t| fast::leaky_relu(t, alpha as f32))
        }
        "Add" | "AddV2" | "Sub" | "Mul" | "RealDiv" | "Div" | "Maximum" | "Minimum" => {
            Ok(vec![binary(dev, node.op(), arg(args, 0)?, arg(args, 1)?)?])
        }
        "Mean" => one(mean(dev, node, args)?),
        "ConcatV2" => Ok(vec![concat(dev, args)?]),
        "Reshape" => Ok(vec![reshape(arg(args, 0)?, &host(args, 1)?.as_i64())?]),
        "Transpose" => one(transpose(dev, args)?),
        "Pad" | "PadV2" => one(pad(dev, node.op(), args)?),
        "MaxPool" => one(max_pool(dev, node, args)?),
        "ResizeBilinear" => one(resize(dev, node, args)?),
        "SplitV" => split_v(dev, args),
        "ExpandDims" => Ok(vec![expand_dims(
            arg(args, 0)?,
            host(args, 1)?.as_i64()[0],
        )?]),
        "Cast" => cast(node, arg(args, 0)?),
        "SparseToDense" => Ok(vec![Value::Host(sparse_to_dense(args)?)]),
        op => bail!("unsupported op {op}"),
    }
}

fn arg<'a>(args: &[&'a Value], k: usize) -> Result<&'a Value> {
    args.get(k)
        .copied()
        .ok_or_else(|| anyhow!("missing input {k}"))
}

fn host<'a>(args: &[&'a Value], k: usize) -> Result<&'a HostTensor> {
    match arg(args, k)? {
        Value::Host(h) => Ok(h),
        Value::Float(_) => bail!("input {k} must be a constant (shape/axis argument)"),
    }
}

/// A float tensor for any value (host constants are uploaded to the graph's device).
fn float(dev: &Device, v: &Value) -> Result<FloatValue> {
    match v {
        Value::Float(f) => Ok(f.clone()),
        Value::Host(h) => {
            ensure!(
                h.shape.len() <= 4,
                "rank {} > 4 is not supported",
                h.shape.len()
            );
            let data = h.as_f32();
            let t = Tensor::<1>::from_data(TensorData::new(data, [h.len()]), dev);
            Ok(FloatValue::new(t.reshape(pad4(&h.shape)), h.shape.clone()))
        }
    }
}

fn float_arg(dev: &Device, args: &[&Value], k: usize) -> Result<FloatValue> {
    float(dev, arg(args, k)?)
}

/// A float input in plain logical layout.
fn logical_arg(dev: &Device, args: &[&Value], k: usize) -> Result<FloatValue> {
    Ok(float_arg(dev, args, k)?.logical())
}

fn unary(dev: &Device, args: &[&Value], f: impl Fn(Tensor<4>) -> Tensor<4>) -> Result<Vec<Value>> {
    let x = float_arg(dev, args, 0)?;
    Ok(vec![Value::Float(FloatValue {
        t: f(x.t),
        shape: x.shape,
        nchw: x.nchw,
    })])
}

// ---------------------------------------------------------------- attributes

fn attr<'a>(node: &'a Node, key: &str) -> Option<&'a serde_json::Value> {
    node.def.attr.get(key)
}

fn attr_f(node: &Node, key: &str) -> Option<f64> {
    attr(node, key)?.get("f")?.as_f64()
}

fn attr_b(node: &Node, key: &str) -> bool {
    attr(node, key)
        .and_then(|v| v.get("b"))
        .and_then(|b| b.as_bool())
        .unwrap_or(false)
}

fn attr_ints(node: &Node, key: &str) -> Option<Vec<i64>> {
    let l = attr(node, key)?.get("list")?.get("i")?.as_array()?;
    l.iter()
        .map(|x| x.as_str().and_then(|s| s.parse().ok()).or(x.as_i64()))
        .collect()
}

fn attr_s(node: &Node, key: &str) -> Option<String> {
    let s = attr(node, key)?.get("s")?.as_str()?;
    Some(String::from_utf8_lossy(&base64_decode(s)).into_owned())
}

fn attr_strings(node: &Node, key: &str) -> Vec<String> {
    attr(node, key)
        .and_then(|v| v.get("list"))
        .and_then(|l| l.get("s"))
        .and_then(|s| s.as_array())
        .map(|a| {
            a.iter()
                .filter_map(|x| x.as_str())
                .map(|s| String::from_utf8_lossy(&base64_decode(s)).into_owned())
                .collect()
        })
        .unwrap_or_default()
}

/// Standard base64 (the converter's encoding of string attributes).
fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            _ => return None,
        } as u32)
    };
    let mut out = Vec::new();
    let (mut acc, mut bits) = (0u32, 0);
    for c in s.bytes().filter_map(val) {
        acc = (acc << 6) | c;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    out
}

fn nhwc_only(node: &Node) -> Result<()> {
    match attr_s(node, "data_format").as_deref() {
        None | Some("NHWC") => Ok(()),
        Some(f) => bail!("data_format {f} is not supported (NHWC only)"),
    }
}

/// TF padding (begin, end) for one spatial axis.
fn tf_padding(
    padding: &str,
    input: usize,
    k: usize,
    stride: usize,
    dil: usize,
) -> Result<(usize, usize)> {
    let k_eff = (k - 1) * dil + 1;
    match padding {
        "VALID" => Ok((0, 0)),
        "SAME" => {
            let out = input.div_ceil(stride);
            let total = ((out - 1) * stride + k_eff).saturating_sub(input);
            Ok((total / 2, total - total / 2))
        }
        p => bail!("padding {p} is not supported"),
    }
}

fn spatial(v: Option<Vec<i64>>, name: &str) -> Result<[usize; 2]> {
    match v.as_deref() {
        None => Ok([1, 1]),
        Some([1, a, b, 1]) if *a > 0 && *b > 0 => Ok([*a as usize, *b as usize]),
        Some(other) => bail!("{name} {other:?} is not supported (NHWC [1,h,w,1] expected)"),
    }
}

// ---------------------------------------------------------------- convolutions

fn is_conv(op: &str) -> bool {
    matches!(
        op,
        "Conv2D" | "_FusedConv2D" | "DepthwiseConv2dNative" | "FusedDepthwiseConv2dNative"
    )
}

/// Rearranges every constant convolution filter of `nodes` to burn's `[out, in/groups, kh, kw]`
/// once, keyed by the convolution node; `source` names the model in errors.
pub(crate) fn prepare_conv_weights(
    source: &str,
    nodes: &[Node],
    consts: &HashMap<usize, Value>,
    dev: &Device,
) -> Result<HashMap<usize, Tensor<4>>> {
    let mut prepared = HashMap::new();
    for (i, node) in nodes.iter().enumerate() {
        if !is_conv(node.op()) {
            continue;
        }
        let &(wi, _) = node
            .inputs
            .get(1)
            .ok_or_else(|| anyhow!("{}: node {:?} has no filter input", source, node.name()))?;
        let w = match consts.get(&wi) {
            Some(Value::Float(f)) => f.to_host()?,
            Some(Value::Host(h)) => h.clone(),
            None => bail!(
                "{}: node {:?}: filter {:?} is not a constant",
                source,
                node.name(),
                nodes[wi].name()
            ),
        };
        ensure!(
            w.shape.len() == 4,
            "{}: node {:?}: filter shape {:?} is not 4-D",
            source,
            node.name(),
            w.shape
        );
        let (kh, kw, ci, co) = (w.shape[0], w.shape[1], w.shape[2], w.shape[3]);
        let src = w.as_f32();
        let depthwise = node.op().contains("Depthwise");
        let out_c = if depthwise { ci * co } else { co };
        let in_c = if depthwise { 1 } else { ci };
        let mut dst = vec![0f32; out_c * in_c * kh * kw];
        for y in 0..kh {
            for x in 0..kw {
                for c in 0..ci {
                    for o in 0..co {
                        let v = src[((y * kw + x) * ci + c) * co + o];
                        // depthwise: out channel c*mult+o, 1 input channel; conv: [o, c].
                        let (oc, ic) = if depthwise { (c * co + o, 0) } else { (o, c) };
                        dst[((oc * in_c + ic) * kh + y) * kw + x] = v;
                    }
                }
            }
        }
        let t = Tensor::<4>::from_data(TensorData::new(dst, [out_c, in_c, kh, kw]), dev);
        prepared.insert(i, t);
    }
    Ok(prepared)
}

fn conv(
    node: &Node,
    weight: Option<&Tensor<4>>,
    dev: &Device,
    args: &[&Value],
) -> Result<FloatValue> {
    nhwc_only(node)?;
    let x = float_arg(dev, args, 0)?;
    ensure!(
        x.rank() == 4,
        "input has shape {:?}, a 4-D NHWC tensor is needed",
        x.shape
    );
    let w = weight.context("filter was not prepared")?.clone();
    let [out_c, in_per_group, kh, kw] = w.dims();
    let depthwise = node.op().contains("Depthwise");
    let channels = x.shape[3];
    let groups = if depthwise { channels } else { 1 };
    ensure!(
        channels == in_per_group * groups,
        "input has {channels} channels, the filter expects {}",
        in_per_group * groups
    );
    let stride = spatial(attr_ints(node, "strides"), "strides")?;
    let dil = spatial(attr_ints(node, "dilations"), "dilations")?;
    let padding = attr_s(node, "padding").unwrap_or_else(|| "VALID".into());
    let ph = tf_padding(&padding, x.shape[1], kh, stride[0], dil[0])?;
    let pw = tf_padding(&padding, x.shape[2], kw, stride[1], dil[1])?;
    let fused = attr_strings(node, "fused_ops");
    let mut bias = None;
    let mut activation_op = None;
    for f in &fused {
        match f.as_str() {
            "BiasAdd" => {
                let b = float_arg(dev, args, 2)?;
                ensure!(b.shape == [out_c], "bias shape {:?} != [{out_c}]", b.shape);
                bias = Some(b.logical().t.reshape([out_c]));
            }
            "Relu" | "Relu6" | "LeakyRelu" | "Elu" | "Sigmoid" => activation_op = Some(f.clone()),
            other => bail!("fused op {other} is not supported (fused_ops {fused:?})"),
        }
    }
    if !fused.is_empty() && fused[0] != "BiasAdd" {
        bail!("fused_ops {fused:?} is not supported (BiasAdd first expected)");
    }
    // Every layer through `detect::conv::conv2d`, the RGB stem included (its own im2col route,
    // from before cac's dense convolution kernels, was 13–18% slower on Flex by then).
    let options = ConvOptions::new_with_padding(stride, [ph, pw], dil, groups);
    let y = conv2d(x.to_nchw(), w, bias, options);
    let y = match activation_op.as_deref() {
        None => y,
        Some("Relu") => fast::relu(y),
        Some("Relu6") => fast::relu6(y),
        Some("Sigmoid") => fast::sigmoid(y),
        Some("Elu") => activation::elu(y, 1.0),
        Some(_) => {
            let alpha = attr_f(node, "leakyrelu_alpha").unwrap_or(0.2);
            fast::leaky_relu(y, alpha as f32)
        }
    };
    Ok(FloatValue::from_nchw(y))
}

// ---------------------------------------------------------------- elementwise

fn binary(dev: &Device, op: &str, a: &Value, b: &Value) -> Result<Value> {
    if let (Value::Host(x), Value::Host(y)) = (a, b) {
        return host_binary(op, x, y).map(Value::Host);
    }
    let shape = broadcast_shape(a.shape(), b.shape())?;
    ensure!(
        shape.len() <= 4,
        "rank {} > 4 is not supported",
        shape.len()
    );
    // Scalar constants become scalar ops (exact same f32 arithmetic, no upload).
    let scalar = |v: &Value| match v {
        Value::Host(h) if h.len() == 1 => Some(h.as_f32()[0]),
        _ => None,
    };
    // An operand held as NCHW makes the op run in NCHW; the others are aligned to it.
    let nchw = [a, b]
        .iter()
        .any(|v| matches!(v, Value::Float(f) if f.nchw));
    let phys = |v: &Value| -> Result<Tensor<4>> {
        let f = float(dev, v)?;
        Ok(if nchw { f.to_nchw() } else { f.t })
    };
    let t = match (scalar(a), scalar(b)) {
        (_, Some(s)) => {
            let x = phys(a)?;
            match op {
                "Add" | "AddV2" => x.add_scalar(s),
                "Sub" => x.sub_scalar(s),
                "Mul" => x.mul_scalar(s),
                "RealDiv" | "Div" => x.div_scalar(s),
                "Maximum" => x.clamp_min(s),
                _ => x.clamp_max(s),
            }
        }
        (Some(s), _) if op != "Sub" && op != "RealDiv" && op != "Div" => {
            let x = phys(b)?;
            match op {
                "Add" | "AddV2" => x.add_scalar(s),
                "Mul" => x.mul_scalar(s),
                "Maximum" => x.clamp_min(s),
                _ => x.clamp_max(s),
            }
        }
        _ => {
            let (x, y) = (phys(a)?, phys(b)?);
            match op {
                "Add" | "AddV2" => broadcast::add(x, y),
                "Sub" => x - y,
                "Mul" => broadcast::mul(x, y),
                "RealDiv" | "Div" => x / y,
                "Maximum" => x.max_pair(y),
                _ => x.min_pair(y),
            }
        }
    };
    if nchw {
        ensure!(shape.len() == 4, "NCHW-held result of rank {}", shape.len());
        return Ok(Value::Float(FloatValue { t, shape, nchw }));
    }
    Ok(Value::Float(FloatValue::new(t, shape)))
}

fn host_binary(op: &str, a: &HostTensor, b: &HostTensor) -> Result<HostTensor> {
    let shape = broadcast_shape(&a.shape, &b.shape)?;
    let n: usize = shape.iter().product();
    let index = |t: &HostTensor, flat: usize| -> usize {
        // Map a flat index of the broadcast shape to the operand's flat index.
        let mut rem = flat;
        let mut idx = 0;
        let mut stride = 1;
        let off = shape.len() - t.shape.len();
        for k in (0..shape.len()).rev() {
            let coord = rem % shape[k];
            rem /= shape[k];
            if k >= off {
                let d = t.shape[k - off];
                if d != 1 {
                    idx += coord * stride;
                }
                stride *= d;
            }
        }
        idx
    };
    let data = match (&a.data, &b.data) {
        (HostData::I64(x), HostData::I64(y)) => HostData::I64(
            (0..n)
                .map(|f| {
                    let (p, q) = (x[index(a, f)], y[index(b, f)]);
                    match op {
                        "Add" | "AddV2" => Ok(p + q),
                        "Sub" => Ok(p - q),
                        "Mul" => Ok(p * q),
                        "Maximum" => Ok(p.max(q)),
                        "Minimum" => Ok(p.min(q)),
                        _ => bail!("{op} on integers is not supported"),
                    }
                })
                .collect::<Result<_>>()?,
        ),
        _ => {
            let (x, y) = (a.as_f32(), b.as_f32());
            HostData::F32(
                (0..n)
                    .map(|f| {
                        let (p, q) = (x[index(a, f)], y[index(b, f)]);
                        match op {
                            "Add" | "AddV2" => p + q,
                            "Sub" => p - q,
                            "Mul" => p * q,
                            "RealDiv" | "Div" => p / q,
                            "Maximum" => p.max(q),
                            _ => p.min(q),
                        }
                    })
                    .collect(),
            )
        }
    };
    Ok(HostTensor { shape, data })
}

// ---------------------------------------------------------------- shape ops

fn norm_axis(axis: i64, rank: usize) -> Result<usize> {
    let a = if axis < 0 { axis + rank as i64 } else { axis };
    ensure!(
        a >= 0 && (a as usize) < rank,
        "axis {axis} out of range for rank {rank}"
    );
    Ok(a as usize)
}

fn mean(dev: &Device, node: &Node, args: &[&Value]) -> Result<FloatValue> {
    let mut x = float_arg(dev, args, 0)?;
    if x.nchw && !attr_b(node, "keep_dims") {
        x = x.logical();
    }
    let mut axes: Vec<usize> = host(args, 1)?
        .as_i64()
        .iter()
        .map(|&a| norm_axis(a, x.rank()))
        .collect::<Result<_>>()?;
    axes.sort();
    axes.dedup();
    let off = x.offset();
    let phys: Vec<usize> = if x.nchw {
        axes.iter().map(|&a| [0, 2, 3, 1][a]).collect()
    } else {
        axes.iter().map(|a| a + off).collect()
    };
    let t = broadcast::mean_dims(x.t, &phys);
    if x.nchw {
        let mut shape = x.shape.clone();
        for &a in &axes {
            shape[a] = 1;
        }
        return Ok(FloatValue {
            t,
            shape,
            nchw: true,
        });
    }
    let mut shape = x.shape.clone();
    for &a in &axes {
        shape[a] = 1;
    }
    if !attr_b(node, "keep_dims") {
        shape = shape
            .iter()
            .enumerate()
            .filter(|(k, _)| !axes.contains(k))
            .map(|(_, &d)| d)
            .collect();
    }
    Ok(FloatValue::new(t, shape))
}

fn concat(dev: &Device, args: &[&Value]) -> Result<Value> {
    ensure!(
        args.len() >= 2,
        "ConcatV2 needs at least one tensor and an axis"
    );
    let axis_v = host(args, args.len() - 1)?.as_i64()[0];
    let parts = &args[..args.len() - 1];
    let rank = parts[0].shape().len();
    let axis = norm_axis(axis_v, rank)?;
    for p in parts {
        ensure!(p.shape().len() == rank, "inputs of different rank");
        for k in 0..rank {
            ensure!(
                k == axis || p.shape()[k] == parts[0].shape()[k],
                "shapes {:?} and {:?} differ outside axis {axis}",
                p.shape(),
                parts[0].shape()
            );
        }
    }
    let mut shape = parts[0].shape().to_vec();
    shape[axis] = parts.iter().map(|p| p.shape()[axis]).sum();
    let all_nchw = parts.iter().all(|p| matches!(p, Value::Float(f) if f.nchw));
    if all_nchw {
        let ts: Vec<Tensor<4>> = parts
            .iter()
            .map(|p| float(dev, p).map(|f| f.t))
            .collect::<Result<_>>()?;
        let t = Tensor::cat(ts, [0, 2, 3, 1][axis]);
        return Ok(Value::Float(FloatValue {
            t,
            shape,
            nchw: true,
        }));
    }
    let ts: Vec<Tensor<4>> = parts
        .iter()
        .map(|p| float(dev, p).map(|f| f.logical().t))
        .collect::<Result<_>>()?;
    let t = Tensor::cat(ts, axis + 4 - rank);
    Ok(Value::Float(FloatValue::new(t, shape)))
}

fn reshape(x: &Value, target: &[i64]) -> Result<Value> {
    let n: usize = x.shape().iter().product();
    let mut shape: Vec<usize> = Vec::with_capacity(target.len());
    let mut infer = None;
    for (k, &d) in target.iter().enumerate() {
        match d {
            -1 if infer.is_none() => {
                infer = Some(k);
                shape.push(1);
            }
            d if d >= 0 => shape.push(d as usize),
            _ => bail!("reshape target {target:?} is invalid"),
        }
    }
    // The graph was traced at batch 1: a leading 1 in the target stands for the batch.
    let batch = x.shape().first().copied().unwrap_or(1);
    if batch > 1 && shape.first() == Some(&1) && infer != Some(0) && n % batch == 0 {
        shape[0] = batch;
    }
    if let Some(k) = infer {
        let known: usize = shape.iter().product();
        ensure!(
            known > 0 && n % known == 0,
            "cannot reshape {:?} to {target:?}",
            x.shape()
        );
        shape[k] = n / known;
    }
    ensure!(
        shape.iter().product::<usize>() == n,
        "cannot reshape {:?} ({n} values) to {target:?}",
        x.shape()
    );
    Ok(match x {
        Value::Host(h) => Value::Host(HostTensor {
            shape,
            data: h.data.clone(),
        }),
        Value::Float(f) => {
            ensure!(
                shape.len() <= 4,
                "rank {} > 4 is not supported",
                shape.len()
            );
            Value::Float(FloatValue::new(f.clone().logical().t, shape))
        }
    })
}

fn expand_dims(x: &Value, axis: i64) -> Result<Value> {
    let r = x.shape().len();
    let a = norm_axis(axis, r + 1)?;
    let mut shape = x.shape().to_vec();
    shape.insert(a, 1);
    let target: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
    reshape(x, &target)
}

fn transpose(dev: &Device, args: &[&Value]) -> Result<FloatValue> {
    let x = logical_arg(dev, args, 0)?;
    let perm = host(args, 1)?.as_i64();
    let r = x.rank();
    ensure!(perm.len() == r, "perm {perm:?} does not match rank {r}");
    let off = x.offset();
    let mut p = [0usize, 1, 2, 3];
    let mut seen = [false; 4];
    for (k, &a) in perm.iter().enumerate() {
        let a = norm_axis(a, r)?;
        ensure!(!seen[a], "perm {perm:?} repeats an axis");
        seen[a] = true;
        p[k + off] = a + off;
    }
    let shape = perm.iter().map(|&a| x.shape[a as usize]).collect();
    Ok(FloatValue {
        t: x.t.permute(p),
        shape,
        nchw: false,
    })
}

fn pad(dev: &Device, op: &str, args: &[&Value]) -> Result<FloatValue> {
    let x = logical_arg(dev, args, 0)?;
    let p = host(args, 1)?;
    ensure!(
        p.shape == [x.rank(), 2],
        "paddings shape {:?} does not match rank {}",
        p.shape,
        x.rank()
    );
    let value = if op == "PadV2" {
        host(args, 2)?.as_f32()[0]
    } else {
        0.0
    };
    let pv = p.as_i64();
    ensure!(pv.iter().all(|&v| v >= 0), "negative paddings {pv:?}");
    let mut pairs = vec![(0usize, 0usize); 4];
    let mut shape = x.shape.clone();
    for k in 0..x.rank() {
        pairs[k + x.offset()] = (pv[2 * k] as usize, pv[2 * k + 1] as usize);
        shape[k] += (pv[2 * k] + pv[2 * k + 1]) as usize;
    }
    Ok(FloatValue {
        t: pad_constant(x.t, &pairs, value),
        shape,
        nchw: false,
    })
}

/// (A max-pool as the maximum of the window's strided views was tried: slower than
/// Flex's `max_pool2d`, 9.6 against 6.1 ms on NanoDet's pool.)
fn max_pool(dev: &Device, node: &Node, args: &[&Value]) -> Result<FloatValue> {
    nhwc_only(node)?;
    let x = float_arg(dev, args, 0)?;
    ensure!(
        x.rank() == 4,
        "input has shape {:?}, NHWC expected",
        x.shape
    );
    let k = spatial(attr_ints(node, "ksize"), "ksize")?;
    let s = spatial(attr_ints(node, "strides"), "strides")?;
    let padding = attr_s(node, "padding").unwrap_or_else(|| "VALID".into());
    let ph = tf_padding(&padding, x.shape[1], k[0], s[0], 1)?;
    let pw = tf_padding(&padding, x.shape[2], k[1], s[1], 1)?;
    // Asymmetric padding (SAME at stride 2) with −∞ added here rather than by burn's `max_pool2d`,
    // which builds that constant on the host on some backends (`kernels::pad_constant`).
    let opts = MaxPoolOptions::new(k).with_stride(s);
    let (x, opts) = match ph.0 == ph.1 && pw.0 == pw.1 {
        true => (x.to_nchw(), opts.with_padding_pairs([ph, pw])),
        false => (
            pad_constant(x.to_nchw(), &[ph, pw], f32::NEG_INFINITY),
            opts,
        ),
    };
    Ok(FloatValue::from_nchw(max_pool2d(x, opts)))
}

fn resize(dev: &Device, node: &Node, args: &[&Value]) -> Result<FloatValue> {
    let x = float_arg(dev, args, 0)?;
    ensure!(
        x.rank() == 4,
        "input has shape {:?}, NHWC expected",
        x.shape
    );
    let size = host(args, 1)?.as_i64();
    ensure!(
        size.len() == 2 && size.iter().all(|&s| s > 0),
        "size {size:?} is invalid"
    );
    let (h, w) = (size[0] as usize, size[1] as usize);
    let align = attr_b(node, "align_corners");
    let half = attr_b(node, "half_pixel_centers");
    let t = resize_bilinear(x.to_nchw(), 2, 3, h, w, align, half);
    Ok(FloatValue::from_nchw(t))
}

fn split_v(dev: &Device, args: &[&Value]) -> Result<Vec<Value>> {
    let x = logical_arg(dev, args, 0)?;
    let axis = norm_axis(host(args, 2)?.as_i64()[0], x.rank())?;
    let mut sizes = host(args, 1)?.as_i64();
    let total = x.shape[axis] as i64;
    if let Some(k) = sizes.iter().position(|&s| s == -1) {
        let known: i64 = sizes.iter().filter(|&&s| s != -1).sum();
        sizes[k] = total - known;
    }
    ensure!(
        sizes.iter().all(|&s| s >= 0) && sizes.iter().sum::<i64>() == total,
        "split sizes {sizes:?} do not add up to {total}"
    );
    let sizes: Vec<usize> = sizes.iter().map(|&s| s as usize).collect();
    let off = x.offset();
    let parts = x.t.split_with_sizes(sizes.clone(), axis + off);
    Ok(parts
        .into_iter()
        .zip(sizes)
        .map(|(t, s)| {
            let mut shape = x.shape.clone();
            shape[axis] = s;
            Value::Float(FloatValue {
                t,
                shape,
                nchw: false,
            })
        })
        .collect())
}

fn cast(node: &Node, x: &Value) -> Result<Vec<Value>> {
    let dst = attr(node, "DstT")
        .and_then(|v| v.get("type"))
        .and_then(|t| t.as_str())
        .unwrap_or("");
    Ok(vec![match (x, dst) {
        (Value::Float(_), "DT_FLOAT") => x.clone(),
        (Value::Host(h), "DT_FLOAT") => Value::Host(HostTensor {
            shape: h.shape.clone(),
            data: HostData::F32(h.as_f32()),
        }),
        (Value::Host(h), "DT_INT32" | "DT_INT64") => Value::Host(HostTensor {
            shape: h.shape.clone(),
            data: HostData::I64(h.as_i64()),
        }),
        _ => bail!("Cast to {dst} of this value is not supported"),
    }])
}

fn sparse_to_dense(args: &[&Value]) -> Result<HostTensor> {
    let indices = host(args, 0)?;
    let out_shape: Vec<usize> = host(args, 1)?
        .as_i64()
        .iter()
        .map(|&d| d as usize)
        .collect();
    let values = host(args, 2)?;
    let default = host(args, 3)?;
    let n: usize = out_shape.iter().product();
    let fill = |v: f64| -> HostData {
        match (&values.data, &default.data) {
            (HostData::I64(_), _) => HostData::I64(vec![v as i64; n]),
            _ => HostData::F32(vec![v as f32; n]),
        }
    };
    let mut data = fill(default.as_f32().first().copied().unwrap_or(0.0) as f64);
    let idx = indices.as_i64();
    let rank = out_shape.len();
    let count = if indices.shape.len() == 2 {
        indices.shape[0]
    } else {
        idx.len().min(if rank == 1 { idx.len() } else { 0 })
    };
    let vals = values.as_f32();
    for e in 0..count {
        let mut flat = 0usize;
        for k in 0..rank {
            let c = idx[e * rank + k];
            ensure!(
                c >= 0 && (c as usize) < out_shape[k],
                "index {c} out of range"
            );
            flat = flat * out_shape[k] + c as usize;
        }
        let v = if vals.len() == 1 { vals[0] } else { vals[e] };
        match &mut data {
            HostData::I64(d) => d[flat] = v as i64,
            HostData::F32(d) => d[flat] = v,
        }
    }
    Ok(HostTensor {
        shape: out_shape,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_padding_is_asymmetric_for_stride_two() {
        assert_eq!(tf_padding("SAME", 512, 3, 2, 1).unwrap(), (0, 1));
        assert_eq!(tf_padding("SAME", 64, 5, 2, 1).unwrap(), (1, 2));
        assert_eq!(tf_padding("SAME", 128, 3, 1, 1).unwrap(), (1, 1));
        assert_eq!(tf_padding("VALID", 128, 3, 1, 1).unwrap(), (0, 0));
    }

    #[test]
    fn base64_attributes_decode() {
        assert_eq!(base64_decode("U0FNRQ=="), b"SAME");
        assert_eq!(base64_decode("Qmlhc0FkZA=="), b"BiasAdd");
    }

    #[test]
    fn host_broadcasting_and_shapes() {
        let a = HostTensor {
            shape: vec![3],
            data: HostData::I64(vec![1, 80, -1]),
        };
        let b = HostTensor {
            shape: vec![3],
            data: HostData::I64(vec![0, 0, 0]),
        };
        assert_eq!(
            host_binary("AddV2", &a, &b).unwrap().as_i64(),
            vec![1, 80, -1]
        );
        assert!(broadcast_shape(&[2, 3], &[4]).is_err());
        assert_eq!(broadcast_shape(&[1, 4, 1], &[3]).unwrap(), vec![1, 4, 3]);
        assert!(broadcast_shape(&[1, 4, 1], &[3, 1]).is_err());
    }
}
