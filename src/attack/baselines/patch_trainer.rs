//! The 2D training loop of AdvPat and ShapeShifter: a square patch, pasted under random plane
//! transformations onto rendered images of the vehicle (its original texture, the environment's
//! conditions), optimised with Adam against the source detectors; the camouflage is then the
//! patch tiled over every paintable texel ([`super::atlas`]).
//!
//! The backgrounds are rendered with the same environment draw as CAC's iterations (seeded by the
//! run seed and the iteration), so resuming from a checkpoint continues exactly. Not here: the
//! objectives ([`super::objectives`]) or the transforms themselves ([`super::patch2d`]).

use super::{atlas, patch2d, Method};
use crate::attack::adam::Adam;
use crate::attack::{
    draw_conditions, ensemble_loss, load_checkpoint, AttackConfig, Checkpoint, IterationLog, Run,
};
use crate::detect::Detector;
use crate::environment::{self, Environment};
use crate::render::{self, Renderer};
use crate::scene::Texture;
use anyhow::{bail, Context, Result};
use burn::tensor::{Device, Tensor, TensorData};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::Path;
use std::time::Instant;

/// Thys et al.'s weight of the total-variation term (AdvPat only).
pub const TV_WEIGHT: f64 = 2.5;

/// A 2D patch run bound to a renderer, an environment and its source detectors.
pub struct PatchTrainer<'a> {
    pub config: AttackConfig,
    pub renderer: &'a Renderer,
    pub env: &'a Environment,
    pub detectors: Vec<&'a dyn Detector>,
    /// An autodiff device (the backgrounds are rendered on its inner device).
    pub device: Device,
    /// `state.atlas` holds the patch (`patch_res² × 3`).
    pub state: Checkpoint,
    /// The object's texture: the backgrounds' vehicle and the atlas outside paintable texels.
    pub base: Texture,
    pub mask: Vec<bool>,
    pub ranges: patch2d::TransformRanges,
}

impl<'a> PatchTrainer<'a> {
    /// Starts from a mid-grey patch (Thys et al.'s grey start); `base` is the object's texture.
    pub fn new(
        config: AttackConfig,
        renderer: &'a Renderer,
        env: &'a Environment,
        detectors: Vec<&'a dyn Detector>,
        device: Device,
        base: &Texture,
    ) -> Result<Self> {
        config.validate()?;
        if !config.method.is_2d() {
            bail!("{} is not a 2D patch method", config.method.name());
        }
        if detectors.len() != config.models.len() {
            bail!(
                "{} detectors given for {} configured models",
                detectors.len(),
                config.models.len()
            );
        }
        let res = renderer.settings.atlas_res;
        let base = if base.width != res || base.height != res {
            base.resized(res, res)
        } else {
            base.clone()
        };
        let n = config.patch_res * config.patch_res * 3;
        Ok(PatchTrainer {
            state: Checkpoint {
                iteration: 0,
                atlas_res: config.patch_res,
                scales: 1,
                adam: Adam::new(n, config.lr),
                atlas: vec![0.5; n],
                log: vec![],
            },
            mask: atlas::paintable_texels(&renderer.scene, res),
            config,
            renderer,
            env,
            detectors,
            device,
            base,
            ranges: patch2d::TransformRanges::default(),
        })
    }

    /// Continues from the checkpoint in `run_dir`.
    pub fn resume(mut self, run_dir: &Path) -> Result<Self> {
        let ck = load_checkpoint(run_dir)?;
        if ck.atlas_res != self.config.patch_res {
            bail!(
                "{}: checkpoint patch is {}², the run asks for {}²",
                run_dir.display(),
                ck.atlas_res,
                self.config.patch_res
            );
        }
        self.state = ck;
        Ok(self)
    }

    /// The current patch.
    pub fn patch(&self) -> Texture {
        let p = self.state.atlas_res;
        Texture {
            width: p,
            height: p,
            texels: self
                .state
                .atlas
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
        }
    }

    /// Backgrounds of iteration `i` (host `[B, 3, H, W]`), their dims, and the object boxes.
    fn backgrounds(&self, i: usize) -> Result<(Vec<f32>, [usize; 4], Vec<[f32; 4]>)> {
        let conds = draw_conditions(self.env, &self.config, i);
        let plain = self.device.clone().inner();
        let a = render::atlas_tensor(&self.base, &plain);
        let (img, plans) = environment::form(self.renderer, self.env, &conds, a)?;
        let (w, h) = (
            self.renderer.settings.width as f32,
            self.renderer.settings.height as f32,
        );
        let boxes = plans
            .iter()
            .map(|p| {
                p.object_box
                    .unwrap_or([0.25 * w, 0.25 * h, 0.75 * w, 0.75 * h])
            })
            .collect();
        let dims = img.dims();
        Ok((crate::detect::to_vec(&img)?, dims, boxes))
    }

    /// One iteration: render backgrounds, paste, detect, loss, backward, Adam step.
    pub fn step(&mut self) -> Result<IterationLog> {
        let i = self.state.iteration;
        let goal = self.config.goal()?;
        let t0 = Instant::now();
        let (bg, dims, boxes) = self.backgrounds(i)?;
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.config.seed.wrapping_mul(0xD1B5_4A32_D192_ED03) ^ (i as u64).wrapping_add(0x5EED),
        );
        let ts: Vec<_> = boxes
            .iter()
            .map(|b| self.ranges.sample(*b, &mut rng))
            .collect();
        let p = self.state.atlas_res;
        let patch = Tensor::<4>::from_data(
            TensorData::new(self.state.atlas.clone(), [1, p, p, 3]),
            &self.device,
        )
        .require_grad();
        let images = patch2d::paste(&bg, dims, patch.clone(), &ts, &self.device)?;
        let ms_render = t0.elapsed().as_secs_f64() * 1e3;
        let t1 = Instant::now();
        let objects: Vec<_> = boxes.iter().map(|b| Some(*b)).collect();
        let (loss, proposals) =
            ensemble_loss(&self.detectors, &images, &objects, &self.config, goal)?;
        let mut loss = loss;
        if self.config.method == Method::Advpat {
            loss = loss + total_variation(patch.clone()) * TV_WEIGHT;
        }
        let loss_value = crate::detect::to_vec(&loss)?[0] as f64;
        let ms_forward = t1.elapsed().as_secs_f64() * 1e3;
        let t2 = Instant::now();
        let grads = loss.backward();
        let g = crate::detect::to_vec(
            &patch
                .grad(&grads)
                .context("no gradient reached the patch")?,
        )?;
        let ms_backward = t2.elapsed().as_secs_f64() * 1e3;
        if !loss_value.is_finite() {
            bail!("iteration {i}: the loss is not finite ({loss_value})");
        }
        let t3 = Instant::now();
        let grad_norm = g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
        self.state.adam.step(&mut self.state.atlas, &g);
        let log = IterationLog {
            iteration: i,
            loss: loss_value,
            grad_norm,
            proposals,
            ms_render,
            ms_forward,
            ms_backward,
            ms_optimiser: t3.elapsed().as_secs_f64() * 1e3,
        };
        self.state.log.push(log.clone());
        self.state.iteration += 1;
        Ok(log)
    }
}

/// Thys et al.'s total variation: mean absolute difference of horizontal and vertical neighbours
/// of a `[1, P, P, 3]` patch.
pub fn total_variation(patch: Tensor<4>) -> Tensor<1> {
    let [_, p, _, _] = patch.dims();
    let dx = patch.clone().slice([0..1, 0..p, 1..p, 0..3])
        - patch.clone().slice([0..1, 0..p, 0..p - 1, 0..3]);
    let dy =
        patch.clone().slice([0..1, 1..p, 0..p, 0..3]) - patch.slice([0..1, 0..p - 1, 0..p, 0..3]);
    (dx.abs().sum() + dy.abs().sum()) / (p * p * 3) as f64
}

impl Run for PatchTrainer<'_> {
    fn config(&self) -> &AttackConfig {
        &self.config
    }
    fn state(&self) -> &Checkpoint {
        &self.state
    }
    fn step(&mut self) -> Result<IterationLog> {
        PatchTrainer::step(self)
    }
    /// The patch tiled over every paintable texel of the object's texture.
    fn atlas(&self) -> Texture {
        atlas::paste_tiled(
            &self.base,
            &self.patch(),
            &self.mask,
            self.config.patch_tiles,
        )
    }
    fn renderer(&self) -> &Renderer {
        self.renderer
    }
    fn env(&self) -> &Environment {
        self.env
    }
    fn extra_images(&self) -> Vec<(String, image::RgbImage)> {
        vec![("patch.png".into(), self.patch().to_rgb8())]
    }
}
