//! Sigmoid, SiLU, leaky ReLU, hard swish, ReLU and ReLU6, forward and backward, at vector speed
//! on the CPU.
//!
//! The detectors' activations were a quarter of a YOLO forward pass: burn's Flex evaluates a
//! sigmoid element by element with a branch and a scalar `exp` on one thread, SiLU is composed
//! as `x · sigmoid(x)` (three passes forward, five backward), leaky ReLU as a mask, a scaled
//! copy and a select, MobileNetV3's hard swish (CenterNet) as six passes forward and more
//! backward, ReLU6 as two clamps with two masks each. Here each is one pass forward and one pass
//! backward (the derivative is
//! computed from the input, fused with the incoming gradient), through a burn *backend
//! extension*: [`ActivationKernels`] has composite default bodies (any backend gets them; the
//! `gpu` build's wgpu backend uses them), a Flex implementation on f32 slices (a polynomial `exp`
//! that the compiler vectorises, compiled for AVX2+FMA where the CPU has it, split over rayon's
//! threads), and an autodiff implementation whose backward calls the fused kernels.
//!
//! Accuracy: [`exp_f32`] is within 2 ulp of the exact exponential on [-87, 88] and the sigmoid
//! within 3 ulp of the exact one (tested; Flex's own is within about 1.5); NaN stays NaN; ±∞ and
//! huge inputs saturate to 0/1 (sigmoid) and about 0/x (SiLU) without overflow. An f64 variant
//! (the exact sigmoid rounded) was tried: 2× slower, and YOLOv8n's raw outputs against
//! onnxruntime moved by as much as with this one (1.6–2.0e-4 of the largest box output on the
//! test photos, against 1.2–2.2e-4 with f32, and onnxruntime against itself 0.7–2.8e-4): on a
//! random-weight network that is float noise amplified, not the kernel's error. The library calls the tensor-level functions
//! ([`sigmoid`], [`silu`], [`leaky_relu`], [`hard_swish`], [`relu`], [`relu6`]); the backend is
//! whatever the tensor's device is. At the kinks (0, ±3, 6) the derivative is ATen's one-sided
//! one (TensorFlow's for ReLU and ReLU6).

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{unary, Backward, Ops, OpsKind};
use burn::backend::autodiff::NodeId;
use burn::backend::flex::{FlexTensor, Layout};
use burn::backend::ops::ActivationOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::TensorMetadata;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex};
use burn::tensor::{Bytes, DType, Tensor};
use rayon::prelude::*;

/// The fused activations, per backend. The default bodies compose burn's own ops (what every
/// backend but Flex and autodiff uses); the `_backward` kernels take the op's *input* `x` and the
/// incoming gradient `g`.
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "gpu"), LibTorch: cfg(feature = "tch"))]
pub(crate) trait ActivationKernels: Backend {
    fn act_sigmoid(x: FloatTensor<Self>) -> FloatTensor<Self> {
        Self::sigmoid(x)
    }
    fn act_sigmoid_backward(x: FloatTensor<Self>, g: FloatTensor<Self>) -> FloatTensor<Self> {
        composite::sigmoid_backward::<Self>(x, g)
    }
    fn act_silu(x: FloatTensor<Self>) -> FloatTensor<Self> {
        composite::silu::<Self>(x)
    }
    /// `g · s · (1 + x · (1 − s))` with `s = sigmoid(x)`.
    fn act_silu_backward(x: FloatTensor<Self>, g: FloatTensor<Self>) -> FloatTensor<Self> {
        composite::silu_backward::<Self>(x, g)
    }
    fn act_leaky_relu(x: FloatTensor<Self>, slope: f32) -> FloatTensor<Self> {
        Self::leaky_relu(x, slope.into())
    }
    /// `g` where `x > 0`, `slope · g` elsewhere (ATen's rule: the slope at 0 and for NaN).
    fn act_leaky_relu_backward(
        x: FloatTensor<Self>,
        g: FloatTensor<Self>,
        slope: f32,
    ) -> FloatTensor<Self> {
        composite::leaky_relu_backward::<Self>(x, g, slope)
    }
    /// `scale · x · clamp(x/6 + 1/2, 0, 1)`: `scale` times PyTorch's `hardswish` (MobileNetV3's
    /// activation as TFJS graphs spell it, fused by `tfjs::fuse::hard_swish`).
    fn act_hard_swish(x: FloatTensor<Self>, scale: f32) -> FloatTensor<Self> {
        composite::hard_swish::<Self>(x, scale)
    }
    /// `g · scale · (0 where x ≤ −3, x/3 + 1/2 where −3 < x < 3, 1 where x ≥ 3)`: ATen's
    /// `hardswish_backward` times `scale` (and TensorFlow's at the kinks, through its ReLU6).
    fn act_hard_swish_backward(
        x: FloatTensor<Self>,
        g: FloatTensor<Self>,
        scale: f32,
    ) -> FloatTensor<Self> {
        composite::hard_swish_backward::<Self>(x, g, scale)
    }
    /// `clamp(x, 0, hi)`: ReLU (`hi = ∞`) and ReLU6.
    fn act_relu_to(x: FloatTensor<Self>, hi: f32) -> FloatTensor<Self> {
        composite::relu_to::<Self>(x, hi)
    }
    /// `g` where `0 < x < hi`, 0 elsewhere (ATen's `threshold_backward`, `hardtanh_backward`).
    fn act_relu_to_backward(
        x: FloatTensor<Self>,
        g: FloatTensor<Self>,
        hi: f32,
    ) -> FloatTensor<Self> {
        composite::relu_to_backward::<Self>(x, g, hi)
    }
}

/// The activations composed of burn's ops, for any backend: the trait's default bodies, and
/// Flex's route for what its kernels do not take (not f32).
mod composite {
    use super::*;

    pub(super) fn sigmoid_backward<B: Backend>(
        x: FloatTensor<B>,
        g: FloatTensor<B>,
    ) -> FloatTensor<B> {
        B::sigmoid_backward(B::sigmoid(x), g)
    }
    pub(super) fn silu<B: Backend>(x: FloatTensor<B>) -> FloatTensor<B> {
        let s = B::sigmoid(x.clone());
        B::float_mul(x, s)
    }
    pub(super) fn silu_backward<B: Backend>(
        x: FloatTensor<B>,
        g: FloatTensor<B>,
    ) -> FloatTensor<B> {
        let s = B::sigmoid(x.clone());
        let one_minus = B::float_add_scalar(B::float_neg(s.clone()), 1.0.into());
        let inner = B::float_add_scalar(B::float_mul(x, one_minus), 1.0.into());
        B::float_mul(g, B::float_mul(s, inner))
    }
    pub(super) fn leaky_relu_backward<B: Backend>(
        x: FloatTensor<B>,
        g: FloatTensor<B>,
        slope: f32,
    ) -> FloatTensor<B> {
        let dtype = burn::backend::get_or_init_device_settings::<B>(&x.device()).bool_dtype;
        let pos = B::float_greater_elem(x, 0f32.into(), dtype);
        let scaled = B::float_mul_scalar(g.clone(), slope.into());
        B::float_mask_where(scaled, pos, g)
    }

    pub(super) fn hard_swish<B: Backend>(x: FloatTensor<B>, scale: f32) -> FloatTensor<B> {
        let h = B::float_add_scalar(B::float_div_scalar(x.clone(), 6f32.into()), 0.5f32.into());
        let h = B::float_clamp(h, 0f32.into(), 1f32.into());
        B::float_mul(B::float_mul_scalar(x, scale.into()), h)
    }
    pub(super) fn hard_swish_backward<B: Backend>(
        x: FloatTensor<B>,
        g: FloatTensor<B>,
        scale: f32,
    ) -> FloatTensor<B> {
        let dtype = burn::backend::get_or_init_device_settings::<B>(&x.device()).bool_dtype;
        let low = B::float_lower_equal_elem(x.clone(), (-3f32).into(), dtype);
        // Not below 3 (rather than at least 3), so NaN takes 1 and passes `g` as in ATen.
        let high = B::bool_not(B::float_lower_elem(x.clone(), 3f32.into(), dtype));
        let d = B::float_add_scalar(B::float_div_scalar(x, 3f32.into()), 0.5f32.into());
        let d = B::float_mask_fill(d, high, 1f32.into());
        let d = B::float_mask_fill(d, low, 0f32.into());
        B::float_mul(B::float_mul_scalar(g, scale.into()), d)
    }
    pub(super) fn relu_to<B: Backend>(x: FloatTensor<B>, hi: f32) -> FloatTensor<B> {
        let y = B::float_clamp_min(x, 0f32.into());
        match hi.is_finite() {
            true => B::float_clamp_max(y, hi.into()),
            false => y,
        }
    }
    pub(super) fn relu_to_backward<B: Backend>(
        x: FloatTensor<B>,
        g: FloatTensor<B>,
        hi: f32,
    ) -> FloatTensor<B> {
        let dtype = burn::backend::get_or_init_device_settings::<B>(&x.device()).bool_dtype;
        let off = B::float_lower_equal_elem(x.clone(), 0f32.into(), dtype);
        let g = B::float_mask_fill(g, off, 0f32.into());
        match hi.is_finite() {
            true => {
                let top = B::float_greater_equal_elem(x, hi.into(), dtype);
                B::float_mask_fill(g, top, 0f32.into())
            }
            false => g,
        }
    }
}

/// `sigmoid(x)`, elementwise.
pub fn sigmoid<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    Tensor::from_dispatch(<Dispatch as ActivationKernels>::act_sigmoid(
        x.into_dispatch(),
    ))
}

/// `x · sigmoid(x)` (SiLU, swish), elementwise.
pub fn silu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    Tensor::from_dispatch(<Dispatch as ActivationKernels>::act_silu(x.into_dispatch()))
}

/// `x` where `x ≥ 0`, `slope · x` elsewhere; its gradient takes the slope at 0 (as ATen does).
pub fn leaky_relu<const D: usize>(x: Tensor<D>, slope: f32) -> Tensor<D> {
    Tensor::from_dispatch(<Dispatch as ActivationKernels>::act_leaky_relu(
        x.into_dispatch(),
        slope,
    ))
}

/// `scale · x · clamp(x/6 + 1/2, 0, 1)` (hard swish times `scale`), elementwise.
pub fn hard_swish<const D: usize>(x: Tensor<D>, scale: f32) -> Tensor<D> {
    Tensor::from_dispatch(<Dispatch as ActivationKernels>::act_hard_swish(
        x.into_dispatch(),
        scale,
    ))
}

/// `max(x, 0)`, elementwise.
pub fn relu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    Tensor::from_dispatch(<Dispatch as ActivationKernels>::act_relu_to(
        x.into_dispatch(),
        f32::INFINITY,
    ))
}

/// `clamp(x, 0, 6)`, elementwise.
pub fn relu6<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    Tensor::from_dispatch(<Dispatch as ActivationKernels>::act_relu_to(
        x.into_dispatch(),
        6.0,
    ))
}

#[cfg(feature = "gpu")]
impl ActivationKernels for burn::backend::Cube {}

impl ActivationKernels for Flex {
    fn act_sigmoid(x: FlexTensor) -> FlexTensor {
        map1(x, Sigmoid, Flex::sigmoid)
    }
    fn act_sigmoid_backward(x: FlexTensor, g: FlexTensor) -> FlexTensor {
        map2(x, g, SigmoidGrad, composite::sigmoid_backward::<Flex>)
    }
    fn act_silu(x: FlexTensor) -> FlexTensor {
        map1(x, Silu, composite::silu::<Flex>)
    }
    fn act_silu_backward(x: FlexTensor, g: FlexTensor) -> FlexTensor {
        map2(x, g, SiluGrad, composite::silu_backward::<Flex>)
    }
    fn act_leaky_relu(x: FlexTensor, slope: f32) -> FlexTensor {
        map1(x, Leaky(slope), |x| Flex::leaky_relu(x, slope.into()))
    }
    fn act_leaky_relu_backward(x: FlexTensor, g: FlexTensor, slope: f32) -> FlexTensor {
        map2(x, g, Leaky(slope), |x, g| {
            composite::leaky_relu_backward::<Flex>(x, g, slope)
        })
    }
    fn act_hard_swish(x: FlexTensor, scale: f32) -> FlexTensor {
        map1(x, HardSwish(scale), |x| {
            composite::hard_swish::<Flex>(x, scale)
        })
    }
    fn act_hard_swish_backward(x: FlexTensor, g: FlexTensor, scale: f32) -> FlexTensor {
        map2(x, g, HardSwish(scale), |x, g| {
            composite::hard_swish_backward::<Flex>(x, g, scale)
        })
    }
    fn act_relu_to(x: FlexTensor, hi: f32) -> FlexTensor {
        map1(x, ReluTo(hi), |x| composite::relu_to::<Flex>(x, hi))
    }
    fn act_relu_to_backward(x: FlexTensor, g: FlexTensor, hi: f32) -> FlexTensor {
        map2(x, g, ReluTo(hi), |x, g| {
            composite::relu_to_backward::<Flex>(x, g, hi)
        })
    }
}

/// An elementwise function of the input (forward) or of the input and the incoming gradient
/// (backward), evaluated lane by lane: `#[inline(always)]` so that each loop below is compiled
/// with the body inside, and vectorised.
trait Lane: Copy + Send + Sync {
    fn f(self, x: f32) -> f32 {
        x
    }
    fn fg(self, x: f32, _g: f32) -> f32 {
        x
    }
}

#[derive(Clone, Copy)]
struct Sigmoid;
#[derive(Clone, Copy)]
struct SigmoidGrad;
#[derive(Clone, Copy)]
struct Silu;
#[derive(Clone, Copy)]
struct SiluGrad;
#[derive(Clone, Copy)]
struct Leaky(f32);
#[derive(Clone, Copy)]
struct HardSwish(f32);
#[derive(Clone, Copy)]
struct ReluTo(f32);

impl Lane for Sigmoid {
    #[inline(always)]
    fn f(self, x: f32) -> f32 {
        sigmoid_f32(x)
    }
}
impl Lane for SigmoidGrad {
    #[inline(always)]
    fn fg(self, x: f32, g: f32) -> f32 {
        let s = sigmoid_f32(x);
        g * s * (1.0 - s)
    }
}
impl Lane for Silu {
    #[inline(always)]
    fn f(self, x: f32) -> f32 {
        x * sigmoid_f32(x)
    }
}
impl Lane for SiluGrad {
    #[inline(always)]
    fn fg(self, x: f32, g: f32) -> f32 {
        let s = sigmoid_f32(x);
        g * s * (1.0 + x * (1.0 - s))
    }
}
impl Lane for Leaky {
    #[inline(always)]
    fn f(self, x: f32) -> f32 {
        if x < 0.0 {
            self.0 * x
        } else {
            x
        }
    }
    #[inline(always)]
    fn fg(self, x: f32, g: f32) -> f32 {
        // ATen's rule: the slope at x = 0 and for NaN as well.
        if x > 0.0 {
            g
        } else {
            self.0 * g
        }
    }
}

impl Lane for HardSwish {
    #[inline(always)]
    fn f(self, x: f32) -> f32 {
        self.0 * x * (x / 6.0 + 0.5).clamp(0.0, 1.0)
    }
    #[inline(always)]
    fn fg(self, x: f32, g: f32) -> f32 {
        // In ATen's order, so NaN passes `g` through as there.
        let d = if x <= -3.0 {
            0.0
        } else if x < 3.0 {
            x / 3.0 + 0.5
        } else {
            1.0
        };
        g * self.0 * d
    }
}
impl Lane for ReluTo {
    #[inline(always)]
    fn f(self, x: f32) -> f32 {
        // NaN stays NaN (as in burn's clamp), which `x.clamp` would not promise.
        if x > self.0 {
            self.0
        } else if x < 0.0 {
            0.0
        } else {
            x
        }
    }
    #[inline(always)]
    fn fg(self, x: f32, g: f32) -> f32 {
        // As ATen's threshold/hardtanh backward: NaN passes `g` through.
        if x <= 0.0 || x >= self.0 {
            0.0
        } else {
            g
        }
    }
}

/// Elements per rayon task: large enough that scheduling is noise, small enough to split a
/// feature map over two threads.
const CHUNK: usize = 1 << 14;

/// The f32 elements of a contiguous tensor (`None`: another dtype or a strided view).
fn f32_slice(x: &FlexTensor) -> Option<&[f32]> {
    if x.dtype() != DType::F32 {
        return None;
    }
    let (start, end) = x.layout().contiguous_offsets()?;
    Some(&x.storage::<f32>()[start..end])
}

/// Whether `x` may be overwritten: f32, nobody else holds its buffer, and the buffer is exactly
/// its elements in order (so the output can take its layout).
fn writable(x: &FlexTensor) -> bool {
    x.dtype() == DType::F32
        && x.is_unique()
        && x.layout().is_contiguous()
        && x.layout().start_offset() == 0
        && x.bytes().len() == x.layout().num_elements() * 4
}

fn contiguous(x: FlexTensor) -> FlexTensor {
    if x.dtype() == DType::F32 && f32_slice(&x).is_none() {
        x.to_contiguous()
    } else {
        x
    }
}

/// `op.f` over the f32 elements of `x` in parallel chunks, in place where `x` is
/// [`writable`], else into a new buffer; `slow(x)` for other dtypes.
fn map1(x: FlexTensor, op: impl Lane, slow: impl FnOnce(FlexTensor) -> FlexTensor) -> FlexTensor {
    let mut x = contiguous(x);
    if writable(&x) {
        x.storage_mut::<f32>()
            .par_chunks_mut(CHUNK)
            .for_each(|y| lanes(op, y, None));
        return x;
    }
    let Some(src) = f32_slice(&x) else {
        return slow(x);
    };
    let out = fresh(src.len(), |start, y| {
        y.copy_from_slice(&src[start..start + y.len()]);
        lanes(op, y, None)
    });
    from_vec(out, &x)
}

/// `op.fg` over the f32 elements of `x` and `g` (same shape) in parallel chunks, in place in
/// `g` where it is [`writable`]; `slow(x, g)` for other dtypes.
fn map2(
    x: FlexTensor,
    g: FlexTensor,
    op: impl Lane,
    slow: impl FnOnce(FlexTensor, FlexTensor) -> FlexTensor,
) -> FlexTensor {
    if x.dtype() != DType::F32
        || g.dtype() != DType::F32
        || x.layout().shape() != g.layout().shape()
    {
        return slow(x, g);
    }
    let (x, mut g) = (contiguous(x), contiguous(g));
    let Some(xs) = f32_slice(&x) else {
        return slow(x, g);
    };
    if writable(&g) {
        g.storage_mut::<f32>()
            .par_chunks_mut(CHUNK)
            .zip(xs.par_chunks(CHUNK))
            .for_each(|(y, x)| lanes(op, y, Some(x)));
        return g;
    }
    let Some(gs) = f32_slice(&g) else {
        return slow(x, g);
    };
    let out = fresh(gs.len(), |start, y| {
        y.copy_from_slice(&gs[start..start + y.len()]);
        lanes(op, y, Some(&xs[start..start + y.len()]))
    });
    from_vec(out, &x)
}

/// A new buffer of `n` elements, each chunk filled by `fill(offset, chunk)` in parallel. The
/// buffer is zeroed first: a slice of uninitialised floats is undefined behaviour in Rust even
/// when every element is written before it is read, and the zeroing pass costs a memset against
/// the kernel's arithmetic.
fn fresh(n: usize, fill: impl Fn(usize, &mut [f32]) + Sync) -> Vec<f32> {
    let mut out = vec![0.0f32; n];
    out.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(k, y)| fill(k * CHUNK, y));
    out
}

fn from_vec(v: Vec<f32>, like: &FlexTensor) -> FlexTensor {
    FlexTensor::new(
        Bytes::from_elems(v),
        Layout::contiguous(like.layout().shape().clone()),
        DType::F32,
    )
}

/// `y[i] = op.f(y[i])`, or `y[i] = op.fg(x[i], y[i])` (`y` holding the gradient) when `x` is
/// given; compiled for AVX2+FMA when the CPU has them.
fn lanes<L: Lane>(op: L, y: &mut [f32], x: Option<&[f32]>) {
    #[inline(always)]
    fn body<L: Lane>(op: L, y: &mut [f32], x: Option<&[f32]>) {
        match x {
            None => y.iter_mut().for_each(|y| *y = op.f(*y)),
            Some(x) => y.iter_mut().zip(x).for_each(|(g, &x)| *g = op.fg(x, *g)),
        }
    }
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2,fma")]
        unsafe fn avx2<L: Lane>(op: L, y: &mut [f32], x: Option<&[f32]>) {
            body(op, y, x)
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has the features the variant is compiled for (checked above).
            return unsafe { avx2(op, y, x) };
        }
    }
    body(op, y, x)
}

/// `exp(x)` without branches (so a loop of it vectorises): `x = n·ln2 + r`, `|r| ≤ ln2/2`,
/// `exp(r)` by Cephes' polynomial, `2^n` built in the exponent bits. Inputs are clamped to
/// [-87.3, 88.7], so the result is a normal float (0 and ∞ are not reached, which the sigmoid and
/// SiLU below rely on); NaN propagates (the clamp's comparisons are false for it).
#[inline(always)]
pub(crate) fn exp_f32(x: f32) -> f32 {
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = if x > 88.7 { 88.7 } else { x };
    let x = if x < -87.3 { -87.3 } else { x };
    // Round to nearest with the 1.5·2^23 trick (exact for |t| < 2^22).
    const MAGIC: f32 = 12_582_912.0;
    let n = (x * std::f32::consts::LOG2_E + MAGIC) - MAGIC;
    let r = x - n * LN2_HI - n * LN2_LO;
    let mut p = 1.987_569_1e-4_f32;
    for c in [
        1.398_199_9e-3,
        8.333_452e-3,
        4.166_579_6e-2,
        1.666_666_5e-1,
        5e-1,
    ] {
        p = p * r + c;
    }
    let p = p * r * r + r + 1.0;
    // n is an integer in [-126, 128]; 2^128 is not a float, so n = 128 (x near 88.7) is
    // built as 2^127 · (2p).
    let n = n as i32;
    let (n, p) = if n > 127 { (127, p * 2.0) } else { (n, p) };
    f32::from_bits(((n + 127) as u32) << 23) * p
}

/// `1 / (1 + exp(−x))`: within a few ulp of the exact sigmoid (tested), 1 above x ≈ 87 and below
/// 3e-39 under x ≈ −89, NaN for NaN.
#[inline(always)]
pub(crate) fn sigmoid_f32(x: f32) -> f32 {
    1.0 / (1.0 + exp_f32(-x))
}

impl<B: Backend + ActivationKernels, C: CheckpointStrategy> ActivationKernels for Autodiff<B, C> {
    fn act_sigmoid(x: FloatTensor<Self>) -> FloatTensor<Self> {
        tracked::<B, C>(Fused::Sigmoid, x)
    }
    fn act_silu(x: FloatTensor<Self>) -> FloatTensor<Self> {
        tracked::<B, C>(Fused::Silu, x)
    }
    fn act_leaky_relu(x: FloatTensor<Self>, slope: f32) -> FloatTensor<Self> {
        tracked::<B, C>(Fused::LeakyRelu(slope), x)
    }
    fn act_hard_swish(x: FloatTensor<Self>, scale: f32) -> FloatTensor<Self> {
        tracked::<B, C>(Fused::HardSwish(scale), x)
    }
    fn act_relu_to(x: FloatTensor<Self>, hi: f32) -> FloatTensor<Self> {
        tracked::<B, C>(Fused::ReluTo(hi), x)
    }
}

/// One fused activation as an autodiff op: the input is kept, the backward is one kernel.
#[derive(Debug, Clone, Copy)]
enum Fused {
    Sigmoid,
    Silu,
    LeakyRelu(f32),
    HardSwish(f32),
    ReluTo(f32),
}

impl Fused {
    fn forward<B: ActivationKernels>(self, x: FloatTensor<B>) -> FloatTensor<B> {
        match self {
            Fused::Sigmoid => B::act_sigmoid(x),
            Fused::Silu => B::act_silu(x),
            Fused::LeakyRelu(a) => B::act_leaky_relu(x, a),
            Fused::HardSwish(k) => B::act_hard_swish(x, k),
            Fused::ReluTo(hi) => B::act_relu_to(x, hi),
        }
    }
    fn backward<B: ActivationKernels>(
        self,
        x: FloatTensor<B>,
        g: FloatTensor<B>,
    ) -> FloatTensor<B> {
        match self {
            Fused::Sigmoid => B::act_sigmoid_backward(x, g),
            Fused::Silu => B::act_silu_backward(x, g),
            Fused::LeakyRelu(a) => B::act_leaky_relu_backward(x, g, a),
            Fused::HardSwish(k) => B::act_hard_swish_backward(x, g, k),
            Fused::ReluTo(hi) => B::act_relu_to_backward(x, g, hi),
        }
    }
}

impl<B: Backend + ActivationKernels> Backward<B, 1> for Fused {
    type State = NodeId;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, cp: &mut Checkpointer) {
        let x: FloatTensor<B> = cp.retrieve_node_output(ops.state);
        unary::<B, _>(ops.parents, ops.node, grads, |g| self.backward::<B>(x, g));
    }
}

fn tracked<B: Backend + ActivationKernels, C: CheckpointStrategy>(
    op: Fused,
    x: FloatTensor<Autodiff<B, C>>,
) -> FloatTensor<Autodiff<B, C>> {
    match op.prepare::<C>([x.node()]).compute_bound().stateful() {
        OpsKind::Tracked(mut prep) => {
            let state = prep.checkpoint(&x);
            prep.finish(state, op.forward::<B>(x.into_primitive()))
        }
        OpsKind::UnTracked(prep) => prep.finish(op.forward::<B>(x.into_primitive())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{activation, Device, TensorData};

    fn seeded(n: usize, scale: f32, seed: u64) -> Vec<f32> {
        use rand::{Rng, SeedableRng};
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| r.random_range(-scale..scale)).collect()
    }

    #[test]
    fn exp_is_within_two_ulp_of_std_over_its_range() {
        let mut worst = 0f64;
        let mut x = -87.0f32;
        while x < 88.0 {
            let (a, b) = (exp_f32(x) as f64, (x as f64).exp());
            worst = worst.max(((a - b) / b).abs());
            x += 0.0137;
        }
        assert!(
            worst < 2.0 * f32::EPSILON as f64,
            "worst relative error {worst:e}"
        );
    }

    /// The sigmoid against the exact one (f64), over seeded inputs: within 3 ulp, or 3.1e-39
    /// absolute where the clamp of exp's input applies.
    #[test]
    fn sigmoid_is_within_three_ulp_of_the_exact_one() {
        for x in seeded(100_000, 100.0, 11) {
            let exact = 1.0 / (1.0 + (-(x as f64)).exp());
            let got = sigmoid_f32(x) as f64;
            let ulp = exact * f32::EPSILON as f64;
            assert!(
                (got - exact).abs() <= 3.0 * ulp + 3.1e-39,
                "sigmoid({x}) = {got}, exact {exact}"
            );
        }
    }

    #[test]
    fn extremes_saturate_and_nan_propagates() {
        for (x, s) in [
            (f32::INFINITY, 1.0),
            (f32::NEG_INFINITY, 0.0),
            (1e30, 1.0),
            (-1e30, 0.0),
            (0.0, 0.5),
        ] {
            let got = sigmoid_f32(x);
            assert!(
                (got - s).abs() < 1e-30 || (got - s).abs() < 1e-7,
                "sigmoid({x}) = {got}"
            );
        }
        assert!(sigmoid_f32(f32::NAN).is_nan());
        // NaN forward stays NaN; backward passes the gradient through as ATen's kernels do.
        assert!(ReluTo(6.0).f(f32::NAN).is_nan() && HardSwish(1.7).f(f32::NAN).is_nan());
        assert_eq!(ReluTo(6.0).fg(f32::NAN, 2.0), 2.0);
        assert_eq!(ReluTo(f32::INFINITY).fg(f32::NAN, 2.0), 2.0);
        assert_eq!(HardSwish(1.5).fg(f32::NAN, 2.0), 3.0);
        // Leaky ReLU takes the slope at 0 and for NaN, as ATen's `leaky_relu_backward` does.
        assert!(Leaky(0.1).f(f32::NAN).is_nan());
        assert_eq!(Leaky(0.25).fg(0.0, 2.0), 0.5);
        assert_eq!(Leaky(0.25).fg(-0.0, 2.0), 0.5);
        assert_eq!(Leaky(0.25).fg(f32::NAN, 2.0), 0.5);
        assert_eq!(Leaky(0.25).fg(1e-30, 2.0), 2.0);
        assert!(exp_f32(f32::NAN).is_nan());
        assert!(exp_f32(1e30).is_finite() && exp_f32(-1e30) > 0.0);
        // SiLU of a huge negative: about 0 (the clamp leaves sigmoid at 2.9e-39), never NaN.
        for x in [-1e30f32, -1e6, -100.0] {
            let silu = Silu.f(x);
            assert!(silu.is_finite() && silu.abs() < 1e-8, "silu({x}) = {silu}");
        }
    }

    /// Forward values and input gradients of each fused activation against burn's own composite
    /// ops on the same seeded input (a strided view included), on Flex with autodiff.
    #[test]
    fn fused_kernels_match_burns_composites_forward_and_backward() {
        let dev = Device::autodiff(Device::from(burn::backend::FlexDevice));
        let n = 3 * 5 * 41 * 37; // several chunks, not a multiple of the vector width
        let data = seeded(n, 12.0, 7);
        let weights = seeded(n, 1.0, 8);
        type Op = fn(Tensor<4>) -> Tensor<4>;
        let cases: [(&str, Op, Op); 6] = [
            ("sigmoid", sigmoid, activation::sigmoid),
            ("silu", silu, |x| x.clone() * activation::sigmoid(x)),
            (
                "leaky_relu",
                |x| leaky_relu(x, 0.1),
                |x| activation::leaky_relu(x, 0.1),
            ),
            (
                "hard_swish",
                |x| hard_swish(x, 1.7),
                |x| x.clone().mul_scalar(1.7) * activation::hard_sigmoid(x, 1.0 / 6.0, 0.5),
            ),
            ("relu", relu, activation::relu),
            ("relu6", relu6, |x| x.clamp(0.0, 6.0)),
        ];
        for (name, fast, reference) in cases {
            for strided in [false, true] {
                let run = |f: Op| {
                    let x =
                        Tensor::<4>::from_data(TensorData::new(data.clone(), [3, 5, 41, 37]), &dev)
                            .require_grad();
                    let xin = if strided {
                        x.clone().swap_dims(1, 3)
                    } else {
                        x.clone()
                    };
                    let w = Tensor::<4>::from_data(
                        TensorData::new(weights.clone(), [3, 5, 41, 37]),
                        &dev,
                    );
                    let w = if strided { w.swap_dims(1, 3) } else { w };
                    let y = f(xin);
                    let grads = (y.clone() * w).sum().backward();
                    let g = x.grad(&grads).expect("gradient");
                    let y = if strided { y.swap_dims(1, 3) } else { y };
                    (
                        y.into_data().try_into_vec::<f32>().unwrap(),
                        g.into_data().try_into_vec::<f32>().unwrap(),
                    )
                };
                let (yf, gf) = run(fast);
                let (yr, gr) = run(reference);
                let err = |a: &[f32], b: &[f32]| {
                    a.iter()
                        .zip(b)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0f32, f32::max)
                };
                assert!(
                    err(&yf, &yr) < 2e-6,
                    "{name} (strided {strided}) forward: {}",
                    err(&yf, &yr)
                );
                assert!(
                    err(&gf, &gr) < 2e-6,
                    "{name} (strided {strided}) backward: {}",
                    err(&gf, &gr)
                );
            }
        }
    }

    /// Without autodiff the fused ops give the same values (the plain Flex route).
    #[test]
    fn inference_device_gives_the_same_values() {
        let dev = Device::from(burn::backend::FlexDevice);
        let data = seeded(1000, 30.0, 3);
        let x = Tensor::<1>::from_data(TensorData::new(data.clone(), [1000]), &dev);
        let y = silu(x).into_data().try_into_vec::<f32>().unwrap();
        for (y, x) in y.iter().zip(&data) {
            let want = (*x as f64) / (1.0 + (-*x as f64).exp());
            assert!(
                (*y as f64 - want).abs() < 1e-5 * want.abs().max(1.0),
                "silu({x}) = {y}"
            );
        }
    }
}
