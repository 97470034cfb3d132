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
    let one = |v: Val| Ok(vec![v]);
    match node.op.as_str() {
        "Identity" | "Dropout" => one(a.input(0)?.clone()),
        "Relu" => unary(&a, fast::relu),
        "Sigmoid" => unary(&a, fast::sigmoid),
        "Tanh" => unary(&a, |t| t.tanh()),
        "Exp" => unary(&a, |t| t.exp()),
        "Log" => unary(&a, |t| t.log()),
        "Sqrt" => unary(&a, |t| t.sqrt()),
        "Abs" => unary(&a, |t| t.abs()),
        "Reciprocal" => unary(&a, |t| t.recip()),
        "Floor" => unary(&a, |t| t.floor()),
        "Ceil" => unary(&a, |t| t.ceil()),
        "Round" => unary(&a, |t| t.round()),
        "Sign" => unary(&a, |t| t.sign()),
        "Erf" => unary(&a, |t| t.erf()),
        "Neg" => match a.input(0)? {
            Val::H(Host::I(x)) => one(Val::H(Host::I(x.mapv(|v| -v)))),
            _ => unary(&a, |t| t.neg()),
        },
        "Softplus" => unary(&a, |t| activation::softplus(t, 1.0)),
        "Mish" => unary(&a, |t| t.clone() * activation::softplus(t, 1.0).tanh()),
        "LeakyRelu" => {
            let alpha = a.f("alpha").unwrap_or(0.01);
            unary(&a, move |t| fast::leaky_relu(t, alpha))
        }
        "Elu" => {
            let alpha = a.f("alpha").unwrap_or(1.0) as f64;
            unary(&a, move |t| activation::elu(t, alpha))
        }
        "HardSigmoid" => {
            let (al, be) = (a.f("alpha").unwrap_or(0.2), a.f("beta").unwrap_or(0.5));
            unary(&a, move |t| t.mul_scalar(al).add_scalar(be).clamp(0.0, 1.0))
        }
        "HardSwish" => unary(&a, |t| fast::hard_swish(t, 1.0)),
        "Clip" => one(ew::clip(&a)?),
        "Add" | "Sub" | "Mul" | "Div" | "Pow" | "Max" | "Min" | "Mod" | "Sum" | "Mean" => {
            one(ew::variadic(&a)?)
        }
        "Equal" | "Greater" | "Less" | "GreaterOrEqual" | "LessOrEqual" | "And" | "Or" | "Xor" => {
            one(ew::compare(&a)?)
        }
        "Not" => {
            let x = a.input(0)?.host()?;
            one(Val::H(Host::I(x.as_f().mapv(|v| i64::from(v == 0.0)))))
        }
        "Where" => one(ew::where_(&a)?),
        "PRelu" => {
            let x = a.dev_input(0)?;
            let s = a.dev_input(1)?;
            let out = broadcast(&x.shape, &s.shape)?;
            let (xt, st) = (expand(&x, &out), expand(&s, &out));
            one(Val::D(Dev::new(
                xt.clone().clamp_min(0.0) + st * xt.clamp_max(0.0),
                out,
            )?))
        }
        "Conv" => one(nn::conv(&a)?),
        "ConvTranspose" => one(nn::conv_transpose(&a)?),
        "LayerNormalization" => transformer::layer_norm(&a),
        "GridSample" => one(transformer::grid_sample(&a)?),
        "BatchNormalization" => one(nn::batch_norm(&a)?),
        "MaxPool" | "AveragePool" => one(nn::pool(&a)?),
        "GlobalAveragePool" | "GlobalMaxPool" => one(nn::global_pool(&a)?),
        "Resize" | "Upsample" => one(nn::resize(&a)?),
        "Softmax" | "LogSoftmax" => one(nn::softmax(&a)?),
        "MatMul" => one(nn::matmul(&a)?),
        "Gemm" => one(nn::gemm(&a)?),
        "ReduceMax" | "ReduceMin" | "ReduceMean" | "ReduceSum" | "ReduceProd" => {
            one(nn::reduce(&a)?)
        }
        "ArgMax" => one(nn::argmax(&a)?),
        "TopK" => nn::top_k(&a),
        "NonMaxSuppression" => one(nn::non_max_suppression(&a)?),
        "Pad" => one(nn::pad(&a)?),
        "Reshape" => one(shape::reshape(&a)?),
        "Flatten" => one(shape::flatten(&a)?),
        "Squeeze" | "Unsqueeze" => one(shape::squeeze(&a)?),
        "Transpose" => one(shape::transpose(&a)?),
        "Concat" => one(shape::concat(&a)?),
        "Split" => shape::split(&a),
        "Slice" => one(shape::slice(&a)?),
        "Gather" => one(shape::gather(&a)?),
        "GatherElements" => one(shape::gather_elements(&a)?),
        "Expand" => one(shape::expand_op(&a)?),
        "Tile" => one(shape::tile(&a)?),
        "Shape" | "Size" => one(shape::shape(&a)?),
        "Constant" => one(shape::constant(&a)?),
        "ConstantOfShape" => one(shape::constant_of_shape(&a)?),
        "Range" => one(shape::range(&a)?),
        "Cast" | "CastLike" => one(shape::cast(&a)?),
        op => bail!("op {op} is not supported"),
    }
}
