//! The kernels on burn's LibTorch backend (the `tch` fast path): libtorch's own fused
//! activations (sigmoid, SiLU, leaky ReLU, hard swish, ReLU and ReLU6: one ATen call forward and
//! one backward, as PyTorch's autograd runs them), its convolution (oneDNN forward; the input
//! gradient as burn's transposed convolution, which libtorch also runs on oneDNN) in PyTorch's
//! channels-last memory format, ATen's constant pad, which keeps that format, and its bilinear
//! up-sampling for the detectors' feature pyramids (`crate::upscale`), which keeps it too.
//!
//! Built only with the `tch` feature. The autodiff implementations of [`ActivationKernels`],
//! [`ConvKernels`], [`PadKernels`] and [`UpscaleKernels`] (in their modules) call these for the inner backend, so a
//! gradient through libtorch costs what it costs in PyTorch.

// burn 0.22 marks its LibTorch backend deprecated (it steers users to CubeCL backends, whose CPU
// and CUDA builds download LLVM at build time and fail offline): chosen here all the same, as the
// one backend on PyTorch's own kernels (docs/detectors.md, "The libtorch fast path").
#![allow(deprecated)]

use crate::activation::ActivationKernels;
use crate::broadcast::BroadcastKernels;
use crate::conv::ConvKernels;
use crate::kernels::PadKernels;
use crate::upscale::{interpolated, UpscaleKernels};
use burn::backend::libtorch::TchTensor;
use burn::backend::ops::ModuleOps;
use burn::backend::LibTorch;
use burn::backend::TensorMetadata;
use burn::tensor::ops::ConvOptions;

impl ActivationKernels for LibTorch {
    fn act_sigmoid(x: TchTensor) -> TchTensor {
        TchTensor::new(x.tensor.sigmoid())
    }
    fn act_sigmoid_backward(x: TchTensor, g: TchTensor) -> TchTensor {
        let s = x.tensor.sigmoid();
        TchTensor::new(tch::Tensor::sigmoid_backward(&g.tensor, &s))
    }
    fn act_silu(x: TchTensor) -> TchTensor {
        TchTensor::new(x.tensor.silu())
    }
    fn act_silu_backward(x: TchTensor, g: TchTensor) -> TchTensor {
        // ATen's `silu_backward(grad_output, self)`: the derivative from the input, fused.
        TchTensor::new(x.tensor.silu_backward(&g.tensor))
    }
    fn act_leaky_relu(x: TchTensor, slope: f32) -> TchTensor {
        // tch exposes ATen's `leaky_relu` only at its default slope; its backward with the input
        // as the incoming gradient is the same function (`x > 0 ? x : slope · x`) in one pass.
        TchTensor::new(x.tensor.leaky_relu_backward(&x.tensor, slope as f64, false))
    }
    fn act_leaky_relu_backward(x: TchTensor, g: TchTensor, slope: f32) -> TchTensor {
        TchTensor::new(x.tensor.leaky_relu_backward(&g.tensor, slope as f64, false))
    }
    fn act_hard_swish(x: TchTensor, scale: f32) -> TchTensor {
        let y = x.tensor.hardswish();
        TchTensor::new(match scale == 1.0 {
            true => y,
            false => y * scale as f64,
        })
    }
    fn act_hard_swish_backward(x: TchTensor, g: TchTensor, scale: f32) -> TchTensor {
        let g = match scale == 1.0 {
            true => g.tensor,
            false => g.tensor * scale as f64,
        };
        TchTensor::new(x.tensor.hardswish_backward(&g))
    }
    fn act_relu_to(x: TchTensor, hi: f32) -> TchTensor {
        TchTensor::new(match hi.is_finite() {
            true => x.tensor.clamp(0.0, hi as f64),
            false => x.tensor.relu(),
        })
    }
    fn act_relu_to_backward(x: TchTensor, g: TchTensor, hi: f32) -> TchTensor {
        TchTensor::new(match hi.is_finite() {
            true => x.tensor.hardtanh_backward(&g.tensor, 0.0, hi as f64),
            false => x.tensor.threshold_backward(&g.tensor, 0.0),
        })
    }
}

/// burn's own convolution and gradients (libtorch's `conv2d`, the input gradient as a transposed
/// convolution), except for an asymmetrically padded input (TensorFlow's SAME padding at stride
/// 2: CenterNet's and NanoDet's downsampling layers): burn pads it with a constant it builds on
/// the host on this backend (a buffer the size of the padded input, filled and copied on every
/// call, forward and backward); here ATen's `constant_pad_nd` pads it, and the input gradient is
/// cropped back.
impl ConvKernels for LibTorch {
    fn cac_conv2d(x: TchTensor, w: TchTensor, options: ConvOptions<2>) -> TchTensor {
        let (x, options) = pad_asymmetric(x, options);
        LibTorch::conv2d(channels_last(x), w, None, options)
    }
    fn cac_conv2d_x_backward(
        x: TchTensor,
        w: TchTensor,
        g: TchTensor,
        options: ConvOptions<2>,
    ) -> TchTensor {
        let g = channels_last(g);
        if !options.is_asymmetric() {
            return LibTorch::conv2d_x_backward(x, w, g, options);
        }
        let [n, c, h, wd] = x.shape().dims();
        let [(top, bottom), (left, right)] = options.padding;
        // burn's input gradient reads only the input's shape: the padded input's, as a
        // zero-stride view of one zero instead of a padded copy.
        let padded = [n, c, h + top + bottom, wd + left + right].map(|d| d as i64);
        let zero = tch::Tensor::zeros([1], (x.tensor.kind(), x.tensor.device()));
        let like = TchTensor::new(zero.expand(padded, false));
        let options = ConvOptions::new(options.stride, [0, 0], options.dilation, options.groups);
        let grad = LibTorch::conv2d_x_backward(like, w, g, options).tensor;
        TchTensor::new(
            grad.narrow(2, top as i64, h as i64)
                .narrow(3, left as i64, wd as i64),
        )
    }
    fn cac_conv2d_weight_backward(
        x: TchTensor,
        w: TchTensor,
        g: TchTensor,
        options: ConvOptions<2>,
    ) -> TchTensor {
        let (x, options) = pad_asymmetric(x, options);
        LibTorch::conv2d_weight_backward(x, w, g, options)
    }
}

/// `x` padded by `options.padding` with zeros on the device, and the options without padding;
/// unchanged where the padding is symmetric (the convolution pads that itself).
fn pad_asymmetric(x: TchTensor, options: ConvOptions<2>) -> (TchTensor, ConvOptions<2>) {
    if !options.is_asymmetric() {
        return (x, options);
    }
    let [(top, bottom), (left, right)] = options.padding;
    let pad = [left, right, top, bottom].map(|p| p as i64);
    let x = TchTensor::new(x.tensor.constant_pad_nd(pad));
    let options = ConvOptions::new(options.stride, [0, 0], options.dilation, options.groups);
    (x, options)
}

/// `t` (4-D) with its channels innermost in memory (PyTorch's `channels_last`), the same tensor
/// where it already is. oneDNN's convolutions run in that layout (2–4× faster than NCHW for
/// CenterNet's depthwise layers, measured in PyTorch 2.9 on the 2-core machine; ATen takes the
/// layout from the input, reordering the weight itself), and ATen's elementwise ops, pads, pools
/// and gradients keep it, so a graph converts its input once. The weight gradient (which burn
/// computes with the batch and channel axes swapped) is left as it comes.
fn channels_last(t: TchTensor) -> TchTensor {
    if is_channels_last(&t.tensor) {
        return t;
    }
    TchTensor::new(
        t.tensor
            .permute([0, 2, 3, 1])
            .contiguous()
            .permute([0, 3, 1, 2]),
    )
}

/// Whether a 4-D tensor's memory is NHWC-dense (strides of axes of size 1 do not matter).
fn is_channels_last(t: &tch::Tensor) -> bool {
    let (size, stride) = (t.size(), t.stride());
    let mut want = 1;
    for axis in [1, 3, 2, 0] {
        if size[axis] != 1 && stride[axis] != want {
            return false;
        }
        want *= size[axis];
    }
    true
}

/// ATen's `constant_pad_nd`: one pass, and the output keeps the input's memory format.
impl PadKernels for LibTorch {
    fn cac_pad(x: TchTensor, pairs: Vec<(usize, usize)>, value: f32) -> TchTensor {
        // ATen lists (before, after) from the last axis backwards.
        let pad: Vec<i64> = pairs
            .iter()
            .rev()
            .flat_map(|&(b, a)| [b as i64, a as i64])
            .collect();
        TchTensor::new(x.tensor.pad(pad, "constant", value as f64))
    }
}

/// ATen's `upsample_bilinear2d` (one pass, channels-last in and out), the legacy formula's end
/// samples by `replication_pad2d`; backward their two backward kernels, as PyTorch's autograd
/// runs them.
impl UpscaleKernels for LibTorch {
    fn cac_upscales_natively(_x: &TchTensor) -> bool {
        true
    }
    fn cac_upscale(x: TchTensor, k: [usize; 2], legacy: bool) -> TchTensor {
        let [_, _, h, w] = x.shape().dims();
        let size = interpolated([h, w], k, legacy).map(|d| d as i64);
        let y = x.tensor.upsample_bilinear2d(size, legacy, None, None);
        TchTensor::new(match legacy {
            true => y.replication_pad2d(end_pad(k)),
            false => y,
        })
    }
    fn cac_upscale_backward(
        g: TchTensor,
        input: [usize; 4],
        k: [usize; 2],
        legacy: bool,
    ) -> TchTensor {
        let size = interpolated([input[2], input[3]], k, legacy).map(|d| d as i64);
        let g = match legacy {
            true => {
                // The pad's input, for its shape and layout: a view of the gradient.
                let like = g.tensor.narrow(2, 0, size[0]).narrow(3, 0, size[1]);
                like.replication_pad2d_backward(&g.tensor, end_pad(k))
            }
            false => g.tensor,
        };
        let input = input.map(|d| d as i64);
        let dx = tch::Tensor::upsample_bilinear2d_backward(&g, size, input, legacy, None, None);
        TchTensor::new(dx)
    }
}

/// `replication_pad2d`'s (left, right, top, bottom) for the legacy formula's end samples.
fn end_pad(k: [usize; 2]) -> [i64; 4] {
    [0, k[1] as i64 - 1, 0, k[0] as i64 - 1]
}

/// One ATen `sum` or `mean` over all the axes (burn-tch reduces one axis at a time); the mean's
/// gradient is the expanded gradient times `1/n`, in one pass (PyTorch's autograd divides by
/// `n`: at most an ulp apart).
impl BroadcastKernels for LibTorch {
    fn cac_sum_dims(x: TchTensor, dims: Vec<usize>) -> TchTensor {
        let dims: Vec<i64> = dims.iter().map(|&d| d as i64).collect();
        TchTensor::new(x.tensor.sum_dim_intlist(dims, true, x.tensor.kind()))
    }
    fn cac_mean_dims(x: TchTensor, dims: Vec<usize>) -> TchTensor {
        let dims: Vec<i64> = dims.iter().map(|&d| d as i64).collect();
        TchTensor::new(x.tensor.mean_dim(dims, true, x.tensor.kind()))
    }
    fn cac_mean_dims_backward(g: TchTensor, shape: Vec<usize>, dims: Vec<usize>) -> TchTensor {
        let n: usize = dims.iter().map(|&d| shape[d]).product();
        let shape: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
        TchTensor::new(g.tensor.expand(shape, false) * (1.0 / n as f64))
    }
}
