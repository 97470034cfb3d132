//! ONNX op semantics, dispatched by op type: the elementwise ops here, the layout and shape ops
//! in [`super::shape`], the network layers (convolution, pooling, resize, normalisation, matrix
//! products, top-k, NMS) in [`super::nn`]. Float ops on device values are burn ops, so autodiff
//! reaches the graph input; ops on host values (exported shape arithmetic) run on the host with
//! ONNX's integer semantics. An op outside [`SUPPORTED`] is an error naming the op.

use super::model::{Attr, NodeDef};
use super::value::{pad6, Dev, Host, Val, MAX_RANK};
use super::{nn, shape};
use anyhow::{anyhow, bail, ensure, Result};
use burn::tensor::{activation, Device, Tensor};
use ndarray::{ArrayD, IxDyn, Zip};

/// Every op type [`eval`] implements (default domain).
pub const SUPPORTED: &[&str] = &[
    "Abs", "Add", "And", "ArgMax", "AveragePool", "BatchNormalization", "Cast", "CastLike",
    "Ceil", "Clip", "Concat", "Constant", "ConstantOfShape", "Conv", "Div", "Dropout", "Elu",
    "Equal", "Exp", "Expand", "Flatten", "Floor", "Gather", "Gemm", "GlobalAveragePool",
    "GlobalMaxPool", "Greater", "GreaterOrEqual", "HardSigmoid", "HardSwish", "Identity",
    "LeakyRelu", "Less", "LessOrEqual", "Log", "LogSoftmax", "MatMul", "Max", "MaxPool", "Mean",
    "Min", "Mish", "Mod", "Mul", "Neg", "NonMaxSuppression", "Not", "Or", "Pad", "Pow", "PRelu",
    "Range", "Reciprocal", "ReduceMax", "ReduceMean", "ReduceMin", "ReduceProd", "ReduceSum",
    "Relu", "Reshape", "Resize", "Round", "Shape", "Sigmoid", "Sign", "Size", "Slice", "Softmax",
    "Softplus", "Split", "Sqrt", "Squeeze", "Sub", "Sum", "Tanh", "Tile", "TopK", "Transpose",
    "Unsqueeze", "Upsample", "Where",
];

/// Evaluates `node` (opset `opset`) on its inputs (`None`: an omitted optional input) on `dev`.
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
        "Relu" => a.unary(activation::relu),
        "Sigmoid" => a.unary(activation::sigmoid),
        "Tanh" => a.unary(|t| t.tanh()),
        "Exp" => a.unary(|t| t.exp()),
        "Log" => a.unary(|t| t.log()),
        "Sqrt" => a.unary(|t| t.sqrt()),
        "Abs" => a.unary(|t| t.abs()),
        "Reciprocal" => a.unary(|t| t.recip()),
        "Floor" => a.unary(|t| t.floor()),
        "Ceil" => a.unary(|t| t.ceil()),
        "Round" => a.unary(|t| t.round()),
        "Sign" => a.unary(|t| t.sign()),
        "Neg" => match a.input(0)? {
            Val::H(Host::I(x)) => one(Val::H(Host::I(x.mapv(|v| -v)))),
            _ => a.unary(|t| t.neg()),
        },
        "Softplus" => a.unary(|t| activation::softplus(t, 1.0)),
        "Mish" => a.unary(|t| t.clone() * activation::softplus(t, 1.0).tanh()),
        "LeakyRelu" => {
            let alpha = a.f("alpha").unwrap_or(0.01) as f64;
            a.unary(move |t| activation::leaky_relu(t, alpha))
        }
        "Elu" => {
            let alpha = a.f("alpha").unwrap_or(1.0) as f64;
            a.unary(move |t| activation::elu(t, alpha))
        }
        "HardSigmoid" => {
            let (al, be) = (a.f("alpha").unwrap_or(0.2), a.f("beta").unwrap_or(0.5));
            a.unary(move |t| t.mul_scalar(al).add_scalar(be).clamp(0.0, 1.0))
        }
        "HardSwish" => a.unary(|t| {
            t.clone() * t.div_scalar(6.0).add_scalar(0.5).clamp(0.0, 1.0)
        }),
        "Clip" => one(a.clip()?),
        "Add" | "Sub" | "Mul" | "Div" | "Pow" | "Max" | "Min" | "Mod" | "Sum" | "Mean" => {
            one(a.variadic()?)
        }
        "Equal" | "Greater" | "Less" | "GreaterOrEqual" | "LessOrEqual" | "And" | "Or" => {
            one(a.compare()?)
        }
        "Not" => {
            let x = a.input(0)?.host()?;
            one(Val::H(Host::I(
                x.as_f().mapv(|v| i64::from(v == 0.0)),
            )))
        }
        "Where" => one(a.where_()?),
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

/// A node's inputs and attributes, as the op implementations read them.
pub struct Args<'a> {
    pub node: &'a NodeDef,
    pub opset: i64,
    pub dev: &'a Device,
    pub args: &'a [Option<&'a Val>],
}

impl<'a> Args<'a> {
    pub fn opt(&self, k: usize) -> Option<&'a Val> {
        self.args.get(k).copied().flatten()
    }
    pub fn input(&self, k: usize) -> Result<&'a Val> {
        self.opt(k).ok_or_else(|| anyhow!("missing input {k}"))
    }
    pub fn n_inputs(&self) -> usize {
        self.args.len()
    }
    /// Input `k` as a device float tensor.
    pub fn dev_input(&self, k: usize) -> Result<Dev> {
        self.input(k)?.dev(self.dev)
    }
    /// Input `k` as host integers (shape, axis, size arguments); `None` when omitted.
    pub fn ints_input(&self, k: usize) -> Result<Option<Vec<i64>>> {
        Ok(match self.opt(k) {
            None => None,
            Some(Val::H(h)) => Some(h.ints()),
            Some(Val::D(d)) => {
                ensure!(
                    d.shape.iter().product::<usize>() <= 64,
                    "input {k} must be a small constant (shape/axis argument), got shape {:?}",
                    d.shape
                );
                Some(d.to_host()?.ints())
            }
        })
    }
    pub fn attr(&self, key: &str) -> Option<&'a Attr> {
        self.node.attrs.get(key)
    }
    pub fn f(&self, key: &str) -> Option<f32> {
        match self.attr(key)? {
            Attr::F(v) => Some(*v),
            Attr::I(v) => Some(*v as f32),
            _ => None,
        }
    }
    pub fn i(&self, key: &str) -> Option<i64> {
        match self.attr(key)? {
            Attr::I(v) => Some(*v),
            _ => None,
        }
    }
    pub fn ints(&self, key: &str) -> Option<Vec<i64>> {
        match self.attr(key)? {
            Attr::Is(v) => Some(v.clone()),
            Attr::I(v) => Some(vec![*v]),
            _ => None,
        }
    }
    pub fn floats(&self, key: &str) -> Option<Vec<f32>> {
        match self.attr(key)? {
            Attr::Fs(v) => Some(v.clone()),
            Attr::F(v) => Some(vec![*v]),
            _ => None,
        }
    }
    pub fn s(&self, key: &str) -> Option<&'a str> {
        match self.attr(key)? {
            Attr::S(v) => Some(v.as_str()),
            _ => None,
        }
    }
    pub fn n_outputs(&self) -> usize {
        self.node.outputs.len()
    }

    fn unary(&self, f: impl Fn(Tensor<MAX_RANK>) -> Tensor<MAX_RANK>) -> Result<Vec<Val>> {
        let x = self.dev_input(0)?;
        Ok(vec![Val::D(Dev {
            t: f(x.t),
            shape: x.shape,
        })])
    }

    /// Clip: bounds from attributes (opset < 11) or optional inputs.
    fn clip(&self) -> Result<Val> {
        let scalar = |k: usize| -> Result<Option<f32>> {
            Ok(match self.opt(k) {
                None => None,
                Some(v) => Some(
                    *v.host()?
                        .floats()
                        .first()
                        .ok_or_else(|| anyhow!("empty bound"))?,
                ),
            })
        };
        let (lo, hi) = if self.opset < 11 {
            (self.f("min"), self.f("max"))
        } else {
            (scalar(1)?, scalar(2)?)
        };
        let x = self.dev_input(0)?;
        let mut t = x.t;
        if let Some(lo) = lo {
            t = t.clamp_min(lo);
        }
        if let Some(hi) = hi {
            t = t.clamp_max(hi);
        }
        Ok(Val::D(Dev { t, shape: x.shape }))
    }

    /// The binary arithmetic ops, folded left over the inputs for the variadic ones.
    fn variadic(&self) -> Result<Val> {
        let op = self.node.op.as_str();
        let mut acc = self.input(0)?.clone();
        for k in 1..self.n_inputs() {
            let b = self.input(k)?;
            acc = match op {
                "Sum" | "Mean" => binary("Add", &acc, b, self.dev)?,
                _ => binary(op, &acc, b, self.dev)?,
            };
        }
        if op == "Mean" && self.n_inputs() > 1 {
            let n = self.n_inputs() as f32;
            let d = acc.dev(self.dev)?;
            acc = Val::D(Dev {
                t: d.t.div_scalar(n),
                shape: d.shape,
            });
        }
        Ok(acc)
    }

    /// Comparisons and logic: host values stay on the host (as 0/1 int64); device values give
    /// a 0/1 float tensor (no gradient).
    fn compare(&self) -> Result<Val> {
        let op = self.node.op.as_str();
        let (a, b) = (self.input(0)?, self.input(1)?);
        if let (Val::H(x), Val::H(y)) = (a, b) {
            let (x, y) = (x.as_f(), y.as_f());
            let out = broadcast(x.shape(), y.shape())?;
            let xb = x.broadcast(IxDyn(&out)).ok_or_else(|| anyhow!("broadcast"))?;
            let yb = y.broadcast(IxDyn(&out)).ok_or_else(|| anyhow!("broadcast"))?;
            let r = Zip::from(&xb).and(&yb).map_collect(|&p, &q| {
                i64::from(match op {
                    "Equal" => p == q,
                    "Greater" => p > q,
                    "Less" => p < q,
                    "GreaterOrEqual" => p >= q,
                    "LessOrEqual" => p <= q,
                    "And" => p != 0.0 && q != 0.0,
                    _ => p != 0.0 || q != 0.0,
                })
            });
            return Ok(Val::H(Host::I(r)));
        }
        let (x, y) = (a.dev(self.dev)?, b.dev(self.dev)?);
        let out = broadcast(&x.shape, &y.shape)?;
        let (xt, yt) = (expand(&x, &out), expand(&y, &out));
        let m = match op {
            "Equal" => xt.equal(yt),
            "Greater" => xt.greater(yt),
            "Less" => xt.lower(yt),
            "GreaterOrEqual" => xt.greater_equal(yt),
            "LessOrEqual" => xt.lower_equal(yt),
            "And" => xt.mul(yt).not_equal_elem(0.0),
            _ => xt.abs().add(yt.abs()).not_equal_elem(0.0),
        };
        Ok(Val::D(Dev::new(m.float(), out)?))
    }

    fn where_(&self) -> Result<Val> {
        let (c, x, y) = (self.input(0)?, self.input(1)?, self.input(2)?);
        if let (Val::H(c), Val::H(x), Val::H(y)) = (c, x, y) {
            let out = broadcast(&broadcast(c.shape(), x.shape())?, y.shape())?;
            let cb = c.as_f();
            let cb = cb.broadcast(IxDyn(&out)).ok_or_else(|| anyhow!("broadcast"))?;
            return Ok(Val::H(match (x, y) {
                (Host::I(x), Host::I(y)) => {
                    let xb = x.broadcast(IxDyn(&out)).ok_or_else(|| anyhow!("broadcast"))?;
                    let yb = y.broadcast(IxDyn(&out)).ok_or_else(|| anyhow!("broadcast"))?;
                    Host::I(
                        Zip::from(&cb)
                            .and(&xb)
                            .and(&yb)
                            .map_collect(|&c, &p, &q| if c != 0.0 { p } else { q }),
                    )
                }
                _ => {
                    let (x, y) = (x.as_f(), y.as_f());
                    let xb = x.broadcast(IxDyn(&out)).ok_or_else(|| anyhow!("broadcast"))?;
                    let yb = y.broadcast(IxDyn(&out)).ok_or_else(|| anyhow!("broadcast"))?;
                    Host::F(
                        Zip::from(&cb)
                            .and(&xb)
                            .and(&yb)
                            .map_collect(|&c, &p, &q| if c != 0.0 { p } else { q }),
                    )
                }
            }));
        }
        let (c, x, y) = (c.dev(self.dev)?, x.dev(self.dev)?, y.dev(self.dev)?);
        let out = broadcast(&broadcast(&c.shape, &x.shape)?, &y.shape)?;
        let mask = expand(&c, &out).not_equal_elem(0.0);
        Ok(Val::D(Dev::new(
            expand(&y, &out).mask_where(mask, expand(&x, &out)),
            out,
        )?))
    }
}

/// numpy's broadcast of two shapes.
pub fn broadcast(a: &[usize], b: &[usize]) -> Result<Vec<usize>> {
    let r = a.len().max(b.len());
    let at = |s: &[usize], k: usize| {
        if k + s.len() >= r {
            s[k + s.len() - r]
        } else {
            1
        }
    };
    (0..r)
        .map(|k| match (at(a, k), at(b, k)) {
            (x, y) if x == y => Ok(x),
            (1, y) => Ok(y),
            (x, 1) => Ok(x),
            _ => bail!("shapes {a:?} and {b:?} do not broadcast"),
        })
        .collect()
}

/// The physical tensor of `d` broadcast to logical shape `out`.
pub fn expand(d: &Dev, out: &[usize]) -> Tensor<MAX_RANK> {
    if d.shape == out {
        d.t.clone()
    } else {
        d.t.clone().expand(pad6(out))
    }
}

/// One binary arithmetic op with numpy broadcasting; integers on the host keep integer
/// semantics (Div truncates, as onnxruntime does).
pub fn binary(op: &str, a: &Val, b: &Val, dev: &Device) -> Result<Val> {
    if let (Val::H(x), Val::H(y)) = (a, b) {
        return host_binary(op, x, y).map(Val::H);
    }
    let out = broadcast(a.shape(), b.shape())?;
    let scalar = |v: &Val| match v {
        Val::H(h) if h.len() == 1 => h.floats().first().copied(),
        _ => None,
    };
    let t = match (op, scalar(b)) {
        ("Add", Some(s)) => a.dev(dev)?.t.add_scalar(s),
        ("Sub", Some(s)) => a.dev(dev)?.t.sub_scalar(s),
        ("Mul", Some(s)) => a.dev(dev)?.t.mul_scalar(s),
        ("Div", Some(s)) => a.dev(dev)?.t.div_scalar(s),
        ("Pow", Some(s)) => {
            let x = a.dev(dev)?.t;
            match s {
                1.0 => x,
                2.0 => x.clone() * x,
                3.0 => x.clone() * x.clone() * x,
                0.5 => x.sqrt(),
                _ => x.powf_scalar(s),
            }
        }
        _ => {
            let (x, y) = (a.dev(dev)?, b.dev(dev)?);
            let (x, y) = (expand(&x, &out), expand(&y, &out));
            match op {
                "Add" => x + y,
                "Sub" => x - y,
                "Mul" => x * y,
                "Div" => x / y,
                "Pow" => x.powf(y),
                "Max" => x.max_pair(y),
                "Min" => x.min_pair(y),
                "Mod" => x.remainder(y),
                _ => bail!("binary op {op} is not supported"),
            }
        }
    };
    let n: usize = out.iter().product();
    ensure!(
        t.dims().iter().product::<usize>() == n,
        "{op} of shapes {:?} and {:?}",
        a.shape(),
        b.shape()
    );
    Ok(Val::D(Dev::new(t, out)?))
}

fn host_binary(op: &str, a: &Host, b: &Host) -> Result<Host> {
    let out = broadcast(a.shape(), b.shape())?;
    fn zip<T: Copy>(
        a: &ArrayD<T>,
        b: &ArrayD<T>,
        out: &[usize],
        f: impl Fn(T, T) -> Result<T>,
    ) -> Result<ArrayD<T>> {
        let ab = a.broadcast(IxDyn(out)).ok_or_else(|| anyhow!("broadcast"))?;
        let bb = b.broadcast(IxDyn(out)).ok_or_else(|| anyhow!("broadcast"))?;
        let v: Vec<T> = ab
            .iter()
            .zip(bb.iter())
            .map(|(&p, &q)| f(p, q))
            .collect::<Result<_>>()?;
        Ok(ArrayD::from_shape_vec(IxDyn(out), v)?)
    }
    Ok(match (a, b) {
        (Host::I(x), Host::I(y)) => Host::I(zip(x, y, &out, |p, q| {
            Ok(match op {
                "Add" => p.wrapping_add(q),
                "Sub" => p.wrapping_sub(q),
                "Mul" => p.wrapping_mul(q),
                "Div" if q == 0 => bail!("integer division by zero"),
                "Div" => p / q,
                "Mod" if q == 0 => bail!("integer modulo by zero"),
                "Mod" => ((p % q) + q) % q, // the sign of the divisor (fmod = 0)
                "Max" => p.max(q),
                "Min" => p.min(q),
                "Pow" => p.pow(u32::try_from(q).map_err(|_| anyhow!("exponent {q}"))?),
                _ => bail!("{op} on integers is not supported"),
            })
        })?),
        _ => Host::F(zip(&a.as_f(), &b.as_f(), &out, |p, q| {
            Ok(match op {
                "Add" => p + q,
                "Sub" => p - q,
                "Mul" => p * q,
                "Div" => p / q,
                "Pow" => p.powf(q),
                "Max" => p.max(q),
                "Min" => p.min(q),
                "Mod" => p % q,
                _ => bail!("{op} is not supported"),
            })
        })?),
    })
}

/// A possibly negative axis of a rank-`rank` tensor, checked.
pub fn axis(a: i64, rank: usize) -> Result<usize> {
    let r = rank as i64;
    ensure!(
        (-r..r).contains(&a) || (rank == 0 && a == 0),
        "axis {a} is out of range for rank {rank}"
    );
    Ok(if a < 0 { (a + r) as usize } else { a as usize })
}
