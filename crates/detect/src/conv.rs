//! Dense 2-D convolution (groups = 1) as im2col and matrix products, forward and backward, with
//! the work split over threads by output columns.
//!
//! burn's Flex runs a dense convolution as tiled im2col + gemm too, but leaves the threading to
//! the gemm crate's own split (or to the batch), which scales poorly on two cores: a 64×576 by
//! 576×25600 product takes 34 ms on one thread and 26 ms on two that way, 18.5 ms when each
//! thread runs a single-threaded product on its own columns. This module does the latter, for
//! the forward pass (`W · col`), the input gradient (`Wᵀ · g`, then col2im) and the weight
//! gradient (`g · colᵀ`, split by the columns of the weight matrix instead), and recomputes the
//! columns in the backward pass rather than keeping them. Depthwise layers keep Flex's own
//! forward and weight gradient, with the input gradient computed here (burn's goes through a
//! transposed convolution); other grouped layers stay on burn's ops, as does every other
//! backend (the extension's default bodies are burn's own ops).
//!
//! The products are the `gemm` crate's (the one Flex uses, with its runtime-selected AVX2/FMA
//! and AVX-512 kernels). Sums run in another order than burn's: agreement is to float rounding
//! (tested against burn's convolution and its gradients).

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{binary, Backward, Ops, OpsKind};
use burn::backend::autodiff::NodeId;
use burn::backend::flex::{FlexTensor, Layout};
use burn::backend::ops::ModuleOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex};
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Bytes, DType, Tensor};
use rayon::prelude::*;

/// The convolution without bias, and its two gradients, per backend. The default bodies are
/// burn's own; Flex's implementation picks this module's kernels where the layer is dense or
/// depthwise and f32, and burn's elsewhere.
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "gpu"), LibTorch: cfg(feature = "tch"))]
pub(crate) trait ConvKernels: Backend {
    fn cac_conv2d(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        Self::conv2d(x, w, None, options)
    }
    fn cac_conv2d_x_backward(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        g: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        Self::conv2d_x_backward(x, w, g, options)
    }
    fn cac_conv2d_weight_backward(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        g: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        Self::conv2d_weight_backward(x, w, g, options)
    }
}

/// `conv2d` of NCHW `x` with OIHW `w` (and a bias per output channel), through
/// [`ConvKernels`]: this module's kernels for dense and depthwise layers on Flex, burn's for
/// the rest.
pub fn conv2d(
    x: Tensor<4>,
    w: Tensor<4>,
    bias: Option<Tensor<1>>,
    options: ConvOptions<2>,
) -> Tensor<4> {
    let y = <Dispatch as ConvKernels>::cac_conv2d(x.into_dispatch(), w.into_dispatch(), options);
    let y = Tensor::<4>::from_dispatch(y);
    match bias {
        Some(b) => add_bias(y, b),
        None => y,
    }
}

/// `y + b` with `b` one value per channel (axis 1).
pub fn add_bias(y: Tensor<4>, b: Tensor<1>) -> Tensor<4> {
    let c = b.dims()[0];
    crate::broadcast::add(y, b.reshape([1, c, 1, 1]))
}

#[cfg(feature = "gpu")]
impl ConvKernels for burn::backend::Cube {}

/// The geometry of one convolution: input `[n, ci, h, w]`, weight `[co, ci, kh, kw]`, output
/// `[n, co, oh, ow]`, and the im2col matrix `[k = ci·kh·kw, p = oh·ow]` of one image.
#[derive(Clone, Copy, Debug)]
struct Geometry {
    n: usize,
    ci: usize,
    h: usize,
    w: usize,
    co: usize,
    kh: usize,
    kw: usize,
    oh: usize,
    ow: usize,
    stride: [usize; 2],
    /// Padding before the first row and column (the ends follow from the output size).
    pad: [usize; 2],
    /// Padding after the last row and column.
    pad_end: [usize; 2],
    dil: [usize; 2],
    /// Whether any side is padded.
    padded: bool,
}

impl Geometry {
    /// A dense convolution (groups = 1).
    fn new(x: &[usize], w: &[usize], o: &ConvOptions<2>) -> Option<Self> {
        match (x, w) {
            (&[_, ci, _, _], &[_, wci, _, _]) if wci == ci && o.groups == 1 => {
                Self::shaped(x, w[0], w, o)
            }
            _ => None,
        }
    }

    /// A depthwise convolution (groups = channels in = channels out, weight `[c, 1, kh, kw]`);
    /// `ci` and `co` are both the channel count.
    fn depthwise(x: &[usize], w: &[usize], o: &ConvOptions<2>) -> Option<Self> {
        match (x, w) {
            (&[_, c, _, _], &[wc, 1, _, _]) if wc == c && o.groups == c => Self::shaped(x, c, w, o),
            _ => None,
        }
    }

    fn shaped(x: &[usize], co: usize, w: &[usize], o: &ConvOptions<2>) -> Option<Self> {
        let (&[n, ci, h, wd], &[_, _, kh, kw]) = (x, w) else {
            return None;
        };
        if kh == 0 || kw == 0 || o.stride.contains(&0) {
            return None;
        }
        let out = |i: usize, d: usize| -> Option<usize> {
            let span = o.dilation[d] * (i - 1) + 1;
            let (before, after) = o.padding[d];
            Some(([h, wd][d] + before + after).checked_sub(span)? / o.stride[d] + 1)
        };
        let (oh, ow) = (out(kh, 0)?, out(kw, 1)?);
        Some(Geometry {
            n,
            ci,
            h,
            w: wd,
            co,
            kh,
            kw,
            oh,
            ow,
            stride: o.stride,
            pad: o.padding_begin(),
            pad_end: o.padding_end(),
            dil: o.dilation,
            padded: o.padding.iter().any(|&(a, b)| a + b > 0),
        })
    }
    fn k(&self) -> usize {
        self.ci * self.kh * self.kw
    }
    fn p(&self) -> usize {
        self.oh * self.ow
    }
    /// A 1×1, stride-1, unpadded convolution: the image is its own im2col matrix.
    fn pointwise(&self) -> bool {
        self.kh == 1 && self.kw == 1 && self.stride == [1, 1] && !self.padded
    }

    /// The input row of output row `oy` for kernel row `ky` (None: in the padding).
    fn input_row(&self, oy: usize, ky: usize) -> Option<usize> {
        let iy = (oy * self.stride[0] + ky * self.dil[0]).checked_sub(self.pad[0])?;
        (iy < self.h).then_some(iy)
    }

    /// Calls `f(oy, ox0, ox1, offset)` for each output-row segment of columns `[p0, p1)`
    /// (`offset`: the segment's first column, relative to `p0`).
    fn segments(&self, p0: usize, p1: usize, mut f: impl FnMut(usize, usize, usize, usize)) {
        let mut p = p0;
        while p < p1 {
            let (oy, ox0) = (p / self.ow, p % self.ow);
            let ox1 = self.ow.min(ox0 + (p1 - p));
            f(oy, ox0, ox1, p - p0);
            p += ox1 - ox0;
        }
    }

    /// Columns `[p0, p1)` of the im2col matrix of image `x` (`[ci, h, w]`) into `buf`
    /// (`k × (p1 − p0)`, row-major; row `r = (c, ky, kx)`).
    fn im2col_tile(&self, x: &[f32], (p0, p1): (usize, usize), buf: &mut [f32]) {
        let t = p1 - p0;
        let taps = self.kh * self.kw;
        for (r, dst) in buf.chunks_exact_mut(t).take(self.k()).enumerate() {
            let (c, ky, kx) = (r / taps, (r % taps) / self.kw, r % self.kw);
            let plane = &x[c * self.h * self.w..][..self.h * self.w];
            let x0 = (kx * self.dil[1]) as isize - self.pad[1] as isize;
            self.segments(p0, p1, |oy, ox0, ox1, at| {
                let seg = &mut dst[at..][..ox1 - ox0];
                let Some(iy) = self.input_row(oy, ky) else {
                    seg.fill(0.0);
                    return;
                };
                let src = &plane[iy * self.w..][..self.w];
                let (a, b) = self.inside(x0, ox0, ox1);
                seg[..a - ox0].fill(0.0);
                seg[b - ox0..].fill(0.0);
                if a < b {
                    let (start, s) = (
                        (x0 + (a * self.stride[1]) as isize) as usize,
                        self.stride[1],
                    );
                    let seg = &mut seg[a - ox0..b - ox0];
                    if s == 1 {
                        seg.copy_from_slice(&src[start..][..seg.len()]);
                    } else {
                        let src = &src[start..=start + (seg.len() - 1) * s];
                        for (d, v) in seg.iter_mut().zip(src.iter().step_by(s)) {
                            *d = *v;
                        }
                    }
                }
            });
        }
    }

    /// The output columns `[a, b)` within `[ox0, ox1)` whose input column `x0 + ox·stride` lies
    /// inside the image (the rest read the padding).
    fn inside(&self, x0: isize, ox0: usize, ox1: usize) -> (usize, usize) {
        let (s, w) = (self.stride[1] as isize, self.w as isize);
        let first = if x0 >= 0 { 0 } else { (-x0 + s - 1) / s };
        let end = if w - x0 <= 0 { 0 } else { (w - x0 + s - 1) / s };
        let a = (first as usize).clamp(ox0, ox1);
        (a, (end as usize).clamp(a, ox1))
    }

    /// Adds `buf` (the im2col rows of channels `c0..`, columns `[p0, p1)`) back onto the planes
    /// `dx` of those channels: the adjoint of [`Geometry::im2col_tile`].
    fn col2im_tile(&self, buf: &[f32], (p0, p1): (usize, usize), dx: &mut [f32]) {
        let t = p1 - p0;
        let taps = self.kh * self.kw;
        for (c, plane) in dx.chunks_exact_mut(self.h * self.w).enumerate() {
            for tap in 0..taps {
                let (ky, kx) = (tap / self.kw, tap % self.kw);
                let row = &buf[(c * taps + tap) * t..][..t];
                let x0 = (kx * self.dil[1]) as isize - self.pad[1] as isize;
                self.segments(p0, p1, |oy, ox0, ox1, at| {
                    let Some(iy) = self.input_row(oy, ky) else {
                        return;
                    };
                    let dst = &mut plane[iy * self.w..][..self.w];
                    let (a, b) = self.inside(x0, ox0, ox1);
                    if a < b {
                        let (start, s) = (
                            (x0 + (a * self.stride[1]) as isize) as usize,
                            self.stride[1],
                        );
                        let src = &row[at + a - ox0..at + b - ox0];
                        let dst = &mut dst[start..=start + (src.len() - 1) * s];
                        for (d, v) in dst.iter_mut().step_by(s).zip(src) {
                            *d += v;
                        }
                    }
                });
            }
        }
    }

    /// Column tiles of one image's output: for im2col, about 512 KB of columns each (they stay
    /// in cache between their construction and the product); for 1×1 layers, a few per thread.
    fn tiles(&self) -> Vec<(usize, usize)> {
        let p = self.p();
        let step = if self.pointwise() {
            p.div_ceil(rayon::current_num_threads() * 4).max(64)
        } else {
            ((524_288 / self.k()) / 16 * 16).clamp(64, 4096)
        };
        (0..p)
            .step_by(step)
            .map(|s| (s, (s + step).min(p)))
            .collect()
    }
}

thread_local! {
    /// Each worker's im2col buffer, kept between calls (a fresh one per tile would be a page
    /// fault per 4 KB).
    static SCRATCH: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's scratch buffer of at least `n` elements.
fn with_scratch<R>(n: usize, f: impl FnOnce(&mut [f32]) -> R) -> R {
    SCRATCH.with_borrow_mut(|v| {
        if v.len() < n {
            v.resize(n, 0.0);
        }
        f(&mut v[..n])
    })
}

/// A matrix operand for [`gemm`]: base pointer, row stride, column stride.
#[derive(Clone, Copy)]
struct Mat(*const f32, isize, isize);

/// `C (+)= A · B` on this thread, `C` row-major `m × n` with row stride `ldc`, `A` `m × k`, `B`
/// `k × n`.
///
/// # Safety
/// The operands must describe matrices of those sizes inside live buffers, `c` overlapping
/// neither.
unsafe fn gemm(
    (m, n, k): (usize, usize, usize),
    c: *mut f32,
    ldc: usize,
    accumulate: bool,
    a: Mat,
    b: Mat,
) {
    // SAFETY: per the function's contract.
    unsafe { gemm_with((m, n, k), c, ldc, accumulate, a, b, gemm::Parallelism::None) }
}

/// [`gemm`] with the gemm crate's own threading (`par`).
///
/// # Safety
/// As [`gemm`].
unsafe fn gemm_with(
    (m, n, k): (usize, usize, usize),
    c: *mut f32,
    ldc: usize,
    accumulate: bool,
    a: Mat,
    b: Mat,
    par: gemm::Parallelism,
) {
    // SAFETY: per the function's contract.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c,
            1,
            ldc as isize,
            accumulate,
            a.0,
            a.2,
            a.1,
            b.0,
            b.2,
            b.1,
            if accumulate { 1.0 } else { 0.0 },
            1.0,
            false,
            false,
            false,
            par,
        )
    }
}

/// A pointer to a buffer that parallel tasks write in disjoint parts.
#[derive(Clone, Copy)]
struct Shared(*mut f32);
// SAFETY: each task writes only its own columns or channels of the buffer.
unsafe impl Send for Shared {}
unsafe impl Sync for Shared {}

/// `x` with its elements contiguous (a copy only where it is a strided view).
fn contiguous(x: FlexTensor) -> FlexTensor {
    match x.layout().contiguous_offsets() {
        Some(_) => x,
        None => x.to_contiguous(),
    }
}

fn slice(x: &FlexTensor) -> &[f32] {
    let (s, e) = x.layout().contiguous_offsets().expect("contiguous");
    &x.storage::<f32>()[s..e]
}

fn tensor(v: Vec<f32>, shape: &[usize]) -> FlexTensor {
    FlexTensor::new(
        Bytes::from_elems(v),
        Layout::contiguous(shape.iter().copied().collect()),
        DType::F32,
    )
}

/// Forward: `y[b][:, tile] = W · col(x[b])[:, tile]`, tiles in parallel.
fn forward(x: &[f32], w: &[f32], g: &Geometry) -> Vec<f32> {
    let (k, p, img) = (g.k(), g.p(), g.ci * g.h * g.w);
    // Zeroed, although the products overwrite all of it: uninitialised floats behind a pointer
    // that becomes a slice are undefined behaviour; a memset is small against the products.
    let mut y = vec![0.0f32; g.n * g.co * p];
    let out = Shared(y.as_mut_ptr());
    let tiles = g.tiles();
    let jobs: Vec<(usize, (usize, usize))> = (0..g.n)
        .flat_map(|b| tiles.iter().map(move |&t| (b, t)))
        .collect();
    let threads = rayon::current_num_threads();
    if threads > 1 && jobs.len() < 2 * threads {
        // Too few columns to split (deep layers of a small input): one product per image over
        // all its columns, threaded by the gemm crate.
        let mut col = if g.pointwise() {
            Vec::new()
        } else {
            vec![0f32; k * p]
        };
        for b in 0..g.n {
            let xb = &x[b * img..][..img];
            if !g.pointwise() {
                g.im2col_tile(xb, (0, p), &mut col);
            }
            let cols = Mat(
                if g.pointwise() {
                    xb.as_ptr()
                } else {
                    col.as_ptr()
                },
                p as isize,
                1,
            );
            let (wm, dst) = (
                Mat(w.as_ptr(), k as isize, 1),
                y[b * g.co * p..].as_mut_ptr(),
            );
            let par = gemm::Parallelism::Rayon(threads);
            // SAFETY: W is co × k, the columns k × p, y[b] co × p.
            unsafe { gemm_with((g.co, p, k), dst, p, false, wm, cols, par) };
        }
        return y;
    }
    jobs.par_iter().for_each(|&(b, (p0, p1))| {
        // The whole wrapper (which is Send), not its raw-pointer field: edition 2021 would
        // capture the field alone.
        #[allow(clippy::redundant_locals)]
        let out = out;
        let xb = &x[b * img..][..img];
        // SAFETY: W is co × k; the columns are k × t; the tile of y[b] is co × t with row stride
        // p, and no other task writes these columns of y[b].
        let dst = unsafe { out.0.add(b * g.co * p + p0) };
        let wm = Mat(w.as_ptr(), k as isize, 1);
        let t = p1 - p0;
        if g.pointwise() {
            let cols = Mat(xb[p0..].as_ptr(), p as isize, 1);
            unsafe { gemm((g.co, t, k), dst, p, false, wm, cols) };
        } else {
            with_scratch(k * t, |buf| {
                g.im2col_tile(xb, (p0, p1), buf);
                let cols = Mat(buf.as_ptr(), t as isize, 1);
                unsafe { gemm((g.co, t, k), dst, p, false, wm, cols) };
            });
        }
    });
    y
}

/// The input gradient of a stride-1 convolution as a forward convolution: of the output
/// gradient with the kernel flipped and its channel axes swapped, padded by
/// `dilation·(k − 1) − padding` on each side (None where that is negative).
fn x_backward_as_conv(w: &[f32], gy: &[f32], g: &Geometry) -> Option<Vec<f32>> {
    if g.stride != [1, 1] {
        return None;
    }
    let full = [g.dil[0] * (g.kh - 1), g.dil[1] * (g.kw - 1)];
    let pad = [
        full[0].checked_sub(g.pad[0])?,
        full[1].checked_sub(g.pad[1])?,
    ];
    let pad_end = [
        full[0].checked_sub(g.pad_end[0])?,
        full[1].checked_sub(g.pad_end[1])?,
    ];
    let taps = g.kh * g.kw;
    let mut flipped = vec![0f32; w.len()];
    for co in 0..g.co {
        for ci in 0..g.ci {
            let src = &w[(co * g.ci + ci) * taps..][..taps];
            let dst = &mut flipped[(ci * g.co + co) * taps..][..taps];
            for (d, s) in dst.iter_mut().zip(src.iter().rev()) {
                *d = *s;
            }
        }
    }
    let back = Geometry {
        n: g.n,
        ci: g.co,
        h: g.oh,
        w: g.ow,
        co: g.ci,
        kh: g.kh,
        kw: g.kw,
        oh: g.h,
        ow: g.w,
        stride: [1, 1],
        pad,
        pad_end,
        dil: g.dil,
        padded: pad.iter().chain(&pad_end).any(|&v| v > 0),
    };
    Some(forward(gy, &flipped, &back))
}

/// Input gradient: `dx[b] = col2im(Wᵀ · g[b])`, split by input channels (each task owns its
/// channels' planes, so the overlapping windows of col2im never race), tile by tile.
fn x_backward(w: &[f32], gy: &[f32], g: &Geometry) -> Vec<f32> {
    let (k, p, taps) = (g.k(), g.p(), g.kh * g.kw);
    let plane = g.h * g.w;
    let mut dx = vec![0f32; g.n * g.ci * plane];
    let per = g.ci.div_ceil(rayon::current_num_threads() * 4).max(1);
    let tiles = g.tiles();
    let jobs: Vec<(usize, usize)> = (0..g.n)
        .flat_map(|b| (0..g.ci).step_by(per).map(move |c0| (b, c0)))
        .collect();
    let out = Shared(dx.as_mut_ptr());
    jobs.par_iter().for_each(|&(b, c0)| {
        // The whole wrapper (which is Send), not its raw-pointer field: edition 2021 would
        // capture the field alone.
        #[allow(clippy::redundant_locals)]
        let out = out;
        let c1 = (c0 + per).min(g.ci);
        let gb = &gy[b * g.co * p..][..g.co * p];
        // SAFETY: channels c0..c1 of image b are written by this task alone.
        let dxb = unsafe {
            std::slice::from_raw_parts_mut(out.0.add((b * g.ci + c0) * plane), (c1 - c0) * plane)
        };
        // Rows c0·taps.. of Wᵀ (k × co): W read with swapped strides.
        let wt = Mat(w[c0 * taps..].as_ptr(), 1, k as isize);
        let rows = (c1 - c0) * taps;
        for &(p0, p1) in &tiles {
            let t = p1 - p0;
            let gm = Mat(gb[p0..].as_ptr(), p as isize, 1);
            if g.pointwise() {
                // SAFETY: rows c0..c1, columns p0..p1 of dx[b] (row stride p).
                unsafe { gemm((rows, t, g.co), dxb[p0..].as_mut_ptr(), p, false, wt, gm) };
            } else {
                with_scratch(rows * t, |buf| {
                    unsafe { gemm((rows, t, g.co), buf.as_mut_ptr(), t, false, wt, gm) };
                    g.col2im_tile(buf, (p0, p1), dxb);
                });
            }
        }
    });
    dx
}

/// Weight gradient: `dW = Σ_b Σ_tiles g[b][:, tile] · col(x[b])[:, tile]ᵀ`, tiles in parallel,
/// each worker summing into its own `co × k` matrix, added up at the end.
fn weight_backward(x: &[f32], gy: &[f32], g: &Geometry) -> Vec<f32> {
    let (k, p, img) = (g.k(), g.p(), g.ci * g.h * g.w);
    let tiles = g.tiles();
    let jobs: Vec<(usize, (usize, usize))> = (0..g.n)
        .flat_map(|b| tiles.iter().map(move |&t| (b, t)))
        .collect();
    jobs.par_iter()
        .fold(
            || (vec![0f32; g.co * k], false),
            |(mut dw, started), &(b, (p0, p1))| {
                let (xb, t) = (&x[b * img..][..img], p1 - p0);
                let gm = Mat(gy[b * g.co * p + p0..].as_ptr(), p as isize, 1);
                if g.pointwise() {
                    // colᵀ is t × k: x[b] read with swapped strides.
                    let ct = Mat(xb[p0..].as_ptr(), 1, p as isize);
                    unsafe { gemm((g.co, k, t), dw.as_mut_ptr(), k, started, gm, ct) };
                } else {
                    with_scratch(k * t, |buf| {
                        g.im2col_tile(xb, (p0, p1), buf);
                        let ct = Mat(buf.as_ptr(), 1, t as isize);
                        unsafe { gemm((g.co, k, t), dw.as_mut_ptr(), k, started, gm, ct) };
                    });
                }
                (dw, true)
            },
        )
        .map(|(dw, _)| dw)
        .reduce(
            || vec![0f32; g.co * k],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
                a
            },
        )
}

/// Which kernel a layer takes on Flex.
fn layer(x: &FlexTensor, w: &FlexTensor, o: &ConvOptions<2>) -> Option<(Geometry, bool)> {
    let (xs, ws) = (x.layout().shape().as_slice(), w.layout().shape().as_slice());
    if x.dtype() != DType::F32 || w.dtype() != DType::F32 {
        return None;
    }
    match Geometry::new(xs, ws, o) {
        Some(g) => Some((g, false)),
        None => Geometry::depthwise(xs, ws, o).map(|g| (g, true)),
    }
}

impl ConvKernels for Flex {
    fn cac_conv2d(x: FlexTensor, w: FlexTensor, options: ConvOptions<2>) -> FlexTensor {
        match layer(&x, &w, &options) {
            Some((g, false)) => {
                let (x, w) = (contiguous(x), contiguous(w));
                tensor(forward(slice(&x), slice(&w), &g), &[g.n, g.co, g.oh, g.ow])
            }
            // Depthwise: Flex's own fast path.
            _ => Flex::conv2d(x, w, None, options),
        }
    }
    fn cac_conv2d_x_backward(
        x: FlexTensor,
        w: FlexTensor,
        gy: FlexTensor,
        options: ConvOptions<2>,
    ) -> FlexTensor {
        let Some((g, depthwise)) = layer(&x, &w, &options).filter(|_| gy.dtype() == DType::F32)
        else {
            return Flex::conv2d_x_backward(x, w, gy, options);
        };
        let (w, gy) = (contiguous(w), contiguous(gy));
        let (w, gy) = (slice(&w), slice(&gy));
        let dx = match depthwise {
            true => depthwise_x_backward(w, gy, &g),
            false => x_backward_as_conv(w, gy, &g).unwrap_or_else(|| x_backward(w, gy, &g)),
        };
        tensor(dx, &[g.n, g.ci, g.h, g.w])
    }
    fn cac_conv2d_weight_backward(
        x: FlexTensor,
        w: FlexTensor,
        gy: FlexTensor,
        options: ConvOptions<2>,
    ) -> FlexTensor {
        match layer(&x, &w, &options).filter(|_| gy.dtype() == DType::F32) {
            Some((g, false)) => {
                let (x, gy) = (contiguous(x), contiguous(gy));
                let dw = weight_backward(slice(&x), slice(&gy), &g);
                tensor(dw, &[g.co, g.ci, g.kh, g.kw])
            }
            _ => Flex::conv2d_weight_backward(x, w, gy, options),
        }
    }
}

/// Input gradient of a depthwise convolution: each output-gradient plane, scaled by each tap's
/// weight, added onto its channel's input plane at the tap's offset (strided for stride > 1);
/// one task per (image, channel).
fn depthwise_x_backward(w: &[f32], gy: &[f32], g: &Geometry) -> Vec<f32> {
    let (taps, plane, out) = (g.kh * g.kw, g.h * g.w, g.oh * g.ow);
    let mut dx = vec![0f32; g.n * g.ci * plane];
    dx.par_chunks_mut(plane).enumerate().for_each(|(bc, dst)| {
        let c = bc % g.ci;
        let src = &gy[bc * out..][..out];
        for tap in 0..taps {
            let (ky, kx, wv) = (tap / g.kw, tap % g.kw, w[c * taps + tap]);
            let x0 = (kx * g.dil[1]) as isize - g.pad[1] as isize;
            let (a, b) = g.inside(x0, 0, g.ow);
            if a >= b {
                continue;
            }
            let (start, s) = ((x0 + (a * g.stride[1]) as isize) as usize, g.stride[1]);
            for oy in 0..g.oh {
                let Some(iy) = g.input_row(oy, ky) else {
                    continue;
                };
                let row = &src[oy * g.ow + a..oy * g.ow + b];
                let dst = &mut dst[iy * g.w + start..=iy * g.w + start + (row.len() - 1) * s];
                for (d, v) in dst.iter_mut().step_by(s).zip(row) {
                    *d += wv * v;
                }
            }
        }
    });
    dx
}

/// The convolution as an autodiff op: keeps `x` and `w`, and computes the gradient of each
/// tracked one with the kernels above.
#[derive(Debug)]
struct Conv;

impl<B: Backend + ConvKernels> Backward<B, 2> for Conv {
    type State = (NodeId, NodeId, ConvOptions<2>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, cp: &mut Checkpointer) {
        let (xs, ws, options) = ops.state;
        let x: FloatTensor<B> = cp.retrieve_node_output(xs);
        let w: FloatTensor<B> = cp.retrieve_node_output(ws);
        let (x2, w2, o2) = (x.clone(), w.clone(), options.clone());
        binary::<B, _, _>(
            ops.parents,
            ops.node,
            grads,
            |g| B::cac_conv2d_x_backward(x, w, g, options),
            |g| B::cac_conv2d_weight_backward(x2, w2, g, o2),
        );
    }
}

impl<B: Backend + ConvKernels, C: CheckpointStrategy> ConvKernels for Autodiff<B, C> {
    fn cac_conv2d(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        match Conv
            .prepare::<C>([x.node(), w.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let (xs, ws) = (prep.checkpoint(&x), prep.checkpoint(&w));
                let y = B::cac_conv2d(x.into_primitive(), w.into_primitive(), options.clone());
                prep.finish((xs, ws, options), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::cac_conv2d(
                x.into_primitive(),
                w.into_primitive(),
                options,
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::seeded;
    use burn::tensor::Device;

    fn max_rel(a: Tensor<4>, b: Tensor<4>) -> f32 {
        let (a, b) = (
            a.into_data().try_into_vec::<f32>().unwrap(),
            b.into_data().try_into_vec::<f32>().unwrap(),
        );
        assert_eq!(a.len(), b.len());
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-6);
        a.iter()
            .zip(&b)
            .fold(0f32, |m, (p, q)| m.max((p - q).abs()))
            / scale
    }

    /// Output, input gradient and weight gradient against burn's own convolution, for strides,
    /// paddings (asymmetric included), dilations, 1×1 and a batch of 2, on seeded data.
    #[test]
    fn matches_burns_convolution_and_its_gradients() {
        let dev = Device::autodiff(Device::from(burn::backend::FlexDevice));
        #[allow(clippy::type_complexity)]
        let cases: [([usize; 4], [usize; 4], [usize; 2], [usize; 2], [usize; 2]); 6] = [
            ([1, 5, 17, 13], [7, 5, 3, 3], [1, 1], [1, 1], [1, 1]),
            ([2, 4, 16, 16], [6, 4, 3, 3], [2, 2], [1, 1], [1, 1]),
            ([1, 3, 20, 18], [8, 3, 3, 3], [2, 2], [1, 1], [1, 1]),
            ([2, 6, 9, 11], [5, 6, 1, 1], [1, 1], [0, 0], [1, 1]),
            ([1, 4, 15, 15], [3, 4, 3, 3], [1, 1], [2, 2], [2, 2]),
            ([1, 2, 9, 9], [4, 2, 5, 3], [1, 2], [2, 0], [1, 1]),
        ];
        let asymmetric = ConvOptions::new_with_padding([2, 2], [(0, 1), (1, 0)], [1, 1], 1);
        let cases = cases
            .into_iter()
            .map(|(xs, ws, stride, pad, dil)| (xs, ws, ConvOptions::new(stride, pad, dil, 1)));
        // TensorFlow's SAME padding of a stride-2 layer: one more row and column at the end.
        let cases = cases.chain([([1, 3, 12, 13], [4, 3, 3, 3], asymmetric)]);
        for (k, (xs, ws, options)) in cases.enumerate() {
            let x0 = seeded(xs, 10 + k as u64, 1.0, &dev);
            let w0 = seeded(ws, 20 + k as u64, 1.0, &dev);
            let bias = seeded([1, 1, 1, ws[0]], 30 + k as u64, 1.0, &dev).reshape([ws[0]]);
            let run = |fast: bool| {
                let (x, w) = (x0.clone().require_grad(), w0.clone().require_grad());
                let y = if fast {
                    conv2d(x.clone(), w.clone(), Some(bias.clone()), options.clone())
                } else {
                    burn::tensor::module::conv2d(
                        x.clone(),
                        w.clone(),
                        Some(bias.clone()),
                        options.clone(),
                    )
                };
                let weights = seeded(y.dims(), 99, 1.0, &dev);
                let grads = (y.clone() * weights).sum().backward();
                (y, x.grad(&grads).unwrap(), w.grad(&grads).unwrap())
            };
            let (y, gx, gw) = run(true);
            let (y0, gx0, gw0) = run(false);
            assert_eq!(y.dims(), y0.dims(), "case {k}");
            for (what, e) in [
                ("output", max_rel(y, y0)),
                ("input gradient", max_rel(gx, gx0)),
                ("weight gradient", max_rel(gw, gw0)),
            ] {
                assert!(e < 1e-5, "case {k}: {what} differs by {e:e} of the largest");
            }
        }
    }

    /// Depthwise layers (Flex's forward, this module's input gradient): output and both
    /// gradients against burn's, for strides 1 and 2, SAME padding, dilation and 5×5.
    #[test]
    fn depthwise_matches_burns_convolution_and_its_gradients() {
        let dev = Device::autodiff(Device::from(burn::backend::FlexDevice));
        let cases = [
            (
                [1, 6, 15, 13],
                [6, 1, 3, 3],
                ConvOptions::new([1, 1], [1, 1], [1, 1], 6),
            ),
            (
                [2, 4, 16, 16],
                [4, 1, 3, 3],
                ConvOptions::new([2, 2], [0, 0], [1, 1], 4),
            ),
            (
                [1, 3, 12, 13],
                [3, 1, 3, 3],
                ConvOptions::new_with_padding([2, 2], [(0, 1), (1, 0)], [1, 1], 3),
            ),
            (
                [1, 5, 14, 14],
                [5, 1, 5, 5],
                ConvOptions::new([1, 1], [2, 2], [1, 1], 5),
            ),
            (
                [1, 2, 15, 15],
                [2, 1, 3, 3],
                ConvOptions::new([1, 2], [2, 1], [2, 1], 2),
            ),
        ];
        for (k, (xs, ws, options)) in cases.into_iter().enumerate() {
            let x0 = seeded(xs, 40 + k as u64, 1.0, &dev);
            let w0 = seeded(ws, 50 + k as u64, 1.0, &dev);
            let run = |fast: bool| {
                let (x, w) = (x0.clone().require_grad(), w0.clone().require_grad());
                let y = if fast {
                    conv2d(x.clone(), w.clone(), None, options.clone())
                } else {
                    burn::tensor::module::conv2d(x.clone(), w.clone(), None, options.clone())
                };
                let weights = seeded(y.dims(), 98, 1.0, &dev);
                let grads = (y.clone() * weights).sum().backward();
                (y, x.grad(&grads).unwrap(), w.grad(&grads).unwrap())
            };
            let ((y, gx, gw), (y0, gx0, gw0)) = (run(true), run(false));
            for (what, e) in [
                ("output", max_rel(y, y0)),
                ("input gradient", max_rel(gx, gx0)),
                ("weight gradient", max_rel(gw, gw0)),
            ] {
                assert!(
                    e < 1e-5,
                    "depthwise case {k}: {what} differs by {e:e} of the largest"
                );
            }
        }
    }

    /// Without autodiff, and for a grouped convolution (burn's path), the same values.
    #[test]
    fn inference_and_grouped_convolutions_agree() {
        let dev = Device::from(burn::backend::FlexDevice);
        let x = seeded([1, 4, 12, 12], 1, 1.0, &dev);
        for (w, groups) in [
            (seeded([6, 4, 3, 3], 2, 1.0, &dev), 1),
            (seeded([4, 1, 3, 3], 3, 1.0, &dev), 4),
        ] {
            let o = ConvOptions::new([1, 1], [1, 1], [1, 1], groups);
            let a = conv2d(x.clone(), w.clone(), None, o.clone());
            let b = burn::tensor::module::conv2d(x.clone(), w, None, o);
            assert!(max_rel(a, b) < 1e-5, "groups {groups}");
        }
    }
}
