//! The kernels on burn's LibTorch backend (the `tch` fast path): libtorch's own fused
//! activations (one ATen call forward and one backward, as PyTorch's autograd runs them) and its
//! convolution (oneDNN forward; the input gradient as burn's transposed convolution, which
//! libtorch also runs on oneDNN).
//!
//! Built only with the `tch` feature. The autodiff implementations of [`ActivationKernels`] and
//! [`ConvKernels`] (in their modules) call these for the inner backend, so a gradient through
//! libtorch costs what it costs in PyTorch.

// burn 0.22 marks its LibTorch backend deprecated (it steers users to CubeCL backends, whose CPU
// and CUDA builds download LLVM at build time and fail offline): chosen here all the same, as the
// one backend on PyTorch's own kernels (docs/detectors.md, "The libtorch fast path").
#![allow(deprecated)]

use crate::activation::ActivationKernels;
use crate::conv::ConvKernels;
use burn::backend::libtorch::TchTensor;
use burn::backend::LibTorch;

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
    fn act_leaky_relu_backward(x: TchTensor, g: TchTensor, slope: f32) -> TchTensor {
        TchTensor::new(x.tensor.leaky_relu_backward(&g.tensor, slope as f64, false))
    }
}

/// The default bodies: burn-tch's `conv2d` is libtorch's, and the gradients compose libtorch ops.
impl ConvKernels for LibTorch {}
