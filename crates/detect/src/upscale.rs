//! Integer bilinear up-scaling (the detectors' 2× feature up-sampling) on the backend's own
//! interpolation kernel where it has a fast one: libtorch's `upsample_bilinear2d` runs it in one
//! pass forward and one backward, keeping channels-last memory (`detect::libtorch`), where the
//! phase path of [`crate::preprocess`] (shifted slices, lerps, an interleave) takes several passes
//! and hands the next convolution an NCHW tensor to convert. Flex and wgpu keep the phase path
//! ([`UpscaleKernels::cac_upscales_natively`] is false there), so their values are as before.
//!
//! TensorFlow's two up-scaling formulas are interpolation's own for a power-of-two factor `k`
//! (the scales `1/k` are exact in f32, so the source positions are too):
//! - legacy (neither half-pixel centres nor aligned corners), source `r/k`: aligned corners to
//!   `k(n−1) + 1` samples (scale `(n−1)/(k(n−1)) = 1/k`), then the last sample repeated `k − 1`
//!   times (the formula's clamp at the far end);
//! - half-pixel centres, source `(r + ½)/k − ½` clamped at 0: half-pixel interpolation to `k n`.
//!
//! The values are the phase path's up to the order of the lerps' roundings (a few ulps).

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{unary, Backward, Ops};
use burn::backend::tensor::FloatTensor;
use burn::backend::TensorMetadata;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex};
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Shape, Slice, Tensor};

/// Which of TensorFlow's formulas an up-scaling follows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Formula {
    /// Neither half-pixel centres nor aligned corners (CenterNet's head).
    Legacy,
    /// Half-pixel centres (NanoDet's feature pyramid).
    HalfPixel,
}

impl Formula {
    /// The formula of a TensorFlow resize's flags, where it is one of the two.
    pub(crate) fn of(align_corners: bool, half_pixel_centers: bool) -> Option<Formula> {
        match (align_corners, half_pixel_centers) {
            (false, false) => Some(Formula::Legacy),
            (false, true) => Some(Formula::HalfPixel),
            _ => None,
        }
    }

    /// The interpolation's output size for an input of `n` samples up-scaled by `k`.
    fn samples(self, n: usize, k: usize) -> usize {
        match self {
            Formula::Legacy => k * (n - 1) + 1,
            Formula::HalfPixel => k * n,
        }
    }

    fn options(self) -> InterpolateOptions {
        InterpolateOptions::new(InterpolateMode::Bilinear)
            .with_align_corners(self == Formula::Legacy)
    }
}

/// The factors `[kh, kw]` when `[h, w] → [out_h, out_w]` is a power-of-two up-scaling on each
/// axis (1 allowed) that interpolation reproduces exactly, and the backend of `x` runs it on its
/// own kernel ([`UpscaleKernels::cac_upscales_natively`]); `None` otherwise.
pub fn native_factors(x: &Tensor<4>, out_h: usize, out_w: usize) -> Option<[usize; 2]> {
    let [_, _, h, w] = x.dims();
    let k = factors([h, w], [out_h, out_w])?;
    let x = x.clone().into_dispatch();
    <Dispatch as UpscaleKernels>::cac_upscales_natively(&x).then_some(k)
}

/// The power-of-two factors of an up-scaling of inputs of two or more samples per axis (1 on
/// one axis allowed, not on both).
fn factors(input: [usize; 2], out: [usize; 2]) -> Option<[usize; 2]> {
    let factor = |n: usize, out: usize| {
        (n >= 2 && out % n == 0 && (out / n).is_power_of_two()).then_some(out / n)
    };
    let k = [factor(input[0], out[0])?, factor(input[1], out[1])?];
    (k != [1, 1]).then_some(k)
}

/// `x` ([N, C, H, W]) up-scaled by `k` = [kh, kw] with `formula`, on the backend's
/// interpolation kernel; its gradient is that kernel's backward.
pub(crate) fn upscale(x: Tensor<4>, k: [usize; 2], formula: Formula) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as UpscaleKernels>::cac_upscale(
        x.into_dispatch(),
        k,
        formula == Formula::Legacy,
    ))
}

/// Up-scaling per backend. The default bodies are burn's `interpolate` (and its backward) with
/// the legacy formula's end samples as slices: a reference that is correct on every backend
/// (tested on Flex against the phase path); they run only where a backend says it up-scales
/// natively without overriding them, which none does today.
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "gpu"), LibTorch: cfg(feature = "tch"))]
pub(crate) trait UpscaleKernels: Backend {
    /// Whether the detectors' up-scalings should run here rather than on the phase path.
    fn cac_upscales_natively(_x: &FloatTensor<Self>) -> bool {
        false
    }
    /// `x` up-scaled by `k` (`legacy`: TensorFlow's legacy formula, else half-pixel centres).
    fn cac_upscale(x: FloatTensor<Self>, k: [usize; 2], legacy: bool) -> FloatTensor<Self> {
        let formula = formula(legacy);
        let [_, _, h, w] = x.shape().dims();
        let size = interpolated([h, w], k, legacy);
        let y = Self::interpolate(x, size, formula.options());
        match formula {
            Formula::Legacy => repeat_last::<Self>(repeat_last::<Self>(y, 2, k[0]), 3, k[1]),
            Formula::HalfPixel => y,
        }
    }
    /// The input gradient of [`UpscaleKernels::cac_upscale`] for an input of shape `input`.
    fn cac_upscale_backward(
        g: FloatTensor<Self>,
        input: [usize; 4],
        k: [usize; 2],
        legacy: bool,
    ) -> FloatTensor<Self> {
        let formula = formula(legacy);
        let size = interpolated([input[2], input[3]], k, legacy);
        let g = match formula {
            Formula::Legacy => sum_last::<Self>(sum_last::<Self>(g, 2, size[0]), 3, size[1]),
            Formula::HalfPixel => g,
        };
        // burn's interpolate_backward reads only the input's shape.
        let like = Self::float_zeros(Shape::from(input), &g.device(), g.dtype().into());
        Self::interpolate_backward(like, g, size, formula.options())
    }
}

/// The size `[h, w]` is interpolated to for an up-scaling by `k` (the formula's `samples`),
/// for the default bodies and the backends' own kernels alike.
pub(crate) fn interpolated([h, w]: [usize; 2], k: [usize; 2], legacy: bool) -> [usize; 2] {
    let formula = formula(legacy);
    [formula.samples(h, k[0]), formula.samples(w, k[1])]
}

fn formula(legacy: bool) -> Formula {
    match legacy {
        true => Formula::Legacy,
        false => Formula::HalfPixel,
    }
}

/// `y` with its last sample along `axis` repeated so that the axis grows by `k − 1`.
fn repeat_last<B: Backend>(y: FloatTensor<B>, axis: usize, k: usize) -> FloatTensor<B> {
    if k == 1 {
        return y;
    }
    let n = y.shape()[axis];
    let last = B::float_slice(y.clone(), &along(4, axis, n - 1..n));
    B::float_cat(vec![y, B::float_repeat_dim(last, axis, k - 1)], axis)
}

/// The adjoint of [`repeat_last`]: the first `keep` samples along `axis`, the last of them
/// carrying the sum of the gradient from there to the end.
fn sum_last<B: Backend>(g: FloatTensor<B>, axis: usize, keep: usize) -> FloatTensor<B> {
    let n = g.shape()[axis];
    if n == keep {
        return g;
    }
    let head = B::float_slice(g.clone(), &along(4, axis, 0..keep - 1));
    let tail = B::float_sum_dim(B::float_slice(g, &along(4, axis, keep - 1..n)), axis);
    B::float_cat(vec![head, tail], axis)
}

/// Full slices of a rank-`rank` tensor except `range` along `axis`.
fn along(rank: usize, axis: usize, range: std::ops::Range<usize>) -> Vec<Slice> {
    (0..rank)
        .map(|a| match a == axis {
            true => Slice::from(range.clone()),
            false => Slice::from(..),
        })
        .collect()
}

impl UpscaleKernels for Flex {}

#[cfg(feature = "gpu")]
impl UpscaleKernels for burn::backend::Cube {}

/// The up-scaling as an autodiff op: the gradient is the kernel's backward.
#[derive(Debug)]
struct Upscale {
    input: [usize; 4],
    k: [usize; 2],
    legacy: bool,
}

impl<B: Backend + UpscaleKernels> Backward<B, 1> for Upscale {
    type State = ();

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        unary::<B, _>(ops.parents, ops.node, grads, |g| {
            B::cac_upscale_backward(g, self.input, self.k, self.legacy)
        });
    }
}

impl<B: Backend + UpscaleKernels, C: CheckpointStrategy> UpscaleKernels for Autodiff<B, C> {
    fn cac_upscales_natively(x: &FloatTensor<Self>) -> bool {
        B::cac_upscales_natively(x.primitive())
    }
    fn cac_upscale(x: FloatTensor<Self>, k: [usize; 2], legacy: bool) -> FloatTensor<Self> {
        let input = x.shape().dims();
        let op = Upscale { input, k, legacy };
        let prep = op.prepare::<C>([x.node()]).compute_bound();
        prep.stateless(B::cac_upscale(x.into_primitive(), k, legacy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::preprocess::resize_bilinear;
    use crate::testing::seeded;
    use burn::tensor::Device;

    fn max_abs(a: Tensor<4>, b: Tensor<4>) -> f32 {
        assert_eq!(a.dims(), b.dims());
        (a - b).abs().max().into_scalar()
    }

    /// Interpolation with the mapped formula gives the phase path's values and input gradients
    /// (to rounding), for both formulas, unequal factors, a factor of 1 and the smallest inputs.
    #[test]
    fn interpolation_reproduces_both_tensorflow_formulas_and_their_gradients() {
        let dev = Device::autodiff(Device::from(burn::backend::FlexDevice));
        let cases = [
            ([1, 3, 5, 4], [2, 2]),
            ([2, 2, 2, 7], [4, 2]),
            ([1, 4, 6, 3], [1, 8]),
        ];
        for (seed, (dims, k)) in cases.into_iter().enumerate() {
            for formula in [Formula::Legacy, Formula::HalfPixel] {
                let half = formula == Formula::HalfPixel;
                let x = seeded(dims, seed as u64, 2.0, &dev).require_grad();
                let (oh, ow) = (dims[2] * k[0], dims[3] * k[1]);
                let want = resize_bilinear(x.clone(), 2, 3, oh, ow, false, half);
                let got = Tensor::from_dispatch(<Dispatch as UpscaleKernels>::cac_upscale(
                    x.clone().into_dispatch(),
                    k,
                    formula == Formula::Legacy,
                ));
                let what = format!("{dims:?} k {k:?} {formula:?}");
                assert!(max_abs(got.clone(), want.clone()) < 1e-6, "values, {what}");
                let up = seeded([dims[0], dims[1], oh, ow], 99, 2.0, &dev);
                let gw = x.grad(&(want * up.clone()).sum().backward()).unwrap();
                let gg = x.grad(&(got * up).sum().backward()).unwrap();
                let scale: f32 = gw.clone().abs().max().into_scalar();
                let err: f32 = (gg - gw).abs().max().into_scalar();
                assert!(err <= 1e-5 * scale, "gradient {err} of {scale}, {what}");
            }
        }
    }

    #[test]
    fn only_power_of_two_upscalings_of_two_or_more_samples_qualify() {
        assert_eq!(factors([16, 32], [32, 64]), Some([2, 2]));
        assert_eq!(factors([16, 32], [16, 256]), Some([1, 8]));
        assert_eq!(factors([16, 16], [16, 16]), None); // no up-scaling
        assert_eq!(factors([16, 16], [48, 32]), None); // 3 is not a power of two
        assert_eq!(factors([16, 16], [24, 32]), None); // not a multiple
        assert_eq!(factors([16, 16], [8, 32]), None); // a down-scaling
        assert_eq!(factors([1, 16], [2, 32]), None); // one sample: the phase path's clamp

        // Flex keeps the phase path whatever the shape.
        let dev = Device::from(burn::backend::FlexDevice);
        assert_eq!(
            native_factors(&seeded([1, 1, 4, 4], 0, 2.0, &dev), 8, 8),
            None
        );
        assert_eq!(Formula::of(true, false), None);
        assert_eq!(Formula::of(false, false), Some(Formula::Legacy));
        assert_eq!(Formula::of(false, true), Some(Formula::HalfPixel));
    }
}
