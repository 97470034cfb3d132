//! torchvision's `GeneralizedRCNNTransform` at inference: normalise with the ImageNet mean/std,
//! resize so the short side is `min_size` (the long side at most `max_size`) with PyTorch's
//! bilinear `interpolate` (align_corners=False, recomputed scale factor), and zero-pad the
//! batch to a multiple of 32. Differentiable: the resize is gathers and weighted sums.

use burn::tensor::{Int, Tensor, TensorData};

pub(crate) const MEAN: [f32; 3] = [0.485, 0.456, 0.406];
pub(crate) const STD: [f32; 3] = [0.229, 0.224, 0.225];
const SIZE_DIVISIBLE: usize = 32;

/// Size bookkeeping of one batch (all images share one size).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Geometry {
    /// `(h, w)` of the input images.
    pub original: (usize, usize),
    /// `(h, w)` after the resize (before padding): torchvision's `image_sizes`.
    pub resized: (usize, usize),
    /// `(h, w)` of the padded network input.
    pub padded: (usize, usize),
}

/// The resized size torchvision computes (`floor(side · scale)`, scale in f64).
pub fn resized_size(h: usize, w: usize, min_size: usize, max_size: usize) -> (usize, usize) {
    let (lo, hi) = (h.min(w) as f64, h.max(w) as f64);
    let scale = (min_size as f64 / lo).min(max_size as f64 / hi);
    (
        ((h as f64 * scale).floor() as usize).max(1),
        ((w as f64 * scale).floor() as usize).max(1),
    )
}

/// Source indices and weights of one axis of PyTorch's bilinear resize (align_corners=False,
/// scale `in / out` in f32, negative source coordinates clamped to 0).
pub(crate) fn bilinear_table(
    input: usize,
    output: usize,
) -> (Vec<i64>, Vec<i64>, Vec<f32>, Vec<f32>) {
    let scale = input as f32 / output as f32;
    let (mut i0, mut i1, mut w0, mut w1) = (vec![], vec![], vec![], vec![]);
    for d in 0..output {
        let src = scale * (d as f32 + 0.5) - 0.5;
        let src = if src < 0.0 { 0.0 } else { src };
        let idx = (src.floor() as i64).min(input as i64 - 1);
        let lambda = (src - idx as f32).clamp(0.0, 1.0);
        let off = if idx < input as i64 - 1 { 1 } else { 0 };
        i0.push(idx);
        i1.push(idx + off);
        w0.push(1.0 - lambda);
        w1.push(lambda);
    }
    (i0, i1, w0, w1)
}

fn resize_axis(x: Tensor<4>, axis: usize, out: usize) -> Tensor<4> {
    let input = x.dims()[axis];
    if input == out {
        return x;
    }
    let dev = x.device();
    let (i0, i1, w0, w1) = bilinear_table(input, out);
    let idx = |v: Vec<i64>| Tensor::<1, Int>::from_data(TensorData::new(v, [out]), &dev);
    let mut shape = [1usize; 4];
    shape[axis] = out;
    let w = |v: Vec<f32>| Tensor::<1>::from_data(TensorData::new(v, [out]), &dev).reshape(shape);
    x.clone().select(axis, idx(i0)) * w(w0) + x.select(axis, idx(i1)) * w(w1)
}

/// `[B, 3, H, W]` in [0, 1] → the padded, normalised network input and its geometry.
pub fn prepare(images: Tensor<4>, min_size: usize, max_size: usize) -> (Tensor<4>, Geometry) {
    let [b, _, h, w] = images.dims();
    let dev = images.device();
    let mean =
        Tensor::<1>::from_data(TensorData::new(MEAN.to_vec(), [3]), &dev).reshape([1, 3, 1, 1]);
    let std =
        Tensor::<1>::from_data(TensorData::new(STD.to_vec(), [3]), &dev).reshape([1, 3, 1, 1]);
    let x = (images - mean) / std;
    let (rh, rw) = resized_size(h, w, min_size, max_size);
    // PyTorch evaluates the height taps of the width-interpolated rows: width first.
    let x = resize_axis(x, 3, rw);
    let x = resize_axis(x, 2, rh);
    let ph = rh.div_ceil(SIZE_DIVISIBLE) * SIZE_DIVISIBLE;
    let pw = rw.div_ceil(SIZE_DIVISIBLE) * SIZE_DIVISIBLE;
    let mut x = x;
    if pw > rw {
        x = Tensor::cat(vec![x, Tensor::zeros([b, 3, rh, pw - rw], &dev)], 3);
    }
    if ph > rh {
        x = Tensor::cat(vec![x, Tensor::zeros([b, 3, ph - rh, pw], &dev)], 2);
    }
    (
        x,
        Geometry {
            original: (h, w),
            resized: (rh, rw),
            padded: (ph, pw),
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_tables_follow_torchvision() {
        assert_eq!(resized_size(300, 451, 320, 640), (320, 481));
        assert_eq!(resized_size(512, 512, 320, 640), (320, 320));
        assert_eq!(resized_size(100, 1000, 320, 640), (64, 640));
        // Upscale 2 -> 4: src = -.25 (clamped to 0), .25, .75, 1.25.
        let (i0, i1, w0, w1) = bilinear_table(2, 4);
        assert_eq!(i0, vec![0, 0, 0, 1]);
        assert_eq!(i1, vec![1, 1, 1, 1]);
        assert_eq!(w1, vec![0.0, 0.25, 0.75, 0.25]);
        assert_eq!(w0, vec![1.0, 0.75, 0.25, 0.75]);
    }
}
