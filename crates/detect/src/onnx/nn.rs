//! ONNX's network layers on device values: Conv (groups, dilations, asymmetric and `auto_pad`
//! padding), ConvTranspose (the same, with `output_padding` and `output_shape`),
//! BatchNormalization (inference), Max/Average/Global pooling, Resize/Upsample (nearest and
//! linear, every coordinate transformation of opset 11–21 but `tf_crop_and_resize`), Softmax
//! (both axis semantics), MatMul, Gemm, Reduce*, ArgMax, TopK, Pad (constant), and
//! NonMaxSuppression on the host. Each follows the ONNX operator specification as onnxruntime
//! implements it (tests/onnx_conformance.rs compares them).

use super::args::{axis, broadcast, expand, Args};
use super::value::{pad6, Dev, Host, Val, MAX_RANK};
use crate::conv::conv2d;
use crate::kernels::pad_constant;
use crate::nms::non_max_suppression as nms;
use anyhow::{anyhow, bail, ensure, Result};
use burn::tensor::module::{avg_pool2d, conv_transpose2d, max_pool2d};
use burn::tensor::ops::{AvgPoolOptions, ConvOptions, ConvTransposeOptions, MaxPoolOptions};
use burn::tensor::{activation, Int, Tensor, TensorData};
use ndarray::{ArrayD, Axis, IxDyn};

/// Spatial attributes of a 2D window op.
struct Window {
    kernel: [usize; 2],
    stride: [usize; 2],
    dilation: [usize; 2],
    /// `(begin, end)` per spatial axis.
    pads: [(usize, usize); 2],
}

fn pair(v: Option<Vec<i64>>, default: usize, what: &str) -> Result<[usize; 2]> {
    match v.as_deref() {
        None => Ok([default; 2]),
        Some([a, b]) if *a >= 0 && *b >= 0 => Ok([*a as usize, *b as usize]),
        Some(o) => bail!("{what} {o:?}: only 2D windows are supported"),
    }
}

fn window(a: &Args, input: [usize; 2], kernel: [usize; 2]) -> Result<Window> {
    let stride = pair(a.ints("strides"), 1, "strides")?;
    let dilation = pair(a.ints("dilations"), 1, "dilations")?;
    let auto = a.s("auto_pad").unwrap_or("NOTSET");
    let pads = match auto {
        "NOTSET" => match a.ints("pads").as_deref() {
            None => [(0, 0); 2],
            Some([t, l, b, r]) if [t, l, b, r].iter().all(|v| **v >= 0) => {
                [(*t as usize, *b as usize), (*l as usize, *r as usize)]
            }
            Some(p) => bail!("pads {p:?}: four non-negative values expected"),
        },
        "VALID" => [(0, 0); 2],
        "SAME_UPPER" | "SAME_LOWER" => std::array::from_fn(|k| {
            let out = input[k].div_ceil(stride[k]);
            let need = ((out - 1) * stride[k] + (kernel[k] - 1) * dilation[k] + 1)
                .saturating_sub(input[k]);
            let small = need / 2;
            if auto == "SAME_UPPER" {
                (small, need - small)
            } else {
                (need - small, small)
            }
        }),
        p => bail!("auto_pad {p} is not supported"),
    };
    Ok(Window {
        kernel,
        stride,
        dilation,
        pads,
    })
}

fn nchw(x: &Dev) -> Result<(Tensor<4>, [usize; 4])> {
    ensure!(
        x.rank() == 4,
        "input of shape {:?}: only 2D (NCHW) is supported",
        x.shape
    );
    let s = [x.shape[0], x.shape[1], x.shape[2], x.shape[3]];
    Ok((x.t4()?, s))
}

pub fn conv(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    let w = a.dev_input(1)?;
    let (xt, s) = nchw(&x)?;
    let (wt, ws) = nchw(&w)?;
    let group = a.i("group").unwrap_or(1).max(1) as usize;
    ensure!(
        ws[1] * group == s[1] && ws[0] % group == 0,
        "weight {ws:?} with group {group} does not fit input {s:?}"
    );
    let k = pair(a.ints("kernel_shape"), 0, "kernel_shape")?;
    ensure!(
        k == [0, 0] || k == [ws[2], ws[3]],
        "kernel_shape {k:?} does not match weight {ws:?}"
    );
    let win = window(a, [s[2], s[3]], [ws[2], ws[3]])?;
    let bias = match a.opt(2) {
        Some(b) => Some(b.dev(a.dev)?.t.reshape([ws[0]])),
        None => None,
    };
    // Every layer through `detect::conv::conv2d` (dense layers: tiled im2col + matrix products
    // split over threads), the RGB stem included.
    let y = conv2d(
        xt,
        wt,
        bias,
        ConvOptions::new_with_padding(win.stride, win.pads, win.dilation, group),
    );
    Ok(Val::D(Dev::from(y)?))
}

/// ConvTranspose (2D): burn's transposed convolution without padding, then the ONNX output
/// window cut from it: `pads` (explicit, or from `auto_pad` / `output_shape`) crop the begin
/// and end, `output_padding` adds rows and columns at the end that no input reaches; the bias
/// is added last, so it covers those too.
pub(crate) fn conv_transpose(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    let w = a.dev_input(1)?;
    let (xt, s) = nchw(&x)?;
    let (wt, ws) = nchw(&w)?;
    let group = a.i("group").unwrap_or(1).max(1) as usize;
    ensure!(
        ws[0] == s[1] && s[1] % group == 0,
        "weight {ws:?} with group {group} does not fit input {s:?} (ConvTranspose's weight is \
         [C_in, C_out / group, kH, kW])"
    );
    let m = ws[1] * group;
    let k = pair(a.ints("kernel_shape"), 0, "kernel_shape")?;
    ensure!(
        k == [0, 0] || k == [ws[2], ws[3]],
        "kernel_shape {k:?} does not match weight {ws:?}"
    );
    let stride = pair(a.ints("strides"), 1, "strides")?;
    let dilation = pair(a.ints("dilations"), 1, "dilations")?;
    let out_pad = pair(a.ints("output_padding"), 0, "output_padding")?;
    ensure!(
        stride.iter().chain(&dilation).all(|&v| v > 0),
        "strides {stride:?} and dilations {dilation:?} must be positive"
    );
    // The uncropped length per spatial axis: every input's kernel footprint, plus output_padding.
    let full: [usize; 2] = std::array::from_fn(|i| {
        stride[i] * (s[2 + i] - 1) + (ws[2 + i] - 1) * dilation[i] + 1 + out_pad[i]
    });
    let pads = transposed_pads(a, [s[2], s[3]], stride, full)?;
    let out: [usize; 2] = std::array::from_fn(|i| full[i].saturating_sub(pads[i].0 + pads[i].1));
    ensure!(
        out[0] > 0 && out[1] > 0,
        "pads {pads:?} leave nothing of the {full:?} output"
    );
    let y = conv_transpose2d(
        xt,
        wt,
        None,
        ConvTransposeOptions::new(stride, [0, 0], [0, 0], dilation, group),
    );
    let mut y = output_window(y, pads, out, s[0], m);
    if let Some(b) = a.opt(2) {
        let b = b.dev(a.dev)?;
        ensure!(
            b.shape.iter().product::<usize>() == m,
            "bias of shape {:?} for {m} output channels",
            b.shape
        );
        y = y + b.t.reshape([1, m, 1, 1]);
    }
    Ok(Val::D(Dev::from(y)?))
}

/// ConvTranspose's `(begin, end)` crop per spatial axis of the uncropped output `full`, for an
/// input of spatial size `input`.
fn transposed_pads(
    a: &Args,
    input: [usize; 2],
    stride: [usize; 2],
    full: [usize; 2],
) -> Result<[(usize, usize); 2]> {
    let auto = a.s("auto_pad").unwrap_or("NOTSET");
    // An explicit output shape (or SAME's input × stride) sets the total padding, split as
    // SAME_UPPER / SAME_LOWER say (NOTSET and VALID as SAME_LOWER would, as onnxruntime does).
    let target: Option<[usize; 2]> = match a.ints("output_shape").as_deref() {
        Some(o) if o.len() >= 2 && o[o.len() - 2..].iter().all(|&v| v > 0) => {
            Some([o[o.len() - 2] as usize, o[o.len() - 1] as usize])
        }
        Some(o) => bail!("output_shape {o:?}: two positive spatial sizes expected"),
        None if auto.starts_with("SAME_") => Some([input[0] * stride[0], input[1] * stride[1]]),
        None => None,
    };
    Ok(match (target, auto) {
        (Some(t), _) => {
            let mut p = [(0, 0); 2];
            for i in 0..2 {
                ensure!(
                    t[i] <= full[i],
                    "output_shape {t:?} is larger than the transposed convolution's {full:?}"
                );
                let total = full[i] - t[i];
                p[i] = match auto {
                    "SAME_UPPER" => (total / 2, total - total / 2),
                    _ => (total - total / 2, total / 2),
                };
            }
            p
        }
        (None, "VALID") => [(0, 0); 2],
        (None, "NOTSET") => match a.ints("pads").as_deref() {
            None => [(0, 0); 2],
            Some([t, l, b, r]) if [t, l, b, r].iter().all(|v| **v >= 0) => {
                [(*t as usize, *b as usize), (*l as usize, *r as usize)]
            }
            Some(p) => bail!("pads {p:?}: four non-negative values expected"),
        },
        (None, p) => bail!("auto_pad {p} is not supported"),
    })
}

/// The window `[begin, begin + out)` per spatial axis of burn's uncropped output `y` (`n`
/// images, `m` channels); burn's output stops short of the output_padding rows/columns, which
/// no input reaches: they are zeros (before the bias).
fn output_window(
    y: Tensor<4>,
    pads: [(usize, usize); 2],
    out: [usize; 2],
    n: usize,
    m: usize,
) -> Tensor<4> {
    let [_, _, yh, yw] = y.dims();
    let keep = |i: usize, have: usize| {
        let start = pads[i].0.min(have);
        let end = (pads[i].0 + out[i]).min(have);
        (start, end, out[i] - (end - start))
    };
    let (h0, h1, hpad) = keep(0, yh);
    let (w0, w1, wpad) = keep(1, yw);
    let mut y = y.slice([0..n, 0..m, h0..h1, w0..w1]);
    if hpad > 0 || wpad > 0 {
        y = pad_constant(y, &[(0, hpad), (0, wpad)], 0.0);
    }
    y
}

/// `scale * (x - mean) / sqrt(var + epsilon) + bias` per channel (axis 1).
pub(crate) fn batch_norm(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    ensure!(x.rank() >= 2, "input of shape {:?}", x.shape);
    let c = x.shape[1];
    let eps = a.f("epsilon").unwrap_or(1e-5);
    let v = |k: usize| -> Result<Vec<f32>> {
        let h = a.input(k)?.host()?;
        ensure!(
            h.len() == c,
            "parameter {k} has {} values for {c} channels",
            h.len()
        );
        Ok(h.floats())
    };
    let (scale, bias, mean, var) = (v(1)?, v(2)?, v(3)?, v(4)?);
    let mul: Vec<f32> = (0..c).map(|i| scale[i] / (var[i] + eps).sqrt()).collect();
    let add: Vec<f32> = (0..c).map(|i| bias[i] - mean[i] * mul[i]).collect();
    let mut s = vec![1; x.rank()];
    s[1] = c;
    let up = |v: Vec<f32>| -> Result<Tensor<MAX_RANK>> {
        Ok(Dev::new(
            Tensor::<1>::from_data(TensorData::new(v, [c]), a.dev),
            s.clone(),
        )?
        .t
        .expand(pad6(&x.shape)))
    };
    Ok(Val::D(Dev {
        t: x.t.clone() * up(mul)? + up(add)?,
        shape: x.shape,
    }))
}

pub fn pool(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    let (xt, s) = nchw(&x)?;
    let k = pair(a.ints("kernel_shape"), 0, "kernel_shape")?;
    ensure!(k[0] > 0 && k[1] > 0, "kernel_shape missing");
    let win = window(a, [s[2], s[3]], k)?;
    let ceil = a.i("ceil_mode").unwrap_or(0) != 0;
    let y = if a.node.op == "MaxPool" {
        ensure!(
            a.n_outputs() == 1,
            "MaxPool's Indices output is not supported"
        );
        let o = MaxPoolOptions::new(win.kernel)
            .with_stride(win.stride)
            .with_padding_pairs(win.pads)
            .with_dilation(win.dilation)
            .with_ceil_mode(ceil);
        max_pool2d(xt, o)
    } else {
        ensure!(
            win.dilation == [1, 1],
            "AveragePool dilations are not supported"
        );
        let o = AvgPoolOptions::new(win.kernel)
            .with_stride(win.stride)
            .with_padding_pairs(win.pads)
            .with_count_include_pad(a.i("count_include_pad").unwrap_or(0) != 0)
            .with_ceil_mode(ceil);
        avg_pool2d(xt, o)
    };
    Ok(Val::D(Dev::from(y)?))
}

pub(crate) fn global_pool(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    let (xt, [n, c, _, _]) = nchw(&x)?;
    let flat: Tensor<3> = xt.reshape([n as i64, c as i64, -1]);
    let y = if a.node.op == "GlobalMaxPool" {
        flat.max_dim(2)
    } else {
        flat.mean_dim(2)
    };
    Ok(Val::D(Dev::new(y, vec![n, c, 1, 1])?))
}

/// Resize (opset 10+) and Upsample on the last two axes.
pub fn resize(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    let r = x.rank();
    let in_shape = x.shape.clone();
    let (scales, sizes) = resize_scales_and_sizes(a)?;
    let (out, scale) = resize_output_shape(&in_shape, sizes, scales)?;
    let sampling = Sampling::of(a);
    let mut v = x;
    for k in r.saturating_sub(2)..r {
        if out[k] == in_shape[k] && scale[k] == 1.0 {
            continue;
        }
        let (n_in, n_out, sc) = (in_shape[k], out[k], scale[k]);
        let axis = AxisResize {
            n_in,
            n_out,
            scale: sc,
            last: (n_in - 1) as f32,
        };
        v = sampling.resize_axis(a, v, k, &axis)?;
    }
    Ok(Val::D(v))
}

/// Resize's scales and sizes, where given.
type ScalesAndSizes = (Option<Vec<f32>>, Option<Vec<i64>>);

/// Resize's `(scales, sizes)` inputs (Upsample's and opset 10's scales alone), refusing
/// `antialias` and `axes`.
fn resize_scales_and_sizes(a: &Args) -> Result<ScalesAndSizes> {
    let (scales, sizes): ScalesAndSizes = if a.node.op == "Upsample" {
        let s = match a.opt(1) {
            Some(v) => v.host()?.floats(),
            None => a
                .floats("scales")
                .ok_or_else(|| anyhow!("Upsample without scales"))?,
        };
        (Some(s), None)
    } else if a.opset < 11 {
        (Some(a.input(1)?.host()?.floats()), None)
    } else {
        let scales = match a.opt(2) {
            Some(v) if !v.shape().contains(&0) => Some(v.host()?.floats()),
            _ => None,
        };
        (scales, a.ints_input(3)?.filter(|v| !v.is_empty()))
    };
    ensure!(
        a.opt(4).is_none() && a.i("antialias").unwrap_or(0) == 0,
        "antialias and axes are not supported"
    );
    Ok((scales, sizes))
}

/// The output shape and the scale per axis (sizes win over scales); only the last two axes
/// may change.
fn resize_output_shape(
    in_shape: &[usize],
    sizes: Option<Vec<i64>>,
    scales: Option<Vec<f32>>,
) -> Result<(Vec<usize>, Vec<f32>)> {
    let r = in_shape.len();
    let (out, scale): (Vec<usize>, Vec<f32>) = match (sizes, scales) {
        (Some(sz), _) => {
            ensure!(sz.len() == r, "sizes {sz:?} for rank {r}");
            let o: Vec<usize> = sz.iter().map(|&v| v.max(0) as usize).collect();
            let sc = (0..r).map(|k| o[k] as f32 / in_shape[k] as f32).collect();
            (o, sc)
        }
        (None, Some(sc)) => {
            ensure!(sc.len() == r, "scales {sc:?} for rank {r}");
            let o = (0..r)
                .map(|k| (in_shape[k] as f32 * sc[k]).floor() as usize)
                .collect();
            (o, sc)
        }
        _ => bail!("neither scales nor sizes given"),
    };
    ensure!(
        (0..r.saturating_sub(2)).all(|k| out[k] == in_shape[k]),
        "resizing axes other than the last two ({in_shape:?} to {out:?}) is not supported"
    );
    Ok((out, scale))
}

/// One resized axis: input and output lengths, the scale, and the last input index.
struct AxisResize {
    n_in: usize,
    n_out: usize,
    scale: f32,
    last: f32,
}

/// How Resize samples: its mode, coordinate transformation and nearest-neighbour rounding.
struct Sampling<'a> {
    mode: &'a str,
    ctm: &'a str,
    nearest_mode: &'a str,
}

impl<'a> Sampling<'a> {
    /// The attributes of `a`, with the defaults of its op and opset.
    fn of(a: &Args<'a>) -> Self {
        let mode = a.s("mode").unwrap_or("nearest");
        let ctm = if a.node.op == "Upsample" || a.opset < 11 {
            "asymmetric"
        } else {
            a.s("coordinate_transformation_mode")
                .unwrap_or("half_pixel")
        };
        let nearest_mode = a.s("nearest_mode").unwrap_or(if a.opset < 11 {
            "floor"
        } else {
            "round_prefer_floor"
        });
        Sampling {
            mode,
            ctm,
            nearest_mode,
        }
    }

    /// The input coordinate of output index `i` on `axis`.
    fn source_coordinate(&self, axis: &AxisResize, i: usize) -> Result<f32> {
        let (n_in, n_out, sc) = (axis.n_in, axis.n_out, axis.scale);
        let i = i as f32;
        Ok(match self.ctm {
            "half_pixel" => (i + 0.5) / sc - 0.5,
            "pytorch_half_pixel" if n_out > 1 => (i + 0.5) / sc - 0.5,
            "pytorch_half_pixel" => 0.0,
            "align_corners" if n_out > 1 => i * (n_in - 1) as f32 / (n_out - 1) as f32,
            "align_corners" => 0.0,
            "asymmetric" => i / sc,
            "tf_half_pixel_for_nn" => (i + 0.5) / sc,
            m => bail!("coordinate_transformation_mode {m} is not supported"),
        })
    }

    /// `v` resized along its axis `k` as `axis` says.
    fn resize_axis(&self, a: &Args, v: Dev, k: usize, axis: &AxisResize) -> Result<Dev> {
        match self.mode {
            "nearest" => self.resize_nearest(a, v, k, axis),
            "linear" | "bilinear" => self.resize_linear(a, v, k, axis),
            m => bail!("Resize mode {m} is not supported"),
        }
    }

    /// Nearest-neighbour resize of `v` along axis `k`: the rounded source index per output.
    fn resize_nearest(&self, a: &Args, v: Dev, k: usize, axis: &AxisResize) -> Result<Dev> {
        let n_out = axis.n_out;
        let ax = v.axis(k);
        let idx = (0..n_out)
            .map(|i| {
                let c = self.source_coordinate(axis, i)?;
                let f = c.floor();
                let j = match self.nearest_mode {
                    "floor" => f,
                    "ceil" => c.ceil(),
                    "round_prefer_ceil" => (c + 0.5).floor(),
                    "round_prefer_floor" if c - f == 0.5 => f,
                    "round_prefer_floor" => c.round(),
                    m => bail!("nearest_mode {m} is not supported"),
                };
                Ok(j.clamp(0.0, axis.last) as i64)
            })
            .collect::<Result<Vec<_>>>()?;
        let mut shape = v.shape.clone();
        shape[k] = n_out;
        let idx = Tensor::<1, Int>::from_data(TensorData::new(idx, [n_out]), a.dev);
        Ok(Dev {
            t: v.t.select(ax, idx),
            shape,
        })
    }

    /// Linear resize of `v` along axis `k`: `lo + (hi - lo) * w` between the two neighbouring
    /// source samples.
    fn resize_linear(&self, a: &Args, v: Dev, k: usize, axis: &AxisResize) -> Result<Dev> {
        let (n_in, n_out) = (axis.n_in, axis.n_out);
        let ax = v.axis(k);
        let mut lo = Vec::with_capacity(n_out);
        let mut hi = Vec::with_capacity(n_out);
        let mut w = Vec::with_capacity(n_out);
        for i in 0..n_out {
            let c = self.source_coordinate(axis, i)?.clamp(0.0, axis.last);
            let f = c.floor();
            lo.push(f as i64);
            hi.push((f as i64 + 1).min(n_in as i64 - 1));
            w.push(c - f);
        }
        let mut shape = v.shape.clone();
        shape[k] = n_out;
        let mut ws = [1usize; MAX_RANK];
        ws[ax] = n_out;
        let wt = Tensor::<1>::from_data(TensorData::new(w, [n_out]), a.dev)
            .reshape(ws)
            .expand(pad6(&shape));
        let sel = |i: Vec<i64>| {
            v.t.clone().select(
                ax,
                Tensor::<1, Int>::from_data(TensorData::new(i, [n_out]), a.dev),
            )
        };
        let (l, h) = (sel(lo), sel(hi));
        Ok(Dev {
            t: l.clone() + (h - l) * wt,
            shape,
        })
    }
}

pub fn softmax(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    let r = x.rank();
    let log = a.node.op == "LogSoftmax";
    let f = |t: Tensor<MAX_RANK>, d: usize| {
        if log {
            activation::log_softmax(t, d)
        } else {
            activation::softmax(t, d)
        }
    };
    if a.opset >= 13 {
        let ax = axis(a.i("axis").unwrap_or(-1), r)?;
        return Ok(Val::D(Dev {
            t: f(x.t.clone(), x.axis(ax)),
            shape: x.shape,
        }));
    }
    // Before opset 13: the input is coerced to 2D at `axis`, softmax over the second part.
    let ax = axis(a.i("axis").unwrap_or(1), r)?;
    let outer: usize = x.shape[..ax].iter().product();
    let inner: usize = x.shape[ax..].iter().product();
    let t: Tensor<2> = x.t.clone().reshape([outer, inner]);
    let y = if log {
        activation::log_softmax(t, 1)
    } else {
        activation::softmax(t, 1)
    };
    Ok(Val::D(Dev::new(y, x.shape)?))
}

/// numpy matmul: batch dimensions broadcast, 1-D operands promoted and their axis removed.
pub fn matmul(a: &Args) -> Result<Val> {
    let (x, y) = (a.dev_input(0)?, a.dev_input(1)?);
    Ok(Val::D(matmul2(x, y)?))
}

fn matmul2(x: Dev, y: Dev) -> Result<Dev> {
    let (xv, yv) = (x.rank() == 1, y.rank() == 1);
    let mut xs = x.shape.clone();
    let mut ys = y.shape.clone();
    if xv {
        xs.insert(0, 1);
    }
    if yv {
        ys.push(1);
    }
    ensure!(xs.len() >= 2 && ys.len() >= 2, "MatMul of scalars");
    let (m, kx) = (xs[xs.len() - 2], xs[xs.len() - 1]);
    let (ky, n) = (ys[ys.len() - 2], ys[ys.len() - 1]);
    ensure!(kx == ky, "MatMul of {:?} and {:?}", x.shape, y.shape);
    let batch = broadcast(&xs[..xs.len() - 2], &ys[..ys.len() - 2])?;
    let full = |b: &[usize], p: usize, q: usize| {
        let mut s = b.to_vec();
        s.extend([p, q]);
        s
    };
    let xt = Dev::new(x.t, xs.clone())?;
    let yt = Dev::new(y.t, ys.clone())?;
    let xe = expand(&xt, &full(&batch, m, kx));
    let ye = expand(&yt, &full(&batch, ky, n));
    let mut shape = full(&batch, m, n);
    let t = xe.matmul(ye);
    if yv {
        shape.pop();
    }
    if xv {
        shape.remove(shape.len() - if yv { 1 } else { 2 });
    }
    Dev::new(t, shape)
}

pub(crate) fn gemm(a: &Args) -> Result<Val> {
    let (mut x, mut y) = (a.dev_input(0)?, a.dev_input(1)?);
    ensure!(
        x.rank() == 2 && y.rank() == 2,
        "Gemm of {:?} and {:?}",
        x.shape,
        y.shape
    );
    let tr = |d: Dev| -> Result<Dev> {
        let s = vec![d.shape[1], d.shape[0]];
        Dev::new(d.t.swap_dims(MAX_RANK - 2, MAX_RANK - 1), s)
    };
    if a.i("transA").unwrap_or(0) != 0 {
        x = tr(x)?;
    }
    if a.i("transB").unwrap_or(0) != 0 {
        y = tr(y)?;
    }
    let mut p = matmul2(x, y)?;
    p.t = p.t.mul_scalar(a.f("alpha").unwrap_or(1.0));
    if let Some(c) = a.opt(2) {
        let c = c.dev(a.dev)?;
        let out = broadcast(&p.shape, &c.shape)?;
        p = Dev::new(
            expand(&p, &out) + expand(&c, &out).mul_scalar(a.f("beta").unwrap_or(1.0)),
            out,
        )?;
    }
    Ok(Val::D(p))
}

/// The reduction axes (attribute before opset 18, or 13 for ReduceSum; input after).
fn reduce_axes(a: &Args, r: usize) -> Result<Vec<usize>> {
    let input_form = a.opset >= 18 || (a.node.op == "ReduceSum" && a.opset >= 13);
    let axes = if input_form {
        a.ints_input(1)?
    } else {
        a.ints("axes")
    };
    Ok(match axes {
        Some(v) if !v.is_empty() => {
            let mut v: Vec<usize> = v.iter().map(|&k| axis(k, r)).collect::<Result<_>>()?;
            v.sort_unstable();
            v.dedup();
            v
        }
        _ if a.i("noop_with_empty_axes").unwrap_or(0) != 0 => vec![],
        _ => (0..r).collect(),
    })
}

pub(crate) fn reduce(a: &Args) -> Result<Val> {
    let x = a.input(0)?;
    let r = x.shape().len();
    let axes = reduce_axes(a, r)?;
    let keep = a.i("keepdims").unwrap_or(1) != 0;
    let mut shape = x.shape().to_vec();
    for &k in &axes {
        shape[k] = 1;
    }
    let out_shape: Vec<usize> = if keep {
        shape.clone()
    } else {
        (0..r)
            .filter(|k| !axes.contains(k))
            .map(|k| x.shape()[k])
            .collect()
    };
    let op = a.node.op.as_str();
    if let Val::H(h) = x {
        let mut v = h.as_f();
        for &k in axes.iter().rev() {
            v = match op {
                "ReduceSum" => v.sum_axis(Axis(k)),
                "ReduceMean" => v.mean_axis(Axis(k)).ok_or_else(|| anyhow!("empty axis"))?,
                "ReduceProd" => v.fold_axis(Axis(k), 1.0, |p, q| p * q),
                "ReduceMax" => v.fold_axis(Axis(k), f32::NEG_INFINITY, |p, q| p.max(*q)),
                _ => v.fold_axis(Axis(k), f32::INFINITY, |p, q| p.min(*q)),
            };
        }
        let v = v.into_shape_with_order(IxDyn(&out_shape))?;
        return Ok(Val::H(match h {
            Host::I(_) => Host::I(v.mapv(|f| f as i64)),
            Host::F(_) => Host::F(v),
        }));
    }
    let d = x.dev(a.dev)?;
    let mut t = d.t.clone();
    for &k in &axes {
        let ax = d.axis(k);
        t = match op {
            "ReduceSum" => t.sum_dim(ax),
            "ReduceMean" => t.mean_dim(ax),
            "ReduceMax" => t.max_dim(ax),
            "ReduceMin" => t.min_dim(ax),
            "ReduceProd" => t.prod_dim(ax),
            _ => unreachable!(),
        };
    }
    Ok(Val::D(Dev::new(t, out_shape)?))
}

/// ArgMax, on the host (its indices carry no gradient).
pub fn argmax(a: &Args) -> Result<Val> {
    let h = a.input(0)?.host()?.as_f();
    let r = h.ndim();
    let ax = axis(a.i("axis").unwrap_or(0), r)?;
    let last = a.i("select_last_index").unwrap_or(0) != 0;
    let keep = a.i("keepdims").unwrap_or(1) != 0;
    let v = h.map_axis(Axis(ax), |lane| {
        let mut best = 0usize;
        for (i, &x) in lane.iter().enumerate() {
            if x > lane[best] || (last && x == lane[best]) {
                best = i;
            }
        }
        best as i64
    });
    Ok(Val::H(Host::I(if keep {
        v.insert_axis(Axis(ax))
    } else {
        v
    })))
}

/// TopK: values stay on the device (differentiable), indices on the host.
pub(crate) fn top_k(a: &Args) -> Result<Vec<Val>> {
    let x = a.dev_input(0)?;
    let k = if a.opset >= 10 {
        a.ints_input(1)?.and_then(|v| v.first().copied())
    } else {
        a.i("k")
    }
    .ok_or_else(|| anyhow!("TopK without k"))?;
    let ax = axis(a.i("axis").unwrap_or(-1), x.rank())?;
    let dim = x.shape[ax];
    ensure!(k >= 0 && k as usize <= dim, "k = {k} for axis length {dim}");
    let largest = a.i("largest").unwrap_or(1) != 0;
    let t = if largest {
        x.t.clone()
    } else {
        x.t.clone().neg()
    };
    let (vals, idx) = t.topk_with_indices(k as usize, x.axis(ax));
    let vals = if largest { vals } else { vals.neg() };
    let mut shape = x.shape.clone();
    shape[ax] = k as usize;
    let idx: Vec<i64> = idx
        .into_data()
        .convert::<i64>()
        .try_into_vec::<i64>()
        .map_err(|e| anyhow!("cannot read indices: {e:?}"))?;
    Ok(vec![
        Val::D(Dev::new(vals, shape.clone())?),
        Val::H(Host::I(ArrayD::from_shape_vec(IxDyn(&shape), idx)?)),
    ])
}

/// Pad, constant mode (the input form of opset 11+, the attribute form before).
pub fn pad(a: &Args) -> Result<Val> {
    let x = a.dev_input(0)?;
    let r = x.rank();
    ensure!(
        a.s("mode").unwrap_or("constant") == "constant",
        "Pad mode {} is not supported",
        a.s("mode").unwrap_or("")
    );
    let (pads, value) = if a.opset >= 11 {
        let v = match a.opt(2) {
            Some(c) if !c.shape().contains(&0) => {
                c.host()?.floats().first().copied().unwrap_or(0.0)
            }
            _ => 0.0,
        };
        (
            a.ints_input(1)?
                .ok_or_else(|| anyhow!("Pad without pads"))?,
            v,
        )
    } else {
        (
            a.ints("pads").ok_or_else(|| anyhow!("Pad without pads"))?,
            a.f("value").unwrap_or(0.0),
        )
    };
    let axes: Vec<usize> = match a.ints_input(3)? {
        Some(v) => v.iter().map(|&k| axis(k, r)).collect::<Result<_>>()?,
        None => (0..r).collect(),
    };
    ensure!(
        pads.len() == 2 * axes.len(),
        "pads {pads:?} for axes {axes:?}"
    );
    ensure!(
        pads.iter().all(|&p| p >= 0),
        "negative pads {pads:?} are not supported"
    );
    let mut pairs = [(0usize, 0usize); MAX_RANK];
    let mut shape = x.shape.clone();
    for (i, &k) in axes.iter().enumerate() {
        let (b, e) = (pads[i] as usize, pads[i + axes.len()] as usize);
        pairs[x.axis(k)] = (b, e);
        shape[k] += b + e;
    }
    Ok(Val::D(Dev {
        t: pad_constant(x.t, &pairs, value),
        shape,
    }))
}

/// NonMaxSuppression on the host: `[selected, 3]` rows of (batch, class, box index).
pub fn non_max_suppression(a: &Args) -> Result<Val> {
    let boxes = a.input(0)?.host()?.floats();
    let scores_h = a.input(1)?.host()?;
    let s = scores_h.shape().to_vec();
    ensure!(s.len() == 3, "scores of shape {s:?}, [B, C, N] expected");
    let (nb, nc, n) = (s[0], s[1], s[2]);
    ensure!(boxes.len() == nb * n * 4, "boxes do not match scores {s:?}");
    let scores = scores_h.floats();
    let max_out = a
        .ints_input(2)?
        .and_then(|v| v.first().copied())
        .unwrap_or(0)
        .max(0) as usize;
    let scalar = |k: usize, d: f32| -> Result<f32> {
        Ok(match a.opt(k) {
            Some(v) => v.host()?.floats().first().copied().unwrap_or(d),
            None => d,
        })
    };
    let iou = scalar(3, 0.0)?;
    let min_score = scalar(4, f32::NEG_INFINITY)?;
    let center = a.i("center_point_box").unwrap_or(0) != 0;
    let mut rows = Vec::new();
    for b in 0..nb {
        let bx: Vec<[f32; 4]> = (0..n)
            .map(|i| {
                let v = &boxes[(b * n + i) * 4..(b * n + i) * 4 + 4];
                if center {
                    let (cx, cy, w, h) = (v[0], v[1], v[2], v[3]);
                    [cy - h / 2.0, cx - w / 2.0, cy + h / 2.0, cx + w / 2.0]
                } else {
                    [
                        v[0].min(v[2]),
                        v[1].min(v[3]),
                        v[0].max(v[2]),
                        v[1].max(v[3]),
                    ]
                }
            })
            .collect();
        for c in 0..nc {
            let sc = &scores[(b * nc + c) * n..(b * nc + c + 1) * n];
            for i in nms(&bx, sc, max_out, iou as f64, min_score as f64) {
                rows.extend([b as i64, c as i64, i as i64]);
            }
        }
    }
    let k = rows.len() / 3;
    Ok(Val::H(Host::I(ArrayD::from_shape_vec(
        IxDyn(&[k, 3]),
        rows,
    )?)))
}

#[cfg(test)]
mod tests {
    //! Backward passes the ops above rely on (Resize/Gather/Slice by `select`, MaxPool).
    use burn::tensor::module::max_pool2d;
    use burn::tensor::ops::MaxPoolOptions;
    use burn::tensor::{Device, Int, Tensor, TensorData};

    fn dev() -> Device {
        Device::autodiff(Device::from(burn::backend::FlexDevice))
    }

    /// The gradient of `y.sum()` with respect to `x`, on the host.
    fn grad_of<const D: usize, const E: usize>(x: &Tensor<D>, y: Tensor<E>) -> Vec<f32> {
        let g = y.sum().backward();
        x.grad(&g)
            .unwrap()
            .to_data()
            .convert::<f32>()
            .try_into_vec()
            .unwrap()
    }

    #[test]
    fn select_with_repeated_indices_accumulates_gradients() {
        let d = dev();
        let x = Tensor::<2>::from_data(TensorData::new(vec![1.0f32, 2.0, 3.0], [1, 3]), &d)
            .require_grad();
        let idx = Tensor::<1, Int>::from_data(TensorData::new(vec![0i64, 0, 1, 1, 2, 2], [6]), &d);
        assert_eq!(grad_of(&x, x.clone().select(1, idx)), vec![2.0, 2.0, 2.0]);
    }

    #[test]
    fn overlapping_max_pool_windows_add_their_gradients() {
        // 5x5 distinct values; windows 3x3, stride 2, pad 1 overlap on rows/cols 2.
        let v: Vec<f32> = (0..25).map(|i| ((i * 7) % 25) as f32).collect();
        let x =
            Tensor::<4>::from_data(TensorData::new(v.clone(), [1, 1, 5, 5]), &dev()).require_grad();
        let o = MaxPoolOptions::new([3, 3])
            .with_stride([2, 2])
            .with_padding_pairs([(1, 1), (1, 1)]);
        let got = grad_of(&x, max_pool2d(x.clone(), o));
        let mut want = vec![0.0f32; 25];
        for oy in 0..3i32 {
            for ox in 0..3i32 {
                let mut best = (f32::MIN, 0usize);
                for ky in 0..3 {
                    for kx in 0..3 {
                        let (iy, ix) = (oy * 2 - 1 + ky, ox * 2 - 1 + kx);
                        if (0..5).contains(&iy) && (0..5).contains(&ix) {
                            let k = (iy * 5 + ix) as usize;
                            if v[k] > best.0 {
                                best = (v[k], k);
                            }
                        }
                    }
                }
                want[best.1] += 1.0;
            }
        }
        assert_eq!(got, want);
    }
}
