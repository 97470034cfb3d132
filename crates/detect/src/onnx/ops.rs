//! ONNX op semantics, dispatched by op type: the elementwise ops in [`super::elementwise`], the
//! layout and shape ops in [`super::shape`], the network layers (convolution, pooling, resize,
//! normalisation, matrix products, top-k, NMS) in [`super::nn`], LayerNormalization and
//! GridSample in [`super::transformer`]. Float ops on device values are burn ops, so autodiff
//! reaches the graph input; ops on host values (exported shape arithmetic) run on the host with
//! ONNX's integer semantics. An op outside [`SUPPORTED`] is an error naming the op.

use super::args::{broadcast, expand, Args};
use super::elementwise::{self as ew, unary};
use super::model::NodeDef;
use super::value::{Dev, Host, Val};
use super::{nn, shape, transformer};
use crate::activation as fast;
use anyhow::{bail, Result};
use burn::tensor::{activation, Device};

/// Every op type [`eval`] implements (default domain).
pub const SUPPORTED: &[&str] = &[
    "Abs",
    "Add",
    "And",
    "ArgMax",
    "AveragePool",
    "BatchNormalization",
    "Cast",
    "CastLike",
    "Ceil",
    "Clip",
    "Concat",
    "Constant",
    "ConstantOfShape",
    "Conv",
    "ConvTranspose",
    "Div",
    "Dropout",
    "Elu",
    "Equal",
    "Erf",
    "Exp",
    "Expand",
    "Flatten",
    "Floor",
    "Gather",
    "GatherElements",
    "Gemm",
    "GlobalAveragePool",
    "GlobalMaxPool",
    "Greater",
    "GreaterOrEqual",
    "GridSample",
    "HardSigmoid",
    "HardSwish",
    "Identity",
    "LayerNormalization",
    "LeakyRelu",
    "Less",
    "LessOrEqual",
    "Log",
    "LogSoftmax",
    "MatMul",
    "Max",
    "MaxPool",
    "Mean",
    "Min",
    "Mish",
    "Mod",
    "Mul",
    "Neg",
    "NonMaxSuppression",
    "Not",
    "Or",
    "Pad",
    "Pow",
    "PRelu",
    "Range",
    "Reciprocal",
    "ReduceMax",
    "ReduceMean",
    "ReduceMin",
    "ReduceProd",
    "ReduceSum",
    "Relu",
    "Reshape",
    "Resize",
    "Round",
    "Shape",
    "Sigmoid",
    "Sign",
    "Size",
    "Slice",
    "Softmax",
    "Softplus",
    "Split",
    "Sqrt",
    "Squeeze",
    "Sub",
    "Sum",
    "Tanh",
    "Tile",
    "TopK",
    "Transpose",
    "Unsqueeze",
    "Upsample",
    "Where",
    "Xor",
];

/// Evaluates `node` (opset `opset`) on its inputs (`None`: an omitted optional input) on `dev`.
/// `x · sigmoid(x)` for a `Mul(x, Sigmoid(x))` pair the executor runs as one op (`node` is the
/// Mul; `args` holds `x` alone).
pub(crate) fn silu(
    node: &NodeDef,
    opset: i64,
    dev: &Device,
    args: &[Option<&Val>],
) -> Result<Vec<Val>> {
    let a = Args {
        node,
        opset,
        dev,
        args,
    };
    unary(&a, fast::silu)
}

pub fn eval(node: &NodeDef, opset: i64, dev: &Device, args: &[Option<&Val>]) -> Result<Vec<Val>> {
    let a = Args {
        node,
        opset,
        dev,
        args,
    };
    if let Some(out) = unary_op(&a)? {
        return Ok(out);
    }
    if let Some(out) = elementwise_op(&a)? {
        return Ok(out);
    }
    if let Some(out) = layer_op(&a)? {
        return Ok(out);
    }
    if let Some(out) = layout_op(&a)? {
        return Ok(out);
    }
    bail!("op {} is not supported", node.op)
}

/// The pass-through ops, activations and unary math; `None` for another op.
fn unary_op(a: &Args) -> Result<Option<Vec<Val>>> {
    Ok(Some(match a.node.op.as_str() {
        "Identity" | "Dropout" => vec![a.input(0)?.clone()],
        "Relu" => unary(a, fast::relu)?,
        "Sigmoid" => unary(a, fast::sigmoid)?,
        "Tanh" => unary(a, |t| t.tanh())?,
        "Exp" => unary(a, |t| t.exp())?,
        "Log" => unary(a, |t| t.log())?,
        "Sqrt" => unary(a, |t| t.sqrt())?,
        "Abs" => unary(a, |t| t.abs())?,
        "Reciprocal" => unary(a, |t| t.recip())?,
        "Floor" => unary(a, |t| t.floor())?,
        "Ceil" => unary(a, |t| t.ceil())?,
        "Round" => unary(a, |t| t.round())?,
        "Sign" => unary(a, |t| t.sign())?,
        "Erf" => unary(a, |t| t.erf())?,
        "Neg" => match a.input(0)? {
            Val::H(Host::I(x)) => vec![Val::H(Host::I(x.mapv(|v| -v)))],
            _ => unary(a, |t| t.neg())?,
        },
        "Softplus" => unary(a, |t| activation::softplus(t, 1.0))?,
        "Mish" => unary(a, |t| t.clone() * activation::softplus(t, 1.0).tanh())?,
        "LeakyRelu" => {
            let alpha = a.f("alpha").unwrap_or(0.01);
            unary(a, move |t| fast::leaky_relu(t, alpha))?
        }
        "Elu" => {
            let alpha = a.f("alpha").unwrap_or(1.0) as f64;
            unary(a, move |t| activation::elu(t, alpha))?
        }
        "HardSigmoid" => {
            let (al, be) = (a.f("alpha").unwrap_or(0.2), a.f("beta").unwrap_or(0.5));
            unary(a, move |t| t.mul_scalar(al).add_scalar(be).clamp(0.0, 1.0))?
        }
        "HardSwish" => unary(a, |t| fast::hard_swish(t, 1.0))?,
        _ => return Ok(None),
    }))
}

/// Clip, the arithmetic, comparison and logical ops, Where and PRelu; `None` for another op.
fn elementwise_op(a: &Args) -> Result<Option<Vec<Val>>> {
    let v = match a.node.op.as_str() {
        "Clip" => ew::clip(a)?,
        "Add" | "Sub" | "Mul" | "Div" | "Pow" | "Max" | "Min" | "Mod" | "Sum" | "Mean" => {
            ew::variadic(a)?
        }
        "Equal" | "Greater" | "Less" | "GreaterOrEqual" | "LessOrEqual" | "And" | "Or" | "Xor" => {
            ew::compare(a)?
        }
        "Not" => {
            let x = a.input(0)?.host()?;
            Val::H(Host::I(x.as_f().mapv(|v| i64::from(v == 0.0))))
        }
        "Where" => ew::where_(a)?,
        "PRelu" => {
            let x = a.dev_input(0)?;
            let s = a.dev_input(1)?;
            let out = broadcast(&x.shape, &s.shape)?;
            let (xt, st) = (expand(&x, &out), expand(&s, &out));
            Val::D(Dev::new(
                xt.clone().clamp_min(0.0) + st * xt.clamp_max(0.0),
                out,
            )?)
        }
        _ => return Ok(None),
    };
    Ok(Some(vec![v]))
}

/// The network layers of [`nn`] and [`transformer`]; `None` for another op.
fn layer_op(a: &Args) -> Result<Option<Vec<Val>>> {
    let v = match a.node.op.as_str() {
        "LayerNormalization" => return transformer::layer_norm(a).map(Some),
        "TopK" => return nn::top_k(a).map(Some),
        "Conv" => nn::conv(a)?,
        "ConvTranspose" => nn::conv_transpose(a)?,
        "GridSample" => transformer::grid_sample(a)?,
        "BatchNormalization" => nn::batch_norm(a)?,
        "MaxPool" | "AveragePool" => nn::pool(a)?,
        "GlobalAveragePool" | "GlobalMaxPool" => nn::global_pool(a)?,
        "Resize" | "Upsample" => nn::resize(a)?,
        "Softmax" | "LogSoftmax" => nn::softmax(a)?,
        "MatMul" => nn::matmul(a)?,
        "Gemm" => nn::gemm(a)?,
        "ReduceMax" | "ReduceMin" | "ReduceMean" | "ReduceSum" | "ReduceProd" => nn::reduce(a)?,
        "ArgMax" => nn::argmax(a)?,
        "NonMaxSuppression" => nn::non_max_suppression(a)?,
        "Pad" => nn::pad(a)?,
        _ => return Ok(None),
    };
    Ok(Some(vec![v]))
}

/// The layout, shape and constant ops of [`shape`]; `None` for another op.
fn layout_op(a: &Args) -> Result<Option<Vec<Val>>> {
    let v = match a.node.op.as_str() {
        "Split" => return shape::split(a).map(Some),
        "Reshape" => shape::reshape(a)?,
        "Flatten" => shape::flatten(a)?,
        "Squeeze" | "Unsqueeze" => shape::squeeze(a)?,
        "Transpose" => shape::transpose(a)?,
        "Concat" => shape::concat(a)?,
        "Slice" => shape::slice(a)?,
        "Gather" => shape::gather(a)?,
        "GatherElements" => shape::gather_elements(a)?,
        "Expand" => shape::expand_op(a)?,
        "Tile" => shape::tile(a)?,
        "Shape" | "Size" => shape::shape(a)?,
        "Constant" => shape::constant(a)?,
        "ConstantOfShape" => shape::constant_of_shape(a)?,
        "Range" => shape::range(a)?,
        "Cast" | "CastLike" => shape::cast(a)?,
        _ => return Ok(None),
    };
    Ok(Some(vec![v]))
}
