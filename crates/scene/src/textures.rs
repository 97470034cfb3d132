//! The simple (non-adversarial) baseline textures of the paper's tables, generated in code from a
//! seed: **Natural** (multi-octave value noise through a foliage/bark colour ramp), **Naive**
//! (army camouflage: blobs of exactly four colours with smooth boundaries) and **Random** (a
//! mosaic of square cells, each a uniformly random colour).
//!
//! Same kind, resolution and seed → the same texels, bit for bit. These are textures only: they are
//! never optimised, and this module does not know about scenes or detectors (to put one on an
//! object use it as the initial atlas, `cac train --init`, or the evaluation's texture list).

use super::generate::value_noise;
use crate::texture::Texture;
use anyhow::{bail, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The three simple textures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    Natural,
    Naive,
    Random,
}

cac_core::choices!(Kind {
    Natural => "natural": "",
    Naive => "naive": "",
    Random => "random": "",
});

/// The Naive texture's palette (woodland camouflage: olive, brown, black, tan).
pub(crate) const NAIVE_PALETTE: [[u8; 3]; 4] =
    [[85, 96, 52], [110, 78, 48], [28, 28, 24], [176, 160, 118]];

/// The Natural texture's colour ramp, dark to light (shadowed leaves, leaves, bark, sunlit leaves).
const NATURAL_RAMP: [[f32; 3]; 5] = [
    [0.08, 0.14, 0.06],
    [0.20, 0.35, 0.12],
    [0.36, 0.27, 0.16],
    [0.42, 0.55, 0.20],
    [0.70, 0.75, 0.45],
];

/// Side of one Random cell in texels at a given atlas side (32 cells across, at least 1 texel).
pub(crate) fn random_cell(res: usize) -> usize {
    (res / 32).max(1)
}

/// Generates a `res × res` texture of `kind` from `seed`.
pub fn generate(kind: Kind, res: usize, seed: u64) -> Result<Texture> {
    if !(2..=8192).contains(&res) {
        bail!("texture resolution must be 2..=8192, got {res}");
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xC0FF_EE00_5EED);
    let s = [
        rng.random::<u32>(),
        rng.random::<u32>(),
        rng.random::<u32>(),
    ];
    let texels = match kind {
        Kind::Natural => natural(res, s),
        Kind::Naive => naive(res, s),
        Kind::Random => random(res, &mut rng),
    };
    Ok(Texture {
        width: res,
        height: res,
        texels,
    })
}

/// Fractal value noise in [0, 1] at `(u, v)` ∈ [0, 1]², `octaves` octaves from `base` cells.
fn fbm(u: f32, v: f32, base: f32, octaves: usize, seed: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut f) = (0.0, 1.0, 0.0, base);
    for o in 0..octaves {
        sum += amp * value_noise(u * f, v * f, seed.wrapping_add(o as u32 * 7919));
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    sum / norm
}

fn natural(res: usize, s: [u32; 3]) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(res * res);
    for y in 0..res {
        for x in 0..res {
            let (u, v) = ((x as f32 + 0.5) / res as f32, (y as f32 + 0.5) / res as f32);
            // Domain warp gives leaf-like, non-grid shapes; fine octaves give texture.
            let wu = u + 0.15 * (fbm(u, v, 4.0, 3, s[1]) - 0.5);
            let wv = v + 0.15 * (fbm(u, v, 4.0, 3, s[2]) - 0.5);
            let n = fbm(wu, wv, 6.0, 6, s[0]);
            let t = ((n - 0.25) / 0.5).clamp(0.0, 1.0) * (NATURAL_RAMP.len() - 1) as f32;
            let i = (t.floor() as usize).min(NATURAL_RAMP.len() - 2);
            let f = t - i as f32;
            let (a, b) = (NATURAL_RAMP[i], NATURAL_RAMP[i + 1]);
            let shade = 0.85 + 0.3 * fbm(u, v, 64.0, 2, s[1] ^ 0xABCD);
            out.push([0, 1, 2].map(|c| ((a[c] * (1.0 - f) + b[c] * f) * shade).clamp(0.0, 1.0)));
        }
    }
    out
}

fn naive(res: usize, s: [u32; 3]) -> Vec<[f32; 3]> {
    let pal = NAIVE_PALETTE.map(|c| c.map(|v| v as f32 / 255.0));
    let mut out = Vec::with_capacity(res * res);
    for y in 0..res {
        for x in 0..res {
            let (u, v) = ((x as f32 + 0.5) / res as f32, (y as f32 + 0.5) / res as f32);
            // Two smooth low-frequency fields: the base layer splits olive/brown, then black and
            // tan blobs are laid on top where a second field crosses its thresholds.
            let a = fbm(u, v, 5.0, 3, s[0]);
            let b = fbm(u + 0.37, v + 0.11, 7.0, 3, s[1]);
            let k = if b > 0.62 {
                2
            } else if b < 0.36 {
                3
            } else if a > 0.5 {
                1
            } else {
                0
            };
            out.push(pal[k]);
        }
    }
    out
}

fn random(res: usize, rng: &mut ChaCha8Rng) -> Vec<[f32; 3]> {
    let cell = random_cell(res);
    let cells = res.div_ceil(cell);
    let colours: Vec<[f32; 3]> = (0..cells * cells)
        .map(|_| {
            [
                rng.random::<f32>(),
                rng.random::<f32>(),
                rng.random::<f32>(),
            ]
        })
        .collect();
    (0..res * res)
        .map(|i| colours[(i / res / cell) * cells + (i % res) / cell])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    fn key(t: &[f32; 3]) -> [u32; 3] {
        t.map(f32::to_bits)
    }

    #[test]
    fn textures_are_deterministic_and_seed_dependent() {
        for kind in [Kind::Natural, Kind::Naive, Kind::Random] {
            let a = generate(kind, 64, 5).unwrap();
            let b = generate(kind, 64, 5).unwrap();
            let c = generate(kind, 64, 6).unwrap();
            assert_eq!(a.texels, b.texels, "{kind:?} is not deterministic");
            assert_ne!(a.texels, c.texels, "{kind:?} ignores its seed");
            assert!(a.texels.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
        }
        assert!(generate(Kind::Natural, 1, 0).is_err());
    }

    #[test]
    fn naive_uses_exactly_its_palette_in_blobs() {
        let t = generate(Kind::Naive, 128, 1).unwrap();
        let pal: HashSet<[u32; 3]> = NAIVE_PALETTE
            .iter()
            .map(|c| key(&c.map(|v| v as f32 / 255.0)))
            .collect();
        let used: HashSet<[u32; 3]> = t.texels.iter().map(key).collect();
        assert_eq!(
            used, pal,
            "Naive must use all four palette colours and nothing else"
        );
        // Blobs, not speckle: most horizontal neighbours share their colour.
        let same = (0..128 * 128)
            .filter(|i| i % 128 != 127)
            .filter(|&i| t.texels[i] == t.texels[i + 1])
            .count();
        assert!(same as f64 / (127.0 * 128.0) > 0.9, "{same}");
        for c in &pal {
            let n = t.texels.iter().filter(|x| &key(x) == c).count();
            assert!(
                n > 128 * 128 / 50,
                "a palette colour covers only {n} texels"
            );
        }
    }

    #[test]
    fn random_has_many_distinct_colours_constant_within_cells() {
        let t = generate(Kind::Random, 128, 2).unwrap();
        let distinct: HashSet<[u32; 3]> = t.texels.iter().map(key).collect();
        assert!(distinct.len() > 1000, "only {} colours", distinct.len());
        let cell = random_cell(128);
        assert_eq!(t.texels[0], t.texels[cell - 1]);
        assert_ne!(t.texels[0], t.texels[cell]);
        let mean: f32 = t.texels.iter().flatten().sum::<f32>() / (3.0 * 128.0 * 128.0);
        assert!((mean - 0.5).abs() < 0.05, "mean {mean}");
    }

    #[test]
    fn natural_is_smooth_greenish_and_varied() {
        let t = generate(Kind::Natural, 128, 3).unwrap();
        let n = t.texels.len() as f32;
        let m = [0, 1, 2].map(|c| t.texels.iter().map(|x| x[c]).sum::<f32>() / n);
        assert!(m[1] > m[2], "foliage: more green than blue {m:?}");
        let var = t.texels.iter().map(|x| (x[1] - m[1]).powi(2)).sum::<f32>() / n;
        assert!(var.sqrt() > 0.05, "too flat: sd {}", var.sqrt());
        let distinct: HashSet<[u32; 3]> = t.texels.iter().map(key).collect();
        assert!(distinct.len() > 500);
    }
}
