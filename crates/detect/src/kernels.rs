//! What both graph executors (TFJS and ONNX) compute the same way: numpy broadcasting of two
//! shapes ([`broadcast_shape`]), the taps of a sliding window as strided views ([`taps`]) and
//! im2col + one 1×1 convolution for the stems, layers with few input channels
//! ([`conv_im2col`]), which burn's `conv2d` (Flex) runs tap by tap over the output. Same sums in
//! another order: agrees with `conv2d` to float rounding (tested). Not here: layouts or
//! attribute parsing (the executors' own).

use crate::conv::conv2d;
use anyhow::{bail, Result};
use burn::tensor::ops::ConvOptions;
use burn::tensor::Tensor;

/// numpy's broadcast of two shapes (aligned at the last axis; a 1 stretches).
/// `x` with `pairs[i]` = (before, after) values of `value` added along its last `pairs.len()`
/// axes, as burn's `pad` with `PadMode::Constant`. burn builds that constant on the host on
/// backends without a native `full` (libtorch: a host buffer the size of the output, then a
/// copy), which was most of NanoDet's pads there; zeros, a scalar add and a slice assignment stay
/// on the device. The gradient is the slice of the output's.
pub fn pad_constant<const D: usize>(
    x: Tensor<D>,
    pairs: &[(usize, usize)],
    value: f32,
) -> Tensor<D> {
    assert!(
        pairs.len() <= D,
        "{} padding pairs for a rank-{D} tensor",
        pairs.len()
    );
    let dims = x.dims();
    let first = D - pairs.len();
    let (mut out, mut centre) = (dims, dims.map(|d| 0..d));
    for (i, &(before, after)) in pairs.iter().enumerate() {
        out[first + i] += before + after;
        centre[first + i] = before..before + dims[first + i];
    }
    if out == dims {
        return x;
    }
    let base = Tensor::<D>::zeros(out, &x.device());
    let base = match value == 0.0 {
        true => base,
        false => base.add_scalar(value),
    };
    base.slice_assign(centre, x)
}

pub fn broadcast_shape(a: &[usize], b: &[usize]) -> Result<Vec<usize>> {
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

/// The `k[0]·k[1]` taps of a sliding window over NCHW `x` zero-padded by `ph`, `pw`
/// (row-major tap order), each of the output's spatial size `out`, as views with unit steps:
/// the padded input is reshaped to `[n, c, rows, stride₀, cols, stride₁]`, so a tap is one phase
/// of each stride, `[n, c, oh, 1, ow, 1]`. (Strided slices would do the same, but a strided
/// slice's gradient is an index-put on burn's LibTorch backend: slow, and it fails on a
/// non-contiguous gradient.) Only the rows and columns a tap reads are padded.
pub fn taps(
    x: Tensor<4>,
    k: [usize; 2],
    stride: [usize; 2],
    dil: [usize; 2],
    [ph, pw]: [(usize, usize); 2],
    [oh, ow]: [usize; 2],
) -> Vec<Tensor<6>> {
    let [n, c, h, w] = x.dims();
    // The extent read along an axis, rounded up to whole strides; zeros added at the end where
    // the padded input is shorter, rows cut where it is longer (no tap reads them).
    let fit = |len: usize, (before, _): (usize, usize), k: usize, d: usize, o: usize, s: usize| {
        let full = ((k - 1) * d + (o - 1) * s + 1).div_ceil(s) * s;
        (full, full.saturating_sub(len + before))
    };
    let (fh, eh) = fit(h, ph, k[0], dil[0], oh, stride[0]);
    let (fw, ew) = fit(w, pw, k[1], dil[1], ow, stride[1]);
    let xp = match (ph.0, eh, pw.0, ew) {
        (0, 0, 0, 0) => x,
        _ => pad_constant(x, &[(ph.0, eh), (pw.0, ew)], 0.0),
    };
    let [_, _, hp, wp] = xp.dims();
    let xp = match (hp, wp) == (fh, fw) {
        true => xp,
        false => xp.slice([0..n, 0..c, 0..fh, 0..fw]),
    };
    let [sy, sx] = stride;
    let grid: Tensor<6> = xp.reshape([n, c, fh / sy, sy, fw / sx, sx]);
    let mut out = Vec::with_capacity(k[0] * k[1]);
    for ky in 0..k[0] {
        let (qy, py) = ((ky * dil[0]) / sy, (ky * dil[0]) % sy);
        for kx in 0..k[1] {
            let (qx, px) = ((kx * dil[1]) / sx, (kx * dil[1]) % sx);
            out.push(grid.clone().slice([
                0..n,
                0..c,
                qy..qy + oh,
                py..py + 1,
                qx..qx + ow,
                px..px + 1,
            ]));
        }
    }
    out
}

/// Dense convolutions with at most this many input channels (the RGB stem) run as im2col + gemm.
pub(crate) const IM2COL_MAX_CHANNELS: usize = 4;

/// Output size of a convolution along one axis, or None where the padded input is shorter than
/// the dilated kernel.
pub(crate) fn conv_out(
    input: usize,
    (b, e): (usize, usize),
    k: usize,
    stride: usize,
    dil: usize,
) -> Option<usize> {
    let span = dil * (k - 1) + 1;
    (input + b + e).checked_sub(span).map(|d| d / stride + 1)
}

/// A dense convolution of an input with few channels as im2col + a 1×1 convolution (one gemm):
/// the `kh·kw` taps are strided views of the zero-padded input, stacked along the channels
/// (tap-major). Flex runs such a layer tap by tap over the output, which does not vectorise
/// with stride 2: CenterNet's 3→16 stem took 11.8 ms that way and takes 4–5 ms this way.
/// Same sums, in another order: agrees with `conv2d` to float rounding (tested). None where the
/// window does not fit the padded input (the caller then leaves the case to `conv2d`).
pub(crate) fn conv_im2col(
    x: Tensor<4>,
    w: Tensor<4>,
    bias: Option<Tensor<1>>,
    stride: [usize; 2],
    dil: [usize; 2],
    [ph, pw]: [(usize, usize); 2],
) -> Option<Tensor<4>> {
    let [_, c, h, wd] = x.dims();
    let [o, _, kh, kw] = w.dims();
    let oh = conv_out(h, ph, kh, stride[0], dil[0])?;
    let ow = conv_out(wd, pw, kw, stride[1], dil[1])?;
    let n = x.dims()[0];
    let cols = taps(x, [kh, kw], stride, dil, [ph, pw], [oh, ow]);
    // channel (ky·kw + kx)·c + ci
    let cols: Tensor<4> = Tensor::cat(cols, 1).reshape([n, kh * kw * c, oh, ow]);
    let w = w.permute([0, 2, 3, 1]).reshape([o, kh * kw * c, 1, 1]);
    Some(conv2d(
        cols,
        w,
        bias,
        ConvOptions::new([1, 1], [0, 0], [1, 1], 1),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::module::conv2d;

    /// The im2col path computes the same convolution as burn's `conv2d`: stride 1 and 2,
    /// asymmetric SAME padding, dilation, a bias.
    #[test]
    fn im2col_conv_equals_conv2d() {
        use burn::tensor::{Device, TensorData};
        use rand::{Rng, SeedableRng};
        let dev = Device::from(burn::backend::FlexDevice);
        // Seeded host values (the device's own generator is shared by parallel tests).
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut uniform = |shape: Vec<usize>| {
            let n = shape.iter().product();
            let v: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0f32..1.0)).collect();
            TensorData::new(v, shape)
        };
        for (c, k, stride, dil, pad) in [
            (3, 3, 2, 1, [(0, 1), (0, 1)]),
            (3, 3, 1, 1, [(1, 1), (1, 1)]),
            (2, 5, 2, 1, [(1, 2), (2, 1)]),
            (4, 3, 1, 2, [(2, 2), (0, 0)]),
            (1, 2, 3, 1, [(0, 0), (0, 0)]),
            // Rows and columns past the last window (cut before the stride reshape).
            (2, 2, 2, 1, [(0, 0), (0, 0)]),
            (3, 1, 2, 1, [(0, 0), (0, 0)]),
        ] {
            let x = Tensor::<4>::from_data(uniform(vec![2, c, 17, 12]), &dev);
            let w = Tensor::<4>::from_data(uniform(vec![6, c, k, k]), &dev);
            let b = Tensor::<1>::from_data(uniform(vec![6]), &dev);
            let opts = ConvOptions::new_with_padding([stride; 2], pad, [dil; 2], 1);
            let want = conv2d(x.clone(), w.clone(), Some(b.clone()), opts);
            for (name, got) in [(
                "im2col",
                conv_im2col(
                    x.clone(),
                    w.clone(),
                    Some(b.clone()),
                    [stride; 2],
                    [dil; 2],
                    pad,
                ),
            )] {
                let got = got.unwrap();
                assert_eq!(
                    got.dims(),
                    want.dims(),
                    "{name}: c {c} k {k} s {stride} d {dil}"
                );
                let err = (got - want.clone()).abs().max().into_scalar::<f32>();
                assert!(
                    err < 1e-5,
                    "{name}: c {c} k {k} s {stride} d {dil}: max error {err}"
                );
            }
        }
        // A window larger than the padded input: no im2col (the caller falls back to conv2d).
        let x = Tensor::<4>::zeros([1, 3, 2, 2], &dev);
        let w = Tensor::<4>::zeros([4, 3, 3, 3], &dev);
        assert!(conv_im2col(x, w, None, [1, 1], [1, 1], [(0, 0), (0, 0)]).is_none());
    }
}
