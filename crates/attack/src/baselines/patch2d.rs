//! Plane transformations of a 2D patch and its pasting into images, differentiable with respect to
//! the patch (the training half of the 2D baselines, AdvPat and ShapeShifter).
//!
//! A [`PlaneTransform`] is Thys et al.'s set: a random rotation, scale and translation of the patch
//! square, contrast × and brightness + on the patch, and uniform per-texel noise; the patch is then
//! clipped to [0, 1]. Pasting is linear in the patch, like the renderer's composite: every pixel
//! whose centre falls inside the rotated square gets the bilinear interpolation of the four nearest
//! patch texels (weights summing to one) instead of the background, so the image is a convex
//! combination of values in [0, 1] and autodiff gives the exact gradient. Not here: the loss, the
//! optimiser, or how the patch is later put on the 3D object ([`super::atlas`]).

use anyhow::{bail, Result};
use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// One random placement and photometric change of the patch in one image.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneTransform {
    /// Centre in pixels.
    pub cx: f32,
    pub cy: f32,
    /// Side of the pasted square in pixels.
    pub side: f32,
    /// Rotation in radians.
    pub angle: f32,
    pub contrast: f32,
    pub brightness: f32,
    /// Amplitude of uniform per-texel noise in [−a, a].
    pub noise: f32,
    pub noise_seed: u64,
}

/// The ranges the transforms are drawn from (Thys et al. 2019's values by default).
#[derive(Clone, Debug, PartialEq)]
pub struct TransformRanges {
    /// Patch side as a fraction of √(box width · box height).
    pub scale: [f32; 2],
    /// ± centre jitter as a fraction of the box size.
    pub jitter: f32,
    pub rotation_deg: f32,
    pub contrast: [f32; 2],
    pub brightness: f32,
    pub noise: f32,
}

impl Default for TransformRanges {
    fn default() -> Self {
        TransformRanges {
            scale: [0.45, 0.75],
            jitter: 0.1,
            rotation_deg: 20.0,
            contrast: [0.8, 1.2],
            brightness: 0.1,
            noise: 0.1,
        }
    }
}

impl TransformRanges {
    /// Draws a transform placing the patch on the object whose box is `bbox` (`x1, y1, x2, y2`).
    pub fn sample(&self, bbox: [f32; 4], rng: &mut ChaCha8Rng) -> PlaneTransform {
        let (w, h) = ((bbox[2] - bbox[0]).max(1.0), (bbox[3] - bbox[1]).max(1.0));
        let u = |rng: &mut ChaCha8Rng, a: f32, b: f32| a + (b - a) * rng.random::<f32>();
        let j = self.jitter;
        PlaneTransform {
            cx: 0.5 * (bbox[0] + bbox[2]) + u(rng, -j, j) * w,
            cy: 0.5 * (bbox[1] + bbox[3]) + u(rng, -j, j) * h,
            side: u(rng, self.scale[0], self.scale[1]) * (w * h).sqrt(),
            angle: u(rng, -self.rotation_deg, self.rotation_deg).to_radians(),
            contrast: u(rng, self.contrast[0], self.contrast[1]),
            brightness: u(rng, -self.brightness, self.brightness),
            noise: self.noise,
            noise_seed: rng.random(),
        }
    }
}

/// The texel taps of one pasted patch: `(pixel, texel, weight)` and the covered pixels.
struct Taps {
    pixel: Vec<i64>,
    texel: Vec<i64>,
    weight: Vec<f32>,
    covered: Vec<usize>,
}

fn taps(t: &PlaneTransform, w: usize, h: usize, p: usize) -> Taps {
    let mut out = Taps {
        pixel: vec![],
        texel: vec![],
        weight: vec![],
        covered: vec![],
    };
    let r = t.side * std::f32::consts::FRAC_1_SQRT_2 + 1.0;
    let (x0, x1) = (
        (t.cx - r).floor().max(0.0) as usize,
        ((t.cx + r).ceil().max(0.0) as usize).min(w),
    );
    let (y0, y1) = (
        (t.cy - r).floor().max(0.0) as usize,
        ((t.cy + r).ceil().max(0.0) as usize).min(h),
    );
    let (s, c) = t.angle.sin_cos();
    let pf = p as f32;
    for y in y0..y1 {
        for x in x0..x1 {
            let (dx, dy) = (x as f32 + 0.5 - t.cx, y as f32 + 0.5 - t.cy);
            // Into the patch's frame (rotate by −angle), normalised to [−0.5, 0.5).
            let (lx, ly) = ((c * dx + s * dy) / t.side, (-s * dx + c * dy) / t.side);
            if !(-0.5..0.5).contains(&lx) || !(-0.5..0.5).contains(&ly) {
                continue;
            }
            let (px, py) = ((lx + 0.5) * pf - 0.5, (ly + 0.5) * pf - 0.5);
            let (fx, fy) = (px.floor(), py.floor());
            let (ax, ay) = (px - fx, py - fy);
            let pix = (y * w + x) as i64;
            out.covered.push(y * w + x);
            for (ox, oy, wt) in [
                (0, 0, (1.0 - ax) * (1.0 - ay)),
                (1, 0, ax * (1.0 - ay)),
                (0, 1, (1.0 - ax) * ay),
                (1, 1, ax * ay),
            ] {
                let tx = (fx as i64 + ox).clamp(0, p as i64 - 1);
                let ty = (fy as i64 + oy).clamp(0, p as i64 - 1);
                out.pixel.push(pix);
                out.texel.push(ty * p as i64 + tx);
                out.weight.push(wt);
            }
        }
    }
    out
}

/// The patch (`[1, P, P, 3]`, values in [0, 1]) after each transform's contrast, brightness and
/// noise, clipped: `[B, P, P, 3]`.
pub fn photometric(patch: Tensor<4>, ts: &[PlaneTransform]) -> Tensor<4> {
    use rand::SeedableRng;
    let [_, p, _, _] = patch.dims();
    let (device, dtype, b) = (patch.device(), patch.dtype(), ts.len());
    let col = |f: &dyn Fn(&PlaneTransform) -> f32| {
        let v: Vec<f32> = ts.iter().map(f).collect();
        Tensor::<4>::from_data(TensorData::new(v, [b, 1, 1, 1]), (&device, dtype))
    };
    let mut noise = Vec::with_capacity(b * p * p * 3);
    for t in ts {
        let mut rng = ChaCha8Rng::seed_from_u64(t.noise_seed);
        noise.extend((0..p * p * 3).map(|_| t.noise * (2.0 * rng.random::<f32>() - 1.0)));
    }
    let noise = Tensor::<4>::from_data(TensorData::new(noise, [b, p, p, 3]), (&device, dtype));
    (patch.repeat_dim(0, b) * col(&|t| t.contrast) + col(&|t| t.brightness) + noise).clamp(0.0, 1.0)
}

/// Pastes the patch into `background` (host `[B, 3, H, W]` values in [0, 1], no gradient) under
/// one transform per image. Returns `[B, 3, H, W]` on `device`, differentiable in `patch`.
pub fn paste(
    background: &[f32],
    dims: [usize; 4],
    patch: Tensor<4>,
    ts: &[PlaneTransform],
    device: &Device,
) -> Result<Tensor<4>> {
    let [b, c, h, w] = dims;
    let [one, p, p2, c2] = patch.dims();
    if c != 3 || c2 != 3 || one != 1 || p != p2 || p == 0 {
        bail!(
            "paste needs a [1, P, P, 3] patch and [B, 3, H, W] images, got {:?} and {dims:?}",
            patch.dims()
        );
    }
    if background.len() != b * c * h * w || ts.len() != b {
        bail!(
            "paste: {} background values and {} transforms for {dims:?}",
            background.len(),
            ts.len()
        );
    }
    let px = h * w;
    // Background as [B·H·W, 3] rows, zeroed where the patch covers the pixel.
    let mut base = vec![0.0f32; b * px * 3];
    for k in 0..b {
        for ch in 0..3 {
            for i in 0..px {
                base[(k * px + i) * 3 + ch] = background[(k * 3 + ch) * px + i];
            }
        }
    }
    let (mut ip, mut it, mut wt) = (vec![], vec![], vec![]);
    for (k, t) in ts.iter().enumerate() {
        let tp = taps(t, w, h, p);
        for i in tp.covered {
            base[(k * px + i) * 3..(k * px + i) * 3 + 3].fill(0.0);
        }
        ip.extend(tp.pixel.iter().map(|&i| i + (k * px) as i64));
        it.extend(tp.texel.iter().map(|&i| i + (k * p * p) as i64));
        wt.extend(tp.weight);
    }
    let dtype = patch.dtype();
    let base = Tensor::<2>::from_data(TensorData::new(base, [b * px, 3]), (device, dtype));
    let flat = photometric(patch, ts).reshape([b * p * p, 3]);
    let img = if ip.is_empty() {
        base + flat.sum().reshape([1, 1]) * 0.0
    } else {
        let n = ip.len();
        let ip = Tensor::<1, Int>::from_data(TensorData::new(ip, [n]), device);
        let it = Tensor::<1, Int>::from_data(TensorData::new(it, [n]), device);
        let wt = Tensor::<2>::from_data(TensorData::new(wt, [n, 1]), (device, dtype));
        base.select_assign(0, ip, flat.select(0, it) * wt, IndexingUpdateOp::Add)
    };
    Ok(img.reshape([b, h, w, 3]).permute([0, 3, 1, 2]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn taps_of_a_covered_pixel_sum_to_one() {
        let t = PlaneTransform {
            cx: 20.0,
            cy: 20.0,
            side: 10.0,
            angle: 0.3,
            contrast: 1.0,
            brightness: 0.0,
            noise: 0.0,
            noise_seed: 0,
        };
        let tp = taps(&t, 40, 40, 8);
        assert!(!tp.covered.is_empty());
        // Area of the rotated square is side² = 100 pixels, up to pixel-centre sampling.
        assert!(
            (tp.covered.len() as i64 - 100).abs() < 12,
            "{}",
            tp.covered.len()
        );
        for (k, _) in tp.covered.iter().enumerate() {
            let s: f32 = tp.weight[k * 4..k * 4 + 4].iter().sum();
            assert!((s - 1.0).abs() < 1e-5);
        }
        let _ = TransformRanges::default()
            .sample([0.0, 0.0, 10.0, 10.0], &mut ChaCha8Rng::seed_from_u64(1));
    }
}
