//! The CAC attack (Algorithm 1 of the paper): learn a camouflage atlas under expectation over
//! transformations with the dense-proposals loss.
//!
//! Each iteration draws a batch of environment conditions (seeded by the run seed and the
//! iteration number, so a resumed run draws the same batches), renders them differentiably, runs
//! every source detector, fixes its proposals (by default the candidates on the object, see
//! [`loss`]), and takes an Adam step on the atlas that lowers the loss over them; the atlas is
//! clipped to [0, 1].
//! Only texels that paintable surfaces sample ever receive a gradient, so only they change.
//!
//! Long runs checkpoint every K iterations into the run folder; [`Trainer::resume`] continues
//! exactly where the last checkpoint left off.

pub mod adam;
pub mod baselines;
pub mod loss;
pub mod pyramid;
pub mod report;

use crate::detect::Detector;
use crate::environment::{self, Brightness, Condition, Environment, ViewpointSet};
use crate::render::Renderer;
use crate::scene::Texture;
use adam::Adam;
use anyhow::{bail, Context, Result};
pub use baselines::Method;
use burn::tensor::{Device, Tensor, TensorData};
use loss::{Goal, ProposalRule};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Attack settings (the `[attack]` table; `cac train --help` documents each flag).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AttackConfig {
    /// The attack: CAC (this paper) or a baseline (`docs/attack.md` says how each is realised).
    pub method: Method,
    /// Source detectors (an ensemble when several).
    pub models: Vec<String>,
    /// COCO class every proposal is pushed towards; ignored with `hide`.
    pub target: String,
    /// Non-targeted mode: suppress every class.
    pub hide: bool,
    /// Which candidates become the fixed proposals (`loss` module docs). Runs written before
    /// the rule existed used top-n, so a run.json without it reads as `topn`.
    #[serde(default = "legacy_rule")]
    pub proposals: ProposalRule,
    /// Fixed proposals per image at most (the paper's n).
    pub top_n: usize,
    /// IoU of the class-agnostic NMS that picks the `topn` proposals.
    pub nms_iou: f64,
    /// Least IoU with the object's box of an `overlap` proposal.
    pub overlap_iou: f64,
    pub batch: usize,
    pub iterations: usize,
    pub lr: f32,
    pub seed: u64,
    /// Write a checkpoint every this many iterations (0: only at the end).
    pub checkpoint_every: usize,
    pub viewpoints: ViewpointSet,
    /// Levels of the atlas's multi-scale parameterisation (1: texel by texel; [`pyramid`]).
    #[serde(default = "one_scale")]
    pub scales: usize,
    /// 2D methods: side of the trained patch in texels.
    pub patch_res: usize,
    /// 2D methods: tiles of the patch across the atlas side when it is put on the object.
    pub patch_tiles: usize,
}

impl Default for AttackConfig {
    fn default() -> Self {
        AttackConfig {
            models: vec!["nanodet".into()],
            target: "person".into(),
            hide: false,
            proposals: ProposalRule::Overlap,
            top_n: 300,
            nms_iou: 0.7,
            overlap_iou: 0.5,
            batch: 2,
            iterations: 200,
            lr: 0.02,
            seed: 0,
            checkpoint_every: 10,
            viewpoints: ViewpointSet::Free,
            method: Method::Cac,
            scales: 1,
            patch_res: 128,
            patch_tiles: 4,
        }
    }
}

fn one_scale() -> usize {
    1
}

fn legacy_rule() -> ProposalRule {
    ProposalRule::TopN
}

impl AttackConfig {
    pub fn goal(&self) -> Result<Goal> {
        if self.hide || !self.method.is_targeted() {
            return Ok(Goal::Hide);
        }
        match crate::detect::labels::class_id(&self.target) {
            Some(c) => Ok(Goal::Targeted(c)),
            None => bail!("unknown target class {:?} (use a COCO-80 label such as \"person\" or \"stop sign\")", self.target),
        }
    }

    pub fn validate(&self) -> Result<()> {
        if self.models.is_empty() {
            bail!("at least one source model is needed");
        }
        if self.batch == 0 || self.top_n == 0 {
            bail!("batch and top_n must be positive");
        }
        if !(self.overlap_iou > 0.0 && self.overlap_iou <= 1.0) {
            bail!("--overlap-iou must be in (0, 1], got {}", self.overlap_iou);
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            bail!("learning rate must be positive");
        }
        if self.hide && self.method != Method::Cac {
            bail!(
                "--hide applies to --method cac only: {} {}",
                self.method.name(),
                if self.method.is_targeted() {
                    "is a targeted attack (it needs --target)"
                } else {
                    "already hides the vehicle (it is non-targeted)"
                }
            );
        }
        if self.scales != 1 && (self.method.is_2d() || !(1..=8).contains(&self.scales)) {
            bail!(
                "--scales must be 1..=8, and 1 for the 2D methods (got {} with {})",
                self.scales,
                self.method.name()
            );
        }
        if self.method.is_2d() && !(4..=2048).contains(&self.patch_res) {
            bail!("--patch-res must be 4..=2048, got {}", self.patch_res);
        }
        if self.method.is_2d() && !(1..=64).contains(&self.patch_tiles) {
            bail!("--patch-tiles must be 1..=64, got {}", self.patch_tiles);
        }
        self.goal().map(|_| ())
    }
}

/// One iteration's record in `run.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct IterationLog {
    pub iteration: usize,
    pub loss: f64,
    pub grad_norm: f64,
    /// Candidates the objective scored, summed over the batch and source models: the fixed
    /// proposals (CAC, ShapeShifter, UPC), every candidate (CAMOU) or one per image (AdvPat).
    pub proposals: usize,
    pub ms_render: f64,
    pub ms_forward: f64,
    pub ms_backward: f64,
    pub ms_optimiser: f64,
}

/// Everything needed to continue a run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Checkpoint {
    pub iteration: usize,
    pub atlas_res: usize,
    /// Levels of the parameterisation: `atlas` holds all of them ([`pyramid`]); 1 for a plain
    /// atlas and for 2D patches.
    pub scales: usize,
    pub adam: Adam,
    /// The optimised parameters: the atlas itself (row-major RGB) when `scales` is 1.
    pub atlas: Vec<f32>,
    pub log: Vec<IterationLog>,
}

/// A training run bound to a renderer, an environment and its source detectors.
pub struct Trainer<'a> {
    pub config: AttackConfig,
    pub renderer: &'a Renderer,
    pub env: &'a Environment,
    pub detectors: Vec<&'a dyn Detector>,
    /// An autodiff device.
    pub device: Device,
    pub state: Checkpoint,
    pub run_dir: Option<PathBuf>,
    /// Texels a paintable surface can sample (where the coarse levels of a multi-scale
    /// parameterisation act; empty for one level).
    paintable: Vec<bool>,
}

impl<'a> Trainer<'a> {
    /// Starts from `init` (the object's texture or a chosen initial atlas).
    /// A CAC or 3D-baseline run (`config.method` must not be a 2D method).
    pub fn new(
        config: AttackConfig,
        renderer: &'a Renderer,
        env: &'a Environment,
        detectors: Vec<&'a dyn Detector>,
        device: Device,
        init: &Texture,
    ) -> Result<Self> {
        config.validate()?;
        if config.method.is_2d() {
            bail!(
                "{} trains a 2D patch: use baselines::PatchTrainer",
                config.method.name()
            );
        }
        if detectors.len() != config.models.len() {
            bail!(
                "{} detectors given for {} configured models",
                detectors.len(),
                config.models.len()
            );
        }
        let res = renderer.settings.atlas_res;
        let init = if init.width != res || init.height != res {
            init.resized(res, res)
        } else {
            init.clone()
        };
        pyramid::check(res, config.scales)?;
        let atlas: Vec<f32> = init.texels.iter().flatten().copied().collect();
        let atlas = pyramid::from_atlas(&atlas, res, config.scales);
        let state = Checkpoint {
            iteration: 0,
            atlas_res: res,
            scales: config.scales,
            adam: Adam::new(atlas.len(), config.lr),
            atlas,
            log: vec![],
        };
        let paintable = if config.scales > 1 {
            baselines::atlas::paintable_texels(&renderer.scene, res)
        } else {
            vec![]
        };
        Ok(Trainer {
            config,
            renderer,
            env,
            detectors,
            device,
            state,
            run_dir: None,
            paintable,
        })
    }

    /// Continues from the checkpoint in `run_dir`.
    pub fn resume(mut self, run_dir: &Path) -> Result<Self> {
        let ck = load_checkpoint(run_dir)?;
        if ck.atlas_res != self.renderer.settings.atlas_res {
            bail!(
                "{}: checkpoint atlas is {}², the config asks for {}²",
                run_dir.display(),
                ck.atlas_res,
                self.renderer.settings.atlas_res
            );
        }
        if ck.scales != self.config.scales {
            bail!(
                "{}: checkpoint has {} atlas levels, the config asks for {}",
                run_dir.display(),
                ck.scales,
                self.config.scales
            );
        }
        self.state = ck;
        Ok(self)
    }

    /// The conditions of iteration `i` (a pure function of the seed and `i`).
    pub fn conditions(&self, i: usize) -> Vec<Condition> {
        draw_conditions(self.env, &self.config, i)
    }

    /// The current atlas as a texture.
    pub fn atlas(&self) -> Texture {
        let r = self.state.atlas_res;
        Texture {
            width: r,
            height: r,
            texels: self
                .composed()
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
        }
    }

    /// The atlas the parameters compose to (row-major RGB).
    fn composed(&self) -> Vec<f32> {
        let (r, k) = (self.state.atlas_res, self.state.scales);
        if k == 1 {
            self.state.atlas.clone()
        } else {
            // Projected parameters compose to [0, 1] up to rounding; the clamp removes that.
            let mut a = pyramid::compose(&self.state.atlas, r, k, &self.paintable);
            a.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
            a
        }
    }

    /// One iteration: render, detect, loss, backward, Adam step.
    pub fn step(&mut self) -> Result<IterationLog> {
        let i = self.state.iteration;
        let goal = self.config.goal()?;
        let conds = self.conditions(i);
        let t0 = Instant::now();
        let r = self.state.atlas_res;
        let atlas =
            Tensor::<4>::from_data(TensorData::new(self.composed(), [1, r, r, 3]), &self.device)
                .require_grad();
        let (images, plans) = environment::form(self.renderer, self.env, &conds, atlas.clone())?;
        let ms_render = t0.elapsed().as_secs_f64() * 1e3;
        let t1 = Instant::now();
        let objects: Vec<_> = plans.iter().map(|p| p.object_box).collect();
        let (loss, proposals) =
            ensemble_loss(&self.detectors, &images, &objects, &self.config, goal)?;
        let loss_value = loss
            .clone()
            .into_data()
            .convert::<f64>()
            .try_to_vec::<f64>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))?[0];
        let ms_forward = t1.elapsed().as_secs_f64() * 1e3;
        let t2 = Instant::now();
        let grads = loss.backward();
        let g = atlas
            .grad(&grads)
            .context("no gradient reached the atlas")?
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let ms_backward = t2.elapsed().as_secs_f64() * 1e3;
        let t3 = Instant::now();
        let grad_norm = g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
        if !loss_value.is_finite() {
            bail!("iteration {i}: the loss is not finite ({loss_value})");
        }
        let k = self.state.scales;
        if k == 1 {
            self.state.adam.step(&mut self.state.atlas, &g);
        } else {
            let gp = pyramid::adjoint(&g, r, k, &self.paintable);
            self.state.adam.step_unclipped(&mut self.state.atlas, &gp);
            pyramid::project(&mut self.state.atlas, r, k, &self.paintable);
        }
        let ms_optimiser = t3.elapsed().as_secs_f64() * 1e3;
        let log = IterationLog {
            iteration: i,
            loss: loss_value,
            grad_norm,
            proposals,
            ms_render,
            ms_forward,
            ms_backward,
            ms_optimiser,
        };
        self.state.log.push(log.clone());
        self.state.iteration += 1;
        Ok(log)
    }
}

/// The batch of conditions of iteration `i`: a pure function of the run seed and `i`, so a
/// resumed run draws the same batches; brightness alternates bright, dark.
pub fn draw_conditions(env: &Environment, config: &AttackConfig, i: usize) -> Vec<Condition> {
    let mut rng = ChaCha8Rng::seed_from_u64(
        config.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (i as u64).wrapping_add(1),
    );
    (0..config.batch)
        .map(|k| {
            let b = if k % 2 == 0 {
                Brightness::Bright
            } else {
                Brightness::Dark
            };
            env.sample(config.viewpoints, b, &mut rng)
        })
        .collect()
}

/// A training run the CLI can drive: CAC and the 3D baselines ([`Trainer`]) or the 2D patch
/// baselines ([`baselines::PatchTrainer`]).
pub trait Run {
    fn config(&self) -> &AttackConfig;
    /// Iteration count, optimiser state and log (for 2D methods the state's atlas is the patch).
    fn state(&self) -> &Checkpoint;
    fn step(&mut self) -> Result<IterationLog>;
    /// The camouflage atlas as it goes on the object.
    fn atlas(&self) -> Texture;
    fn renderer(&self) -> &Renderer;
    fn env(&self) -> &Environment;
    /// Extra images for the run folder (name, image), e.g. the 2D patch.
    fn extra_images(&self) -> Vec<(String, image::RgbImage)> {
        vec![]
    }
}

impl Run for Trainer<'_> {
    fn config(&self) -> &AttackConfig {
        &self.config
    }
    fn state(&self) -> &Checkpoint {
        &self.state
    }
    fn step(&mut self) -> Result<IterationLog> {
        Trainer::step(self)
    }
    fn atlas(&self) -> Texture {
        Trainer::atlas(self)
    }
    fn renderer(&self) -> &Renderer {
        self.renderer
    }
    fn env(&self) -> &Environment {
        self.env
    }
}

/// The loss of one image batch averaged over the source detectors (an ensemble), and the number of
/// fixed proposals it was taken over; `objects` are the object's boxes in the images. Shared by the
/// 3D trainer and the 2D patch trainer.
pub fn ensemble_loss(
    detectors: &[&dyn Detector],
    images: &Tensor<4>,
    objects: &[Option<[f32; 4]>],
    config: &AttackConfig,
    goal: Goal,
) -> Result<(Tensor<1>, usize)> {
    let mut total: Option<Tensor<1>> = None;
    let mut proposals = 0;
    let sel = baselines::objectives::Selection {
        rule: config.proposals,
        top_n: config.top_n,
        nms_iou: config.nms_iou,
        overlap_iou: config.overlap_iou,
        objects,
    };
    for det in detectors {
        let c = det.candidates(images.clone())?;
        let (l, n) = baselines::objective(config.method, c, &sel, goal)?;
        proposals += n;
        total = Some(match total {
            Some(t) => t + l,
            None => l,
        });
    }
    Ok((
        total.context("no detector")? / detectors.len() as f64,
        proposals,
    ))
}

const CHECKPOINT: &str = "checkpoint";

/// Writes the checkpoint into `run_dir/checkpoint/` atomically (a new folder renamed into place).
pub fn save_checkpoint(run_dir: &Path, ck: &Checkpoint) -> Result<()> {
    std::fs::create_dir_all(run_dir)
        .with_context(|| format!("cannot create run folder {}", run_dir.display()))?;
    let tmp = run_dir.join(format!("{CHECKPOINT}.tmp"));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp)?;
    let bin = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    crate::io::write_atomic(&tmp.join("atlas.f32"), &bin(&ck.atlas))?;
    crate::io::write_atomic(&tmp.join("adam_m.f32"), &bin(&ck.adam.m))?;
    crate::io::write_atomic(&tmp.join("adam_v.f32"), &bin(&ck.adam.v))?;
    let meta = serde_json::json!({
        "iteration": ck.iteration, "atlas_res": ck.atlas_res, "scales": ck.scales,
        "adam": {"lr": ck.adam.lr, "beta1": ck.adam.beta1, "beta2": ck.adam.beta2, "eps": ck.adam.eps, "t": ck.adam.t},
        "log": ck.log,
    });
    crate::io::write_atomic(
        &tmp.join("state.json"),
        serde_json::to_string(&meta)?.as_bytes(),
    )?;
    let dst = run_dir.join(CHECKPOINT);
    let old = run_dir.join(format!("{CHECKPOINT}.old"));
    let _ = std::fs::remove_dir_all(&old);
    if dst.exists() {
        std::fs::rename(&dst, &old)?;
    }
    std::fs::rename(&tmp, &dst)?;
    let _ = std::fs::remove_dir_all(&old);
    Ok(())
}

/// Reads the newest complete checkpoint of a run folder.
pub fn load_checkpoint(run_dir: &Path) -> Result<Checkpoint> {
    let dir = [CHECKPOINT, "checkpoint.old"]
        .iter()
        .map(|n| run_dir.join(n))
        .find(|d| d.join("state.json").is_file())
        .with_context(|| format!("{} holds no checkpoint to resume from", run_dir.display()))?;
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("state.json"))?)
            .with_context(|| format!("{}: malformed checkpoint state", dir.display()))?;
    let f32s = |name: &str| -> Result<Vec<f32>> {
        let b = std::fs::read(dir.join(name))
            .with_context(|| format!("{}: missing {name}", dir.display()))?;
        if b.len() % 4 != 0 {
            bail!("{}: {name} is truncated", dir.display());
        }
        Ok(b.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    };
    let res = meta["atlas_res"]
        .as_u64()
        .context("checkpoint lacks atlas_res")? as usize;
    // Checkpoints written before the multi-scale parameterisation hold one level.
    let scales = meta["scales"].as_u64().unwrap_or(1) as usize;
    if !(1..=8).contains(&scales) {
        bail!(
            "{}: checkpoint has {scales} atlas levels (1..=8)",
            dir.display()
        );
    }
    let atlas = f32s("atlas.f32")?;
    let (m, v) = (f32s("adam_m.f32")?, f32s("adam_v.f32")?);
    let want = pyramid::len(res, scales);
    if atlas.len() != want || m.len() != want || v.len() != want {
        bail!(
            "{}: checkpoint arrays do not match a {res}² atlas in {scales} level(s)",
            dir.display()
        );
    }
    let a = &meta["adam"];
    let adam = Adam {
        lr: a["lr"].as_f64().context("adam.lr")? as f32,
        beta1: a["beta1"].as_f64().context("adam.beta1")? as f32,
        beta2: a["beta2"].as_f64().context("adam.beta2")? as f32,
        eps: a["eps"].as_f64().context("adam.eps")? as f32,
        t: a["t"].as_u64().context("adam.t")?,
        m,
        v,
    };
    let log: Vec<IterationLog> =
        serde_json::from_value(meta["log"].clone()).context("checkpoint log")?;
    Ok(Checkpoint {
        iteration: meta["iteration"].as_u64().context("iteration")? as usize,
        atlas_res: res,
        scales,
        adam,
        atlas,
        log,
    })
}
