//! ONNX's layout and shape ops (Reshape, Flatten, Squeeze/Unsqueeze, Transpose, Concat, Split,
//! Slice, Gather, GatherElements, Expand, Tile) on device values and on host values alike, and
//! the ops that make host values (Shape, Size, Constant, ConstantOfShape, Range, Cast). Attribute
//! forms and input forms are both read, by opset, where the op changed (Split 13/18,
//! Squeeze/Unsqueeze 13, Slice 10).

use super::args::{axis, broadcast, expand, Args};
use super::model::Attr;
use super::value::{pad6, Dev, Host, Val, MAX_RANK};
use anyhow::{anyhow, bail, ensure, Result};
use burn::tensor::{Int, Tensor, TensorData};
use ndarray::{ArrayD, Axis, IxDyn};

/// Applies `$e` (an expression over the array `$a`, of either element type) to a host value.
macro_rules! each {
    ($h:expr, $a:ident => $e:expr) => {
        match $h {
            Host::F($a) => Host::F($e),
            Host::I($a) => Host::I($e),
        }
    };
}

fn reshaped<T: Clone>(a: &ArrayD<T>, shape: &[usize]) -> Result<ArrayD<T>> {
    Ok(a.as_standard_layout()
        .into_owned()
        .into_shape_with_order(IxDyn(shape))?)
}

/// A value with the same elements in a new shape.
fn with_shape(v: &Val, shape: Vec<usize>) -> Result<Val> {
    let n: usize = shape.iter().product();
    ensure!(
        n == v.shape().iter().product::<usize>(),
        "cannot reshape {:?} to {shape:?}",
        v.shape()
    );
    Ok(match v {
        Val::D(d) => Val::D(Dev::new(d.t.clone(), shape)?),
        Val::H(h) => Val::H(each!(h, a => reshaped(a, &shape)?)),
    })
}

pub fn reshape(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let target = a
        .ints_input(1)?
        .or_else(|| a.ints("shape"))
        .ok_or_else(|| anyhow!("Reshape without a shape"))?;
    let allowzero = a.i("allowzero").unwrap_or(0) != 0;
    let n: usize = x.shape().iter().product();
    let mut shape = Vec::with_capacity(target.len());
    let mut infer = None;
    for (k, &d) in target.iter().enumerate() {
        shape.push(match d {
            0 if !allowzero => *x
                .shape()
                .get(k)
                .ok_or_else(|| anyhow!("0 at axis {k} beyond the input's rank"))?,
            -1 => {
                ensure!(infer.is_none(), "two -1 in shape {target:?}");
                infer = Some(k);
                1
            }
            d if d >= 0 => d as usize,
            d => bail!("dimension {d} in shape {target:?}"),
        });
    }
    if let Some(k) = infer {
        let rest: usize = shape.iter().product();
        ensure!(
            rest > 0 && n % rest == 0,
            "cannot reshape {:?} to {target:?}",
            x.shape()
        );
        shape[k] = n / rest;
    }
    with_shape(x, shape)
}

pub fn flatten(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let r = x.shape().len();
    let k = if a.i("axis").unwrap_or(1) == r as i64 {
        r
    } else {
        axis(a.i("axis").unwrap_or(1), r)?
    };
    let s = x.shape();
    with_shape(x, vec![s[..k].iter().product(), s[k..].iter().product()])
}

pub(crate) fn squeeze(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let axes = if a.opset >= 13 {
        a.ints_input(1)?
    } else {
        a.ints("axes")
    };
    let mut shape = x.shape().to_vec();
    if a.node.op == "Unsqueeze" {
        let axes = axes.ok_or_else(|| anyhow!("Unsqueeze without axes"))?;
        let r = shape.len() + axes.len();
        let mut ax: Vec<usize> = axes.iter().map(|&k| axis(k, r)).collect::<Result<_>>()?;
        ax.sort_unstable();
        for k in ax {
            shape.insert(k, 1);
        }
    } else {
        let r = shape.len();
        let ax: Vec<usize> = match axes {
            Some(v) if !v.is_empty() => v.iter().map(|&k| axis(k, r)).collect::<Result<_>>()?,
            _ => (0..r).filter(|&k| shape[k] == 1).collect(),
        };
        for &k in &ax {
            ensure!(shape[k] == 1, "cannot squeeze axis {k} of shape {shape:?}");
        }
        shape = (0..r)
            .filter(|k| !ax.contains(k))
            .map(|k| shape[k])
            .collect();
    }
    with_shape(x, shape)
}

pub fn transpose(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let r = x.shape().len();
    let perm: Vec<usize> = match a.ints("perm") {
        Some(p) => p.iter().map(|&k| axis(k, r)).collect::<Result<_>>()?,
        None => (0..r).rev().collect(),
    };
    let mut seen = vec![false; r];
    ensure!(
        perm.len() == r && perm.iter().all(|&k| !std::mem::replace(&mut seen[k], true)),
        "perm {perm:?} is not a permutation of rank {r}"
    );
    let shape: Vec<usize> = perm.iter().map(|&k| x.shape()[k]).collect();
    Ok(match x {
        Val::D(d) => {
            let off = MAX_RANK - r;
            let mut p = [0usize; MAX_RANK];
            for (k, slot) in p.iter_mut().enumerate() {
                *slot = if k < off { k } else { off + perm[k - off] };
            }
            Val::D(Dev {
                t: d.t.clone().permute(p),
                shape,
            })
        }
        Val::H(h) => Val::H(
            each!(h, a => a.clone().permuted_axes(IxDyn(&perm)).as_standard_layout().into_owned()),
        ),
    })
}

pub fn concat(a: &Args) -> Result<Val> {
    let vals: Vec<&Val> = (0..a.n_inputs())
        .map(|k| a.input(k))
        .collect::<Result<_>>()?;
    let r = vals[0].shape().len();
    let ax = axis(
        a.i("axis").ok_or_else(|| anyhow!("Concat without axis"))?,
        r,
    )?;
    let mut shape = vals[0].shape().to_vec();
    shape[ax] = 0;
    for v in &vals {
        let s = v.shape();
        ensure!(
            s.len() == r && (0..r).all(|k| k == ax || s[k] == shape[k]),
            "inputs of shapes {:?} do not concatenate on axis {ax}",
            vals.iter().map(|v| v.shape().to_vec()).collect::<Vec<_>>()
        );
        shape[ax] += s[ax];
    }
    if vals.iter().all(|v| matches!(v, Val::H(Host::I(_)))) {
        let arrs: Vec<_> = vals
            .iter()
            .map(|v| match v {
                Val::H(Host::I(x)) => x.view(),
                _ => unreachable!(),
            })
            .collect();
        return Ok(Val::H(Host::I(ndarray::concatenate(Axis(ax), &arrs)?)));
    }
    if vals.iter().all(|v| matches!(v, Val::H(_))) {
        let fs: Vec<ArrayD<f32>> = vals
            .iter()
            .map(|v| v.host().map(|h| h.as_f()))
            .collect::<Result<_>>()?;
        let views: Vec<_> = fs.iter().map(|x| x.view()).collect();
        return Ok(Val::H(Host::F(ndarray::concatenate(Axis(ax), &views)?)));
    }
    let ts: Vec<Tensor<MAX_RANK>> = vals
        .iter()
        .filter(|v| v.shape()[ax] > 0)
        .map(|v| v.dev(a.dev).map(|d| d.t))
        .collect::<Result<_>>()?;
    Ok(Val::D(Dev {
        t: Tensor::cat(ts, MAX_RANK - r + ax),
        shape,
    }))
}

/// Values along one axis: indices (each in 0..dim) to keep, in order.
fn take(v: &Val, ax: usize, idx: &[usize], dev: &burn::tensor::Device) -> Result<Val> {
    let mut shape = v.shape().to_vec();
    let dim = shape[ax];
    ensure!(idx.iter().all(|&i| i < dim), "index out of range 0..{dim}");
    shape[ax] = idx.len();
    let contiguous = idx.windows(2).all(|w| w[1] == w[0] + 1);
    Ok(match v {
        Val::D(_) if idx.is_empty() => Val::D(Dev::new(Tensor::<1>::zeros([0], dev), shape)?),
        Val::D(d) if contiguous => Val::D(Dev {
            t: d.t.clone().narrow(d.axis(ax), idx[0], idx.len()),
            shape,
        }),
        Val::D(d) => {
            let i = Tensor::<1, Int>::from_data(
                TensorData::new(
                    idx.iter().map(|&i| i as i64).collect::<Vec<_>>(),
                    [idx.len()],
                ),
                dev,
            );
            Val::D(Dev {
                t: d.t.clone().select(d.axis(ax), i),
                shape,
            })
        }
        Val::H(h) => Val::H(each!(h, a => a.select(Axis(ax), idx))),
    })
}

pub fn split(a: &Args) -> Result<Vec<Val>> {
    let x = a.input(0)?;
    let r = x.shape().len();
    let ax = axis(a.i("axis").unwrap_or(0), r)?;
    let dim = x.shape()[ax];
    let n = a.n_outputs();
    let sizes: Vec<usize> = match (a.ints_input(1)?, a.ints("split"), a.i("num_outputs")) {
        (Some(s), _, _) | (None, Some(s), _) => s.iter().map(|&v| v.max(0) as usize).collect(),
        (None, None, Some(k)) => {
            let k = k as usize;
            let c = dim.div_ceil(k);
            (0..k).map(|i| c.min(dim.saturating_sub(i * c))).collect()
        }
        _ => {
            ensure!(dim % n == 0, "{dim} does not split evenly into {n}");
            vec![dim / n; n]
        }
    };
    ensure!(
        sizes.iter().sum::<usize>() == dim && sizes.len() == n,
        "split sizes {sizes:?} for axis length {dim} and {n} outputs"
    );
    let mut start = 0;
    sizes
        .iter()
        .map(|&s| {
            let idx: Vec<usize> = (start..start + s).collect();
            start += s;
            take(x, ax, &idx, a.dev)
        })
        .collect()
}

pub fn slice(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let r = x.shape().len();
    let (starts, ends, axes, steps) = if a.opset >= 10 {
        (
            a.ints_input(1)?
                .ok_or_else(|| anyhow!("Slice without starts"))?,
            a.ints_input(2)?
                .ok_or_else(|| anyhow!("Slice without ends"))?,
            a.ints_input(3)?,
            a.ints_input(4)?,
        )
    } else {
        (
            a.ints("starts")
                .ok_or_else(|| anyhow!("Slice without starts"))?,
            a.ints("ends")
                .ok_or_else(|| anyhow!("Slice without ends"))?,
            a.ints("axes"),
            None,
        )
    };
    let axes = axes.unwrap_or_else(|| (0..starts.len() as i64).collect());
    let steps = steps.unwrap_or_else(|| vec![1; starts.len()]);
    ensure!(
        ends.len() == starts.len() && axes.len() == starts.len() && steps.len() == starts.len(),
        "starts {starts:?}, ends {ends:?}, axes {axes:?}, steps {steps:?} differ in length"
    );
    let mut v = x.clone();
    for k in 0..starts.len() {
        let ax = axis(axes[k], r)?;
        let dim = v.shape()[ax] as i64;
        let step = steps[k];
        ensure!(step != 0, "step 0");
        let norm = |p: i64| if p < 0 { p + dim } else { p };
        let idx: Vec<usize> = if step > 0 {
            let s = norm(starts[k]).clamp(0, dim);
            let e = norm(ends[k]).clamp(0, dim);
            (s..e).step_by(step as usize).map(|i| i as usize).collect()
        } else {
            let s = norm(starts[k]).clamp(-1, dim - 1);
            let e = norm(ends[k]).clamp(-1, dim - 1);
            let mut out = Vec::new();
            let mut i = s;
            while i > e {
                out.push(i as usize);
                i += step;
            }
            out
        };
        v = take(&v, ax, &idx, a.dev)?;
    }
    Ok(v)
}

pub fn gather(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let ind = a.input(1)?.host()?;
    let r = x.shape().len();
    let ax = axis(a.i("axis").unwrap_or(0), r)?;
    let dim = x.shape()[ax] as i64;
    let idx: Vec<usize> = ind
        .ints()
        .iter()
        .map(|&i| {
            let j = if i < 0 { i + dim } else { i };
            ensure!(
                (0..dim).contains(&j),
                "index {i} out of range for axis length {dim}"
            );
            Ok(j as usize)
        })
        .collect::<Result<_>>()?;
    let picked = take(x, ax, &idx, a.dev)?;
    let s = x.shape();
    let shape: Vec<usize> = s[..ax]
        .iter()
        .chain(ind.shape())
        .chain(&s[ax + 1..])
        .copied()
        .collect();
    with_shape(&picked, shape)
}

/// GatherElements: `out[i][j][k] = data[index[i][j][k]][j][k]` (axis 0; likewise for the
/// others), indices of any sign within the axis, the output shaped as the indices. Device data
/// stays a burn `gather` (its gradient reaches the data); host data is gathered on the host.
pub(crate) fn gather_elements(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let ind = a.input(1)?.host()?;
    let s = x.shape().to_vec();
    let r = s.len();
    ensure!(
        r > 0 && ind.shape().len() == r,
        "indices of shape {:?} for data of shape {s:?}: the same rank is expected",
        ind.shape()
    );
    let ax = axis(a.i("axis").unwrap_or(0), r)?;
    let out = ind.shape().to_vec();
    ensure!(
        (0..r).all(|k| k == ax || out[k] <= s[k]),
        "indices of shape {out:?} exceed data of shape {s:?} off axis {ax}"
    );
    let dim = s[ax] as i64;
    let idx: Vec<i64> = ind
        .ints()
        .iter()
        .map(|&i| {
            let j = if i < 0 { i + dim } else { i };
            ensure!(
                (0..dim).contains(&j),
                "index {i} out of range for axis {ax} of length {dim}"
            );
            Ok(j)
        })
        .collect::<Result<_>>()?;
    match x {
        Val::D(d) => {
            // Off the axis only the indices' extent of the data takes part: cut it to that, so
            // data and indices agree there as burn's gather requires.
            let mut cut = pad6(&out);
            cut[d.axis(ax)] = s[ax];
            let data = d.t.clone().slice(cut.map(|n| 0..n));
            let it = Tensor::<MAX_RANK, Int>::from_data(TensorData::new(idx, pad6(&out)), a.dev);
            Ok(Val::D(Dev::new(data.gather(d.axis(ax), it), out)?))
        }
        Val::H(h) => {
            // Row-major walk over the output; the data's index is the output's with the axis
            // coordinate replaced by the index read there.
            let mut strides = vec![1usize; r];
            for k in (0..r.saturating_sub(1)).rev() {
                strides[k] = strides[k + 1] * s[k + 1];
            }
            let mut coord = vec![0usize; r];
            let src: Vec<usize> = idx
                .iter()
                .map(|&j| {
                    let at = (0..r)
                        .map(|k| if k == ax { j as usize } else { coord[k] } * strides[k])
                        .sum();
                    for k in (0..r).rev() {
                        coord[k] += 1;
                        if coord[k] < out[k] {
                            break;
                        }
                        coord[k] = 0;
                    }
                    at
                })
                .collect();
            Ok(Val::H(each!(h, arr => {
                let v: Vec<_> = arr.iter().copied().collect();
                ArrayD::from_shape_vec(IxDyn(&out), src.iter().map(|&i| v[i]).collect())?
            })))
        }
    }
}

pub(crate) fn expand_op(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let target: Vec<usize> = a
        .ints_input(1)?
        .ok_or_else(|| anyhow!("Expand without a shape"))?
        .iter()
        .map(|&v| v.max(0) as usize)
        .collect();
    let out = broadcast(x.shape(), &target)?;
    Ok(match x {
        Val::D(d) => Val::D(Dev::new(expand(d, &out), out)?),
        Val::H(h) => Val::H(each!(h, a => a
            .broadcast(IxDyn(&out))
            .ok_or_else(|| anyhow!("cannot expand {:?} to {out:?}", a.shape()))?
            .to_owned())),
    })
}

pub fn tile(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let reps = a
        .ints_input(1)?
        .ok_or_else(|| anyhow!("Tile without repeats"))?;
    ensure!(
        reps.len() == x.shape().len(),
        "repeats {reps:?} for shape {:?}",
        x.shape()
    );
    let mut v = x.clone();
    for (ax, &n) in reps.iter().enumerate() {
        let dim = v.shape()[ax];
        let idx: Vec<usize> = (0..n.max(0) as usize * dim).map(|i| i % dim).collect();
        v = take(&v, ax, &idx, a.dev)?;
    }
    Ok(v)
}

pub fn shape(a: &Args) -> Result<Val> {
    let s: Vec<i64> = a.input(0)?.shape().iter().map(|&d| d as i64).collect();
    if a.node.op == "Size" {
        return Ok(Val::H(Host::scalar_i(s.iter().product())));
    }
    let r = s.len() as i64;
    let clampi = |p: i64| (if p < 0 { p + r } else { p }).clamp(0, r) as usize;
    let start = clampi(a.i("start").unwrap_or(0));
    let end = clampi(a.i("end").unwrap_or(r));
    Ok(Val::H(Host::vec_i(s[start..end.max(start)].to_vec())))
}

pub fn constant(a: &Args) -> Result<Val> {
    let node = a.node;
    let get = |k: &str| node.attrs.get(k);
    Ok(Val::H(
        match (
            get("value"),
            get("value_float"),
            get("value_floats"),
            get("value_int"),
            get("value_ints"),
        ) {
            (Some(Attr::T(h)), ..) => h.clone(),
            (_, Some(Attr::F(v)), ..) => Host::F(ArrayD::from_elem(IxDyn(&[]), *v)),
            (_, _, Some(Attr::Fs(v)), ..) => {
                Host::F(ArrayD::from_shape_vec(IxDyn(&[v.len()]), v.clone())?)
            }
            (_, _, _, Some(Attr::I(v)), _) => Host::scalar_i(*v),
            (_, _, _, _, Some(Attr::Is(v))) => Host::vec_i(v.clone()),
            _ => bail!("Constant without a supported value attribute"),
        },
    ))
}

pub(crate) fn constant_of_shape(a: &Args) -> Result<Val> {
    let shape: Vec<usize> = a
        .ints_input(0)?
        .unwrap_or_default()
        .iter()
        .map(|&v| v.max(0) as usize)
        .collect();
    Ok(Val::H(match a.attr("value") {
        Some(Attr::T(Host::I(v))) => Host::I(ArrayD::from_elem(
            IxDyn(&shape),
            *v.iter().next().unwrap_or(&0),
        )),
        Some(Attr::T(Host::F(v))) => Host::F(ArrayD::from_elem(
            IxDyn(&shape),
            *v.iter().next().unwrap_or(&0.0),
        )),
        _ => Host::F(ArrayD::zeros(IxDyn(&shape))),
    }))
}

pub fn range(a: &Args) -> Result<Val> {
    let (s, l, d) = (
        a.input(0)?.host()?,
        a.input(1)?.host()?,
        a.input(2)?.host()?,
    );
    Ok(Val::H(match (&s, &l, &d) {
        (Host::I(_), Host::I(_), Host::I(_)) => {
            let (s, l, d) = (s.ints()[0], l.ints()[0], d.ints()[0]);
            ensure!(d != 0, "Range with delta 0");
            let n = ((l - s) as f64 / d as f64).ceil().max(0.0) as usize;
            Host::vec_i((0..n as i64).map(|i| s + i * d).collect())
        }
        _ => {
            let (s, l, d) = (s.floats()[0], l.floats()[0], d.floats()[0]);
            ensure!(d != 0.0, "Range with delta 0");
            let n = ((l - s) / d).ceil().max(0.0) as usize;
            let v: Vec<f32> = (0..n).map(|i| s + i as f32 * d).collect();
            Host::F(ArrayD::from_shape_vec(IxDyn(&[n]), v)?)
        }
    }))
}

/// Cast to a float type keeps device values on the device (gradients flow); a cast to an
/// integer or boolean type brings the value to the host (shape arithmetic).
pub fn cast(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let to = if a.node.op == "CastLike" {
        match a.input(1)? {
            Val::H(Host::I(_)) => 7,
            _ => 1,
        }
    } else {
        a.i("to").ok_or_else(|| anyhow!("Cast without `to`"))?
    };
    Ok(match (to, x) {
        (1 | 10 | 11 | 16, Val::D(_)) => x.clone(),
        (1 | 10 | 11 | 16, Val::H(h)) => Val::H(Host::F(h.as_f())),
        (9, v) => Val::H(Host::I(v.host()?.as_f().mapv(|f| i64::from(f != 0.0)))),
        (2..=7 | 12 | 13, v) => Val::H(Host::I(match v.host()? {
            Host::I(i) => i,
            Host::F(f) => f.mapv(|f| f as i64),
        })),
        (t, _) => bail!("Cast to data type {t} is not supported"),
    })
}
