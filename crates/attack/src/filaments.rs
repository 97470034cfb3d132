//! Training through a multi-material FDM printer: the atlas as a choice among the K filaments
//! per region, relaxed by Gumbel-softmax (Jang et al. 2017) and annealed to a hard choice, as in
//! AdvCaT (Hu et al., CVPR 2023).
//!
//! The atlas is cut into square regions of [`Filaments::cell`] texels, no smaller than the
//! nozzle width at the print scale. Each region holds K logits `l`; iteration `i` draws Gumbel
//! noise `g` (seeded by the run seed and `i`) and paints the region with
//! `Σ_k softmax((l + g) / τ_i)_k · filament_k`, where `τ_i` falls geometrically from
//! [`TAU_START`] to [`TAU_END`]. From [`HARD_FROM`] of the run on, the forward paints the one
//! filament of the largest `(l + g)` (what the printer makes) and the gradient passes through the
//! soft choice (straight-through). The written texture is always the hard choice of `l`: every
//! texel is one of the filaments, so the texture trained is the texture printed.

use anyhow::{bail, Result};
use cac_core::printer::Printer;
use cac_scene::{Scene, Texture};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Temperature at the start of a run.
pub const TAU_START: f32 = 1.0;
/// Temperature at the end of a run.
pub const TAU_END: f32 = 0.05;
/// Share of the run after which the forward pass is the hard choice.
pub const HARD_FROM: f32 = 0.75;
/// Scale, in ΔE2000, of the starting logits (`-ΔE / INIT_DE` for each filament from the initial
/// texture's colour): a region starts most likely as its nearest filament.
pub const INIT_DE: f32 = 5.0;

/// The parameterisation: the filaments' colours and the regions' size.
#[derive(Clone, Debug)]
pub struct Filaments {
    /// sRGB colour of each filament.
    pub palette: Vec<[f32; 3]>,
    /// Atlas side, texels.
    pub res: usize,
    /// Region side, texels.
    pub cell: usize,
    /// Run seed (the Gumbel noise).
    pub seed: u64,
    /// A texel's mean side on the printed object, mm.
    pub texel_mm: f32,
}

/// One forward pass: the atlas and what the backward pass needs.
pub struct Forward {
    /// Row-major RGB, `res²`.
    pub atlas: Vec<f32>,
    /// Soft choice per region, `cells² × K`.
    probs: Vec<f32>,
    tau: f32,
}

impl Filaments {
    /// The parameterisation for `printer` (FDM) on `scene`'s `res²` atlas: regions at least the
    /// nozzle wide at the profile's print size (the object's longest side).
    pub fn new(printer: &Printer, scene: &Scene, res: usize, seed: u64) -> Result<Self> {
        let Printer::Fdm { palette, fdm, .. } = printer else {
            bail!("training through filaments needs an FDM printer profile");
        };
        let Some(texel) = cac_scene::paint::texel_size(scene, res) else {
            bail!("{}: no paintable surface with UVs to print on", scene.name);
        };
        let (lo, hi) = scene.bounds();
        let longest = (hi - lo).max_element();
        let texel_mm = texel * fdm.object_size_mm / longest;
        let cell = ((fdm.nozzle_mm / texel_mm).ceil() as usize).clamp(1, res);
        Ok(Filaments {
            palette: palette.clone(),
            res,
            cell,
            seed,
            texel_mm,
        })
    }

    /// One line for the log: filaments, regions and their size on the print.
    pub fn describe(&self) -> String {
        format!(
            "through {} filaments: regions of {c}x{c} texels ({:.2} mm on the print; a texel is \
             {:.2} mm)",
            self.palette.len(),
            self.cell as f32 * self.texel_mm,
            self.texel_mm,
            c = self.cell
        )
    }

    /// Regions per atlas side.
    pub fn cells(&self) -> usize {
        self.res.div_ceil(self.cell)
    }

    /// Number of parameters (`cells² × K`).
    pub fn len(&self) -> usize {
        self.cells().pow(2) * self.palette.len()
    }

    /// Whether there are no parameters (never, for a valid printer).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The region of texel `(x, y)`.
    fn region(&self, x: usize, y: usize) -> usize {
        (y / self.cell) * self.cells() + x / self.cell
    }

    /// Starting logits from a texture (`res²`): each region's mean colour, `-ΔE2000 / INIT_DE`
    /// to each filament.
    pub fn init(&self, atlas: &Texture) -> Vec<f32> {
        let (n, k) = (self.cells().pow(2), self.palette.len());
        let mut sum = vec![[0.0f32; 3]; n];
        let mut count = vec![0u32; n];
        for y in 0..self.res {
            for x in 0..self.res {
                let r = self.region(x, y);
                let c = atlas.texels[y * self.res + x];
                (0..3).for_each(|j| sum[r][j] += c[j]);
                count[r] += 1;
            }
        }
        let labs: Vec<[f32; 3]> = self
            .palette
            .iter()
            .map(|&c| cac_core::colour::srgb_to_lab(c))
            .collect();
        let mut logits = Vec::with_capacity(n * k);
        for (s, c) in sum.iter().zip(&count) {
            let lab = cac_core::colour::srgb_to_lab(s.map(|v| v / (*c).max(1) as f32));
            logits.extend(
                labs.iter()
                    .map(|f| -cac_core::colour::delta_e2000(lab, *f) / INIT_DE),
            );
        }
        logits
    }

    /// Temperature at iteration `i` of `n`.
    pub fn tau(i: usize, n: usize) -> f32 {
        let t = i as f32 / n.max(1) as f32;
        TAU_START * (TAU_END / TAU_START).powf(t.min(1.0))
    }

    /// The atlas of iteration `i` of `n` from the logits.
    pub fn forward(&self, logits: &[f32], i: usize, n: usize) -> Forward {
        let k = self.palette.len();
        let tau = Self::tau(i, n);
        let hard = i as f32 >= HARD_FROM * n as f32;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x6675_6d62_656c ^ ((i as u64) << 20));
        let mut probs = Vec::with_capacity(logits.len());
        let mut colours = Vec::with_capacity(logits.len() / k);
        for l in logits.chunks_exact(k) {
            let z: Vec<f32> = l.iter().map(|v| (v + gumbel(&mut rng)) / tau).collect();
            let m = z.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let e: Vec<f32> = z.iter().map(|v| (v - m).exp()).collect();
            let s: f32 = e.iter().sum();
            let p: Vec<f32> = e.iter().map(|v| v / s).collect();
            colours.push(if hard {
                self.palette[argmax(&z)]
            } else {
                mix(&self.palette, &p)
            });
            probs.extend(p);
        }
        Forward {
            atlas: self.paint(&colours),
            probs,
            tau,
        }
    }

    /// The gradient with respect to the logits from the gradient with respect to the atlas of
    /// the same forward pass (through the soft choice).
    pub fn backward(&self, fw: &Forward, g_atlas: &[f32]) -> Vec<f32> {
        let k = self.palette.len();
        let mut g_region = vec![[0.0f32; 3]; self.cells().pow(2)];
        for y in 0..self.res {
            for x in 0..self.res {
                let t = (y * self.res + x) * 3;
                let r = self.region(x, y);
                (0..3).for_each(|j| g_region[r][j] += g_atlas[t + j]);
            }
        }
        let mut g = Vec::with_capacity(fw.probs.len());
        for (p, gr) in fw.probs.chunks_exact(k).zip(&g_region) {
            // dL/dp_k = g · filament_k; softmax's Jacobian over τ.
            let dp: Vec<f32> = self.palette.iter().map(|c| dot(*gr, *c)).collect();
            let mean: f32 = p.iter().zip(&dp).map(|(a, b)| a * b).sum();
            g.extend(p.iter().zip(&dp).map(|(pk, dk)| pk * (dk - mean) / fw.tau));
        }
        g
    }

    /// The printed texture: each region the filament of its largest logit.
    pub fn hard(&self, logits: &[f32]) -> Texture {
        let k = self.palette.len();
        let colours: Vec<[f32; 3]> = logits
            .chunks_exact(k)
            .map(|l| self.palette[argmax(l)])
            .collect();
        let a = self.paint(&colours);
        Texture {
            width: self.res,
            height: self.res,
            texels: a.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        }
    }

    /// The atlas (row-major RGB) with each region's colour.
    fn paint(&self, colours: &[[f32; 3]]) -> Vec<f32> {
        let mut a = Vec::with_capacity(self.res * self.res * 3);
        for y in 0..self.res {
            for x in 0..self.res {
                a.extend(colours[self.region(x, y)]);
            }
        }
        a
    }
}

fn gumbel(rng: &mut ChaCha8Rng) -> f32 {
    let u: f32 = rng.random_range(1e-7..1.0);
    -(-u.ln()).ln()
}

fn argmax(v: &[f32]) -> usize {
    (0..v.len())
        .max_by(|&a, &b| v[a].total_cmp(&v[b]))
        .unwrap_or(0)
}

fn mix(palette: &[[f32; 3]], p: &[f32]) -> [f32; 3] {
    let mut c = [0.0; 3];
    for (f, w) in palette.iter().zip(p) {
        (0..3).for_each(|j| c[j] += w * f[j]);
    }
    c
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn four(res: usize, cell: usize) -> Filaments {
        Filaments {
            palette: vec![[0.95; 3], [0.1; 3], [0.76, 0.18, 0.12], [0.04, 0.16, 0.54]],
            res,
            cell,
            seed: 7,
            texel_mm: 0.5,
        }
    }

    /// The loss `Σ w · atlas` for fixed seeded weights `w`: its gradient is `w`.
    fn weights(n: usize) -> Vec<f32> {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
    }

    #[test]
    fn the_gradient_matches_finite_differences_of_the_soft_choice() {
        let f = four(6, 4);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let logits: Vec<f32> = (0..f.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let w = weights(6 * 6 * 3);
        let loss = |l: &[f32]| -> f64 {
            let a = f.forward(l, 2, 10).atlas;
            a.iter()
                .zip(&w)
                .map(|(a, b)| (*a as f64) * (*b as f64))
                .sum()
        };
        let g = f.backward(&f.forward(&logits, 2, 10), &w);
        for j in 0..logits.len() {
            let h = 1e-2;
            let (mut p, mut m) = (logits.clone(), logits.clone());
            p[j] += h;
            m[j] -= h;
            let fd = (loss(&p) - loss(&m)) / (2.0 * h as f64);
            // f32 sums of ~20 terms: the finite difference's own rounding is ~1e-5 / h.
            assert!(
                (fd - g[j] as f64).abs() < 2e-3 * (1.0 + fd.abs()),
                "{j}: {fd} vs {}",
                g[j]
            );
        }
    }

    #[test]
    fn the_late_forward_and_the_written_texture_are_only_filaments() {
        let f = four(10, 3);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let logits: Vec<f32> = (0..f.len()).map(|_| rng.random_range(-2.0..2.0)).collect();
        let late = f.forward(&logits, 80, 100).atlas;
        let early = f.forward(&logits, 0, 100).atlas;
        let is_filament = |c: &[f32]| f.palette.iter().any(|p| p[..] == *c);
        assert!(late.chunks_exact(3).all(is_filament));
        assert!(
            !early.chunks_exact(3).all(is_filament),
            "the early forward is a soft mix"
        );
        let t = f.hard(&logits);
        assert!(t.texels.iter().all(|c| is_filament(c)));
        // Regions are uniform: texels (0,0) and (2,2) share one, (3,0) starts the next.
        assert_eq!(t.texels[0], t.texels[2 * 10 + 2]);
        assert_eq!(f.cells(), 4);
    }

    #[test]
    fn the_start_is_the_nearest_filament_of_each_region() {
        let f = four(4, 2);
        let colours = [
            [0.9, 0.9, 0.9],
            [0.05, 0.05, 0.05],
            [0.8, 0.2, 0.1],
            [0.0, 0.2, 0.6],
        ];
        let atlas = Texture {
            width: 4,
            height: 4,
            texels: (0..16)
                .map(|i| colours[((i / 4) / 2) * 2 + (i % 4) / 2])
                .collect(),
        };
        let t = f.hard(&f.init(&atlas));
        for (i, c) in t.texels.iter().enumerate() {
            assert_eq!(*c, f.palette[((i / 4) / 2) * 2 + (i % 4) / 2], "texel {i}");
        }
    }
}
