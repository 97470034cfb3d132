//! Differentiable image pre-processing shared by the detectors and the graph executor:
//! bilinear resize with the exact tfjs-cpu index formula, image ↔ tensor conversion.
//!
//! The resize is two gathers (`select`) and a lerp per axis, so gradients flow back to the
//! source image; an integer up-scaling whose table is a shift per phase (the detectors' 2×
//! feature up-sampling) runs as shifted slices and an interleave instead, with the same lerp
//! and the same values. Index and weight tables are computed in f64 like tfjs-cpu; the lerps
//! run in f32 on the device (tfjs-cpu runs them in f64 and rounds once: ~1 ulp apart). Where
//! the backend has a fast interpolation kernel of its own (libtorch), power-of-two up-scalings
//! run on it instead ([`crate::upscale`]).

use crate::upscale::{native_factors, upscale, Formula};
use burn::tensor::{Device, Int, Tensor, TensorData};

/// Source indices (floor, ceil) and fractional weights of one resized axis, tfjs-cpu formula.
pub(crate) fn resize_table(
    input: usize,
    output: usize,
    align_corners: bool,
    half_pixel_centers: bool,
) -> (Vec<i64>, Vec<i64>, Vec<f32>) {
    let (eff_in, eff_out) = if align_corners && output > 1 {
        (input - 1, output - 1)
    } else {
        (input, output)
    };
    let ratio = eff_in as f64 / eff_out as f64;
    let mut lo = Vec::with_capacity(output);
    let mut hi = Vec::with_capacity(output);
    let mut frac = Vec::with_capacity(output);
    for r in 0..output {
        let src = if half_pixel_centers {
            ratio * (r as f64 + 0.5) - 0.5
        } else {
            ratio * r as f64
        };
        let floor = src.floor().max(0.0);
        let ceil = (src.ceil() as i64).min(input as i64 - 1);
        lo.push(floor as i64);
        hi.push(ceil.max(0));
        frac.push((src - floor) as f32);
    }
    (lo, hi, frac)
}

/// Bilinear resize of the axes `h_axis`, `w_axis` of a rank-4 tensor to `(out_h, out_w)`,
/// with TF `align_corners` / `half_pixel_centers` semantics (tfjs-cpu index formula).
pub fn resize_bilinear(
    x: Tensor<4>,
    h_axis: usize,
    w_axis: usize,
    out_h: usize,
    out_w: usize,
    align_corners: bool,
    half_pixel_centers: bool,
) -> Tensor<4> {
    if let Some(formula) = Formula::of(align_corners, half_pixel_centers) {
        if (h_axis, w_axis) == (2, 3) {
            if let Some(k) = native_factors(&x, out_h, out_w) {
                return upscale(x, k, formula);
            }
        }
    }
    let x = resize_axis(x, w_axis, out_w, align_corners, half_pixel_centers);
    resize_axis(x, h_axis, out_h, align_corners, half_pixel_centers)
}

fn resize_axis(x: Tensor<4>, axis: usize, out: usize, align: bool, half: bool) -> Tensor<4> {
    let input = x.dims()[axis];
    if input == out {
        return x; // every formula reduces to the identity
    }
    let (lo, hi, frac) = resize_table(input, out, align, half);
    match phase_shifts(input, out, &lo, &hi, &frac) {
        Some(phases) => resize_by_phases(x, axis, &phases),
        None => resize_by_gather(x, axis, (lo, hi, frac)),
    }
}

/// The general resize of one axis: gather the two source rows of every output, then lerp.
fn resize_by_gather(
    x: Tensor<4>,
    axis: usize,
    (lo, hi, frac): (Vec<i64>, Vec<i64>, Vec<f32>),
) -> Tensor<4> {
    let out = lo.len();
    let device = x.device();
    let idx = |v: Vec<i64>| Tensor::<1, Int>::from_data(TensorData::new(v, [out]), &device);
    let a = x.clone().select(axis, idx(lo));
    let b = x.select(axis, idx(hi));
    let mut wshape = [1usize; 4];
    wshape[axis] = out;
    let w = Tensor::<1>::from_data(TensorData::new(frac, [out]), &device).reshape(wshape);
    a.clone() + (b - a) * w
}

/// One output phase `r = k·i + p` of an integer up-scaling by `k`: reads input `i + lo` and
/// `i + hi` (clamped to the axis) with weight `frac`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Phase {
    lo: isize,
    hi: isize,
    frac: f32,
}

/// The per-phase shifts that reproduce the table exactly, when the output is an integer
/// multiple `k` of the input: for every output, the same indices and weight, or a table entry
/// with `lo == hi` that the shifts also map to that one index (the lerp then gives `x[lo]`
/// whatever the weight). None where the table is not of that form.
fn phase_shifts(
    input: usize,
    out: usize,
    lo: &[i64],
    hi: &[i64],
    frac: &[f32],
) -> Option<Vec<Phase>> {
    if input < 2 || out <= input || out % input != 0 {
        return None;
    }
    let k = out / input;
    let clamp = |v: isize| v.clamp(0, input as isize - 1) as i64;
    let mid = input / 2;
    (0..k)
        .map(|p| {
            let r = k * mid + p;
            let ph = Phase {
                lo: lo[r] as isize - mid as isize,
                hi: hi[r] as isize - mid as isize,
                frac: frac[r],
            };
            let fits = (0..input).all(|i| {
                let r = k * i + p;
                let (l, h) = (clamp(i as isize + ph.lo), clamp(i as isize + ph.hi));
                (lo[r], hi[r], frac[r]) == (l, h, ph.frac)
                    || (lo[r] == hi[r] && l == lo[r] && h == lo[r])
            });
            fits.then_some(ph)
        })
        .collect()
}

/// `x` shifted by `d` along `axis`, reading clamped indices: `y[i] = x[clamp(i + d)]`.
fn shifted(x: Tensor<4>, axis: usize, d: isize) -> Tensor<4> {
    let n = x.dims()[axis];
    let m = d.unsigned_abs();
    if d == 0 {
        x
    } else if m >= n {
        // Every index clamps to the same end.
        let at = if d > 0 { n - 1 } else { 0 };
        x.narrow(axis, at, 1).repeat_dim(axis, n)
    } else if d > 0 {
        let edge = x.clone().narrow(axis, n - 1, 1).repeat_dim(axis, m);
        Tensor::cat(vec![x.narrow(axis, m, n - m), edge], axis)
    } else {
        let edge = x.clone().narrow(axis, 0, 1).repeat_dim(axis, m);
        Tensor::cat(vec![edge, x.narrow(axis, 0, n - m)], axis)
    }
}

/// The integer up-scaling of `phase_shifts`: each phase is a lerp of two shifted copies (or one
/// copy, when its weight is 0 and both shifts agree), and the phases are interleaved.
fn resize_by_phases(x: Tensor<4>, axis: usize, phases: &[Phase]) -> Tensor<4> {
    let parts: Vec<Tensor<4>> = phases
        .iter()
        .map(|p| {
            let a = shifted(x.clone(), axis, p.lo);
            if p.lo == p.hi || p.frac == 0.0 {
                a
            } else {
                let b = shifted(x.clone(), axis, p.hi);
                a.clone() + (b - a).mul_scalar(p.frac)
            }
        })
        .collect();
    let mut dims = x.dims();
    dims[axis] *= phases.len();
    Tensor::stack::<5>(parts, axis + 1).reshape(dims)
}

/// An 8-bit RGB image as a `[1, 3, H, W]` tensor in [0, 1] (value / 255).
pub fn image_to_tensor(img: &image::RgbImage, device: &Device) -> Tensor<4> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let mut data = vec![0f32; 3 * h * w];
    for (x, y, p) in img.enumerate_pixels() {
        for c in 0..3 {
            data[(c * h + y as usize) * w + x as usize] = p.0[c] as f32 / 255.0;
        }
    }
    Tensor::from_data(TensorData::new(data, [1, 3, h, w]), device)
}

/// Stacks several images of the same size into one `[B, 3, H, W]` tensor in [0, 1].
pub fn images_to_tensor(imgs: &[image::RgbImage], device: &Device) -> Tensor<4> {
    Tensor::cat(imgs.iter().map(|i| image_to_tensor(i, device)).collect(), 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The phase path gives exactly the gather path's values, for the up-scalings it takes.
    #[test]
    fn phase_resize_equals_gather_resize() {
        use rand::{Rng, SeedableRng};
        let device = Device::from(burn::backend::FlexDevice);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut taken = 0;
        for (n, k) in [
            (2usize, 2usize),
            (5, 2),
            (13, 2),
            (7, 3),
            (4, 4),
            (1, 2),
            (6, 1),
        ] {
            for (align, half) in [(false, false), (false, true), (true, false)] {
                let out = n * k;
                // Seeded host values (the device's generator is shared by parallel tests).
                let v: Vec<f32> = (0..2 * n * 3)
                    .map(|_| rng.random_range(-1.0f32..1.0))
                    .collect();
                let x = Tensor::<4>::from_data(TensorData::new(v, [1, 2, n, 3]), &device);
                let (lo, hi, frac) = resize_table(n, out, align, half);
                let want = resize_by_gather(x.clone(), 2, (lo.clone(), hi.clone(), frac.clone()));
                let got = resize_axis(x, 2, out, align, half);
                assert_eq!(got.dims(), [1, 2, out, 3]);
                let (a, b) = (got.into_data(), want.into_data());
                assert_eq!(a, b, "n {n} k {k} align {align} half {half}");
                taken += phase_shifts(n, out, &lo, &hi, &frac).is_some() as usize;
            }
        }
        // The detectors' cases (2× with and without half-pixel centres) do take the phase path.
        for half in [false, true] {
            let (lo, hi, frac) = resize_table(26, 52, false, half);
            assert!(
                phase_shifts(26, 52, &lo, &hi, &frac).is_some(),
                "half {half}"
            );
        }
        assert!(
            taken >= 6,
            "only {taken} configurations took the phase path"
        );
    }

    /// `shifted` reads clamped indices, also for shifts as long as the axis.
    #[test]
    fn shifts_clamp_to_the_ends() {
        let device = Device::from(burn::backend::FlexDevice);
        let x = Tensor::<4>::from_data(TensorData::new(vec![1f32, 2., 3.], [1, 1, 3, 1]), &device);
        let read = |d: isize| {
            shifted(x.clone(), 2, d)
                .into_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        assert_eq!(read(1), [2., 3., 3.]);
        assert_eq!(read(-1), [1., 1., 2.]);
        assert_eq!(read(5), [3., 3., 3.]);
        assert_eq!(read(-3), [1., 1., 1.]);
    }

    #[test]
    fn resize_tables_follow_tfjs_cpu() {
        // Downscale 4 -> 2, no half pixel: src = 0, 2.
        let (lo, hi, f) = resize_table(4, 2, false, false);
        assert_eq!((lo, hi, f), (vec![0, 2], vec![0, 2], vec![0.0, 0.0]));
        // Upscale 2 -> 4: src = 0, .5, 1, 1.5 ; ceil clamped to 1.
        let (lo, hi, f) = resize_table(2, 4, false, false);
        assert_eq!(lo, vec![0, 0, 1, 1]);
        assert_eq!(hi, vec![0, 1, 1, 1]);
        assert_eq!(f, vec![0.0, 0.5, 0.0, 0.5]);
        // Half pixel, upscale 2 -> 4: src = -.25, .25, .75, 1.25 ; floor clamped to 0.
        let (lo, hi, f) = resize_table(2, 4, false, true);
        assert_eq!(lo, vec![0, 0, 0, 1]);
        assert_eq!(hi, vec![0, 1, 1, 1]);
        assert_eq!(f, vec![-0.25, 0.25, 0.75, 0.25]);
    }
}
