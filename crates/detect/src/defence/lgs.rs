//! Local gradient smoothing (Naseer et al., WACV 2019): a training-free defence against localised
//! adversarial patterns. The image's first-order gradient magnitude, normalised to [0, 1], is
//! kept only in windows where it is high on average (15-pixel windows, 5 pixels of overlap,
//! mean above 0.1); the image is then multiplied by `1 − λ·g`, which darkens busy regions to
//! nothing and leaves smooth ones as they were.

use super::Planes;

const WINDOW: usize = 15;
const STRIDE: usize = 10;
const THRESHOLD: f32 = 0.1;

/// The image with its busy regions suppressed by `strength` (λ; the paper's 2.3).
pub fn local_gradient_smoothing(p: Planes, strength: f32) -> Vec<f32> {
    let m = lgs_mask(p, strength);
    let n = m.len();
    p.data
        .iter()
        .enumerate()
        .map(|(i, v)| v * m[i % n])
        .collect()
}

/// The factor `clamp(1 − λ·g, 0, 1)` each pixel is multiplied by (one per pixel, all channels).
pub fn lgs_mask(p: Planes, strength: f32) -> Vec<f32> {
    let (h, w) = (p.height, p.width);
    let g = normalised_gradient(p);
    let mut kept = vec![0f32; h * w];
    for y0 in starts(h) {
        for x0 in starts(w) {
            let (y1, x1) = ((y0 + WINDOW).min(h), (x0 + WINDOW).min(w));
            let mut sum = 0f32;
            for y in y0..y1 {
                sum += g[y * w + x0..y * w + x1].iter().sum::<f32>();
            }
            if sum / ((y1 - y0) * (x1 - x0)) as f32 > THRESHOLD {
                for y in y0..y1 {
                    kept[y * w + x0..y * w + x1].copy_from_slice(&g[y * w + x0..y * w + x1]);
                }
            }
        }
    }
    kept.iter()
        .map(|g| (1.0 - strength * g).clamp(0.0, 1.0))
        .collect()
}

/// The windows' first rows (or columns): every `STRIDE`, the last one ending at the edge.
fn starts(len: usize) -> Vec<usize> {
    let last = len.saturating_sub(WINDOW);
    let mut s: Vec<usize> = (0..=last).step_by(STRIDE).collect();
    if s.last() != Some(&last) {
        s.push(last);
    }
    s
}

/// The gradient magnitude of the grey image (channels' mean), forward differences, divided by
/// its largest value (all zero for a flat image).
fn normalised_gradient(p: Planes) -> Vec<f32> {
    let (h, w) = (p.height, p.width);
    let n = h * w;
    let channels = p.data.len() / n;
    let grey: Vec<f32> = (0..n)
        .map(|i| (0..channels).map(|c| p.data[c * n + i]).sum::<f32>() / channels as f32)
        .collect();
    let g: Vec<f32> = (0..n)
        .map(|i| {
            let (y, x) = (i / w, i % w);
            let gx = if x + 1 < w {
                grey[i + 1] - grey[i]
            } else {
                0.0
            };
            let gy = if y + 1 < h {
                grey[i + w] - grey[i]
            } else {
                0.0
            };
            (gx * gx + gy * gy).sqrt()
        })
        .collect();
    let max = g.iter().copied().fold(0f32, f32::max);
    match max > 0.0 {
        true => g.iter().map(|v| v / max).collect(),
        false => g,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A smooth image with a 24-pixel square of seeded noise (a patch): the patch is darkened
    /// (its mean falls by over half), the smooth surround away from it is untouched.
    #[test]
    fn a_noisy_patch_is_suppressed_and_the_smooth_rest_kept() {
        let (h, w) = (64, 80);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let patch = |y: usize, x: usize| (20..44).contains(&y) && (30..54).contains(&x);
        let mut v = vec![0f32; 3 * h * w];
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    v[(c * h + y) * w + x] = match patch(y, x) {
                        true => rng.random_range(0.0..1.0),
                        false => 0.5 + 0.002 * x as f32,
                    };
                }
            }
        }
        let p = Planes {
            data: &v,
            height: h,
            width: w,
        };
        let out = local_gradient_smoothing(p, 2.3);
        let mean = |img: &[f32], inside: bool| {
            let idx: Vec<usize> = (0..h * w)
                .filter(|i| patch(i / w, i % w) == inside)
                .collect();
            idx.iter().map(|&i| img[i]).sum::<f32>() / idx.len() as f32
        };
        assert!(
            mean(&out, true) < 0.5 * mean(&v, true),
            "the patch was not suppressed"
        );
        for y in 0..h {
            for x in 0..w {
                let far = !(5..59).contains(&y) || !(15..69).contains(&x);
                if far {
                    let i = y * w + x;
                    assert_eq!(out[i], v[i], "smooth pixel ({x}, {y}) changed");
                }
            }
        }
    }
}
