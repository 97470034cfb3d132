//! Total-variation minimisation (Guo et al. 2018): keep a random share of the pixels and find the
//! image of least total variation that stays close to them,
//! `min_z ½ Σ m·(z − x)² + λ Σ |∇z|` (isotropic TV per channel, `m` the kept pixels), solved
//! by the primal-dual method of Chambolle and Pock (2011) with steps `τ = σ = 0.99/√8`.

use super::Planes;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The solver's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TvSettings {
    /// λ, the weight of the total variation (image values in [0, 1]).
    pub weight: f32,
    /// The share of pixels kept (the rest are filled by the solver).
    pub keep: f32,
    pub iterations: usize,
    /// The seed of the kept pixels.
    pub seed: u64,
}

impl TvSettings {
    /// The defence's settings: half the pixels kept, 40 iterations.
    pub fn guo(weight: f32, seed: u64) -> TvSettings {
        TvSettings {
            weight,
            keep: 0.5,
            iterations: 40,
            seed,
        }
    }

    /// The kept pixels (one mask for all channels), 1 or 0.
    fn mask(&self, pixels: usize) -> Vec<f32> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        (0..pixels)
            .map(|_| (rng.random::<f32>() < self.keep) as u8 as f32)
            .collect()
    }
}

/// The image of least objective the solver finds, clamped to [0, 1].
pub fn tv_minimise(p: Planes, s: &TvSettings) -> Vec<f32> {
    let n = p.height * p.width;
    let m = s.mask(n);
    let mut out = Vec::with_capacity(p.data.len());
    for x in p.data.chunks_exact(n) {
        out.extend(
            solve_plane(x, &m, p.height, p.width, s)
                .into_iter()
                .map(|v| v.clamp(0.0, 1.0)),
        );
    }
    out
}

/// The objective `½ Σ m·(z − x)² + λ Σ |∇z|` of `z` for the input `p` (all channels).
pub fn tv_objective(p: Planes, z: &[f32], s: &TvSettings) -> f64 {
    let (h, w) = (p.height, p.width);
    let m = s.mask(h * w);
    let mut total = 0f64;
    for (x, z) in p.data.chunks_exact(h * w).zip(z.chunks_exact(h * w)) {
        for i in 0..h * w {
            let (gx, gy) = forward_differences(z, i, h, w);
            total += 0.5 * (m[i] * (z[i] - x[i]).powi(2)) as f64;
            total += (s.weight * (gx * gx + gy * gy).sqrt()) as f64;
        }
    }
    total
}

/// `z[right] − z`, `z[below] − z` at pixel `i` (0 at the last column and row).
fn forward_differences(z: &[f32], i: usize, h: usize, w: usize) -> (f32, f32) {
    let (y, x) = (i / w, i % w);
    let gx = if x + 1 < w { z[i + 1] - z[i] } else { 0.0 };
    let gy = if y + 1 < h { z[i + w] - z[i] } else { 0.0 };
    (gx, gy)
}

/// One channel: Chambolle-Pock iterations from the kept values (dropped ones start at the
/// kept values' mean).
fn solve_plane(x: &[f32], m: &[f32], h: usize, w: usize, s: &TvSettings) -> Vec<f32> {
    let kept: f32 = m.iter().sum();
    let mean = match kept > 0.0 {
        true => x.iter().zip(m).map(|(v, k)| v * k).sum::<f32>() / kept,
        false => 0.5,
    };
    let mut z: Vec<f32> = x
        .iter()
        .zip(m)
        .map(|(v, k)| if *k > 0.0 { *v } else { mean })
        .collect();
    let mut z_bar = z.clone();
    let (mut px, mut py) = (vec![0f32; h * w], vec![0f32; h * w]);
    let step = 0.99 / 8f32.sqrt();
    for _ in 0..s.iterations {
        for i in 0..h * w {
            let (gx, gy) = forward_differences(&z_bar, i, h, w);
            let (qx, qy) = (px[i] + step * gx, py[i] + step * gy);
            let shrink = ((qx * qx + qy * qy).sqrt() / s.weight).max(1.0);
            (px[i], py[i]) = (qx / shrink, qy / shrink);
        }
        for i in 0..h * w {
            let (y, c) = (i / w, i % w);
            let mut div = if c + 1 < w { px[i] } else { 0.0 };
            div -= if c > 0 { px[i - 1] } else { 0.0 };
            div += if y + 1 < h { py[i] } else { 0.0 };
            div -= if y > 0 { py[i - w] } else { 0.0 };
            let v = z[i] + step * div;
            let new = (v + step * m[i] * x[i]) / (1.0 + step * m[i]);
            z_bar[i] = 2.0 * new - z[i];
            z[i] = new;
        }
    }
    z
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A seeded noisy image: two flat regions and noise.
    fn noisy(h: usize, w: usize) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        (0..3 * h * w)
            .map(|i| if i % w < w / 3 { 0.25 } else { 0.7 } + rng.random_range(-0.1..0.1))
            .collect()
    }

    /// More iterations, lower objective; the solution is below the input's own objective, and
    /// it is smoother (its TV term alone falls).
    #[test]
    fn the_tv_solvers_objective_decreases() {
        let (h, w) = (24, 32);
        let x = noisy(h, w);
        let p = Planes {
            data: &x,
            height: h,
            width: w,
        };
        let at = |iterations| {
            let s = TvSettings {
                iterations,
                ..TvSettings::guo(0.05, 3)
            };
            tv_objective(p, &tv_minimise(p, &s), &s)
        };
        let start = tv_objective(p, &x, &TvSettings::guo(0.05, 3));
        let e: Vec<f64> = [5, 20, 80, 320].into_iter().map(at).collect();
        eprintln!("objective: input {start:.3}, after 5/20/80/320 iterations {e:?}");
        assert!(e[0] < start, "{} vs the input's {start}", e[0]);
        assert!(e.windows(2).all(|p| p[1] <= p[0] * (1.0 + 1e-4)), "{e:?}");
        assert!(e[3] < 0.5 * start, "{e:?}");
    }

    /// A constant image is a fixed point: nothing to smooth, nothing to fill.
    #[test]
    fn a_flat_image_is_unchanged() {
        let x = vec![0.4f32; 3 * 10 * 12];
        let p = Planes {
            data: &x,
            height: 10,
            width: 12,
        };
        let z = tv_minimise(p, &TvSettings::guo(0.03, 1));
        assert!(z.iter().all(|v| (v - 0.4).abs() < 1e-6));
    }
}
