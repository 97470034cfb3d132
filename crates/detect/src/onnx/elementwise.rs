//! ONNX's elementwise ops: unary activations, Clip, the binary arithmetic ops with numpy
//! broadcasting (host integers keep integer semantics: Div truncates, Mod takes the divisor's
//! sign, as onnxruntime does), comparisons and logic (And, Or, Xor), Where. Device values stay
//! burn ops.

use super::args::{broadcast, expand, Args};
use super::value::{Dev, Host, Val, MAX_RANK};
use anyhow::{anyhow, bail, ensure, Result};
use burn::tensor::{Device, Tensor};
use ndarray::{ArrayD, IxDyn, Zip};

pub(crate) fn unary(
    a: &Args,
    f: impl Fn(Tensor<MAX_RANK>) -> Tensor<MAX_RANK>,
) -> Result<Vec<Val>> {
    let x = a.dev_input(0)?;
    Ok(vec![Val::D(Dev {
        t: f(x.t),
        shape: x.shape,
    })])
}

/// Clip: bounds from attributes (opset < 11) or optional inputs.
pub fn clip(a: &Args) -> Result<Val> {
    let scalar = |k: usize| -> Result<Option<f32>> {
        Ok(match a.opt(k) {
            None => None,
            Some(v) => Some(
                *v.host()?
                    .floats()
                    .first()
                    .ok_or_else(|| anyhow!("empty bound"))?,
            ),
        })
    };
    let (lo, hi) = if a.opset < 11 {
        (a.f("min"), a.f("max"))
    } else {
        (scalar(1)?, scalar(2)?)
    };
    let x = a.dev_input(0)?;
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
pub(crate) fn variadic(a: &Args) -> Result<Val> {
    let op = a.node.op.as_str();
    let mut acc = a.input(0)?.clone();
    for k in 1..a.n_inputs() {
        let b = a.input(k)?;
        acc = match op {
            "Sum" | "Mean" => binary("Add", &acc, b, a.dev)?,
            _ => binary(op, &acc, b, a.dev)?,
        };
    }
    if op == "Mean" && a.n_inputs() > 1 {
        let n = a.n_inputs() as f32;
        let d = acc.dev(a.dev)?;
        acc = Val::D(Dev {
            t: d.t.div_scalar(n),
            shape: d.shape,
        });
    }
    Ok(acc)
}

/// Comparisons and logic: host values stay on the host (as 0/1 int64); device values give
/// a 0/1 float tensor (no gradient).
pub fn compare(args: &Args) -> Result<Val> {
    let op = args.node.op.as_str();
    let (a, b) = (args.input(0)?, args.input(1)?);
    if let (Val::H(x), Val::H(y)) = (a, b) {
        let (x, y) = (x.as_f(), y.as_f());
        let out = broadcast(x.shape(), y.shape())?;
        let xb = x
            .broadcast(IxDyn(&out))
            .ok_or_else(|| anyhow!("broadcast"))?;
        let yb = y
            .broadcast(IxDyn(&out))
            .ok_or_else(|| anyhow!("broadcast"))?;
        let r = Zip::from(&xb).and(&yb).map_collect(|&p, &q| {
            i64::from(match op {
                "Equal" => p == q,
                "Greater" => p > q,
                "Less" => p < q,
                "GreaterOrEqual" => p >= q,
                "LessOrEqual" => p <= q,
                "And" => p != 0.0 && q != 0.0,
                "Xor" => (p != 0.0) != (q != 0.0),
                _ => p != 0.0 || q != 0.0,
            })
        });
        return Ok(Val::H(Host::I(r)));
    }
    let (x, y) = (a.dev(args.dev)?, b.dev(args.dev)?);
    let out = broadcast(&x.shape, &y.shape)?;
    let (xt, yt) = (expand(&x, &out), expand(&y, &out));
    let m = match op {
        "Equal" => xt.equal(yt),
        "Greater" => xt.greater(yt),
        "Less" => xt.lower(yt),
        "GreaterOrEqual" => xt.greater_equal(yt),
        "LessOrEqual" => xt.lower_equal(yt),
        "And" => xt.mul(yt).not_equal_elem(0.0),
        "Xor" => xt
            .not_equal_elem(0.0)
            .float()
            .sub(yt.not_equal_elem(0.0).float())
            .not_equal_elem(0.0),
        _ => xt.abs().add(yt.abs()).not_equal_elem(0.0),
    };
    Ok(Val::D(Dev::new(m.float(), out)?))
}

pub(crate) fn where_(a: &Args) -> Result<Val> {
    let (c, x, y) = (a.input(0)?, a.input(1)?, a.input(2)?);
    if let (Val::H(c), Val::H(x), Val::H(y)) = (c, x, y) {
        let out = broadcast(&broadcast(c.shape(), x.shape())?, y.shape())?;
        /// `c ? x : y` elementwise, all three broadcast to `out`.
        fn pick<T: Copy>(
            c: &ArrayD<f32>,
            x: &ArrayD<T>,
            y: &ArrayD<T>,
            out: &[usize],
        ) -> Result<ArrayD<T>> {
            let b = |what: &str, s: &[usize]| {
                anyhow!("Where: {what} {s:?} does not broadcast to {out:?}")
            };
            let cb = c
                .broadcast(IxDyn(out))
                .ok_or_else(|| b("condition", c.shape()))?;
            let xb = x.broadcast(IxDyn(out)).ok_or_else(|| b("X", x.shape()))?;
            let yb = y.broadcast(IxDyn(out)).ok_or_else(|| b("Y", y.shape()))?;
            Ok(Zip::from(&cb)
                .and(&xb)
                .and(&yb)
                .map_collect(|&c, &p, &q| if c != 0.0 { p } else { q }))
        }
        let c = c.as_f();
        return Ok(Val::H(match (x, y) {
            (Host::I(x), Host::I(y)) => Host::I(pick(&c, x, y, &out)?),
            _ => Host::F(pick(&c, &x.as_f(), &y.as_f(), &out)?),
        }));
    }
    let (c, x, y) = (c.dev(a.dev)?, x.dev(a.dev)?, y.dev(a.dev)?);
    let out = broadcast(&broadcast(&c.shape, &x.shape)?, &y.shape)?;
    let mask = expand(&c, &out).not_equal_elem(0.0);
    Ok(Val::D(Dev::new(
        expand(&y, &out).mask_where(mask, expand(&x, &out)),
        out,
    )?))
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
        let ab = a
            .broadcast(IxDyn(out))
            .ok_or_else(|| anyhow!("broadcast"))?;
        let bb = b
            .broadcast(IxDyn(out))
            .ok_or_else(|| anyhow!("broadcast"))?;
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
