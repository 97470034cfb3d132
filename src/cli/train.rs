//! `cac train`: learn a camouflage with CAC or a baseline (`--method`); writes a run folder
//! (run.json, atlas.png, views.png, loss.png, checkpoints, and patch.png for 2D methods) and resumes
//! with `--resume DIR`.

use super::device;
use anyhow::{Context, Result};
use cac::attack::{run::RunDir, AttackConfig, Method, Trainer};
use cac::config::SceneConfig;
use cac::detect::{self, Detector};
use cac::environment::ViewpointSet;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The attack: cac (this paper) or a baseline (advpat, shapeshifter: 2D patch tiled on the
    /// object; upc, camou: full atlas in 3D). See docs/attack.md.
    #[arg(long, value_enum, default_value_t = Method::Cac)]
    pub method: Method,
    /// Scene config (TOML); defaults to the training preset: the built-in pickup, the
    /// evaluation protocol's environment, 320² renders at 1 sample per pixel, a 256² atlas.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Run folder (created; must be empty unless --resume).
    #[arg(long, default_value = "runs/cac")]
    pub out: PathBuf,
    /// Continue the run in this folder from its last checkpoint.
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Source detectors, comma-separated (an ensemble when several).
    #[arg(long, default_value = "nanodet", value_delimiter = ',', value_parser = cac::detect::spec::MODEL_SPECS)]
    pub models: Vec<String>,
    /// Target COCO class.
    #[arg(long, default_value = "person")]
    pub target: String,
    /// Non-targeted mode: hide the object (suppress --hide-classes in the proposals).
    #[arg(long)]
    pub hide: bool,
    /// The classes --hide suppresses: comma-separated COCO labels, or `all` (every class; it
    /// does not hide the pickup: docs/attack.md).
    #[arg(long, default_value = "car,bus,truck")]
    pub hide_classes: String,
    /// Which candidates the loss fixes: `overlap` (those on the object's box, IoU >=
    /// --overlap-iou) or `topn` (the top n after NMS over the whole image). See docs/attack.md.
    #[arg(long, value_enum, default_value_t = cac::attack::loss::ProposalRule::Overlap)]
    pub proposals: cac::attack::loss::ProposalRule,
    /// Least IoU with the object's box of an `overlap` proposal.
    #[arg(long, default_value_t = 0.5)]
    pub overlap_iou: f64,
    /// Fixed proposals per image at most (the paper's n).
    #[arg(long, default_value_t = 300)]
    pub top_n: usize,
    #[arg(long, default_value_t = 2)]
    pub batch: usize,
    #[arg(long, default_value_t = 200)]
    pub iterations: usize,
    #[arg(long, default_value_t = 0.02)]
    pub lr: f32,
    /// Learning-rate schedule: constant, or cosine (annealed from --lr to 0 over --iterations).
    #[arg(long, value_enum, default_value_t = cac::attack::LrDecay::Constant)]
    pub lr_decay: cac::attack::LrDecay,
    /// Power of the mean over images of their losses (overlap rule): 1 is the mean, p > 1
    /// weighs the views the texture fails on more (docs/attack.md).
    #[arg(long, default_value_t = 1.0)]
    pub image_power: f32,
    /// Share of the training views drawn within 30° of the front or back (uniform azimuth: 1/3).
    #[arg(long)]
    pub front_back_share: Option<f32>,
    /// Levels of the atlas's multi-scale parameterisation: 1 optimises texel by texel; K adds
    /// K-1 coarser levels (each half the side of the last) whose sum is the atlas.
    #[arg(long, default_value_t = 1)]
    pub scales: usize,
    /// Atlas side in texels (overrides the config).
    #[arg(long)]
    pub texture_res: Option<usize>,
    /// Initial atlas PNG (default: the object's own texture).
    #[arg(long)]
    pub init: Option<PathBuf>,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long, default_value_t = 10)]
    pub checkpoint_every: usize,
    /// Train on side views only (the restricted viewpoint set).
    #[arg(long)]
    pub restricted: bool,
    /// 2D methods: side of the patch in texels.
    #[arg(long, default_value_t = 128)]
    pub patch_res: usize,
    /// 2D methods: copies of the patch across the atlas side when it is put on the object.
    #[arg(long, default_value_t = 4)]
    pub patch_tiles: usize,
}

pub fn run(a: Args) -> Result<()> {
    let run = match &a.resume {
        Some(dir) => {
            let mut run = RunDir::open(dir)?;
            run.attack.iterations = run.attack.iterations.max(a.iterations);
            run
        }
        None => RunDir::create(&a.out, scene_config(&a)?, attack_config(&a))?,
    };
    if a.resume.is_none() && !a.method.is_targeted() && a.target != "person" {
        eprintln!(
            "note: {} is non-targeted; --target {:?} is ignored",
            a.method.name(),
            a.target
        );
    }
    let stage = run.scene.stage()?;
    let init = match &a.init {
        Some(p) => cac::scene::Texture::from_rgb8(
            &cac::io::load_rgb(p).with_context(|| format!("--init {}", p.display()))?,
        ),
        None => stage.original.clone(),
    };
    let dets = load_detectors(&run.attack.models)?;
    let dets_ref = cac::detect::refs(&dets);
    let tr = Trainer::new(
        run.attack.clone(),
        &stage.renderer,
        &stage.env,
        dets_ref,
        device::training(),
        &init,
    )?;
    let mut tr = run.resume(tr)?;
    if a.resume.is_some() {
        println!(
            "resuming {} at iteration {}",
            run.path.display(),
            tr.state.iteration
        );
    }
    run.train(&mut tr, true)?;
    println!("wrote {}", run.path.display());
    Ok(())
}

/// The scene of a new run: the config file or the training preset, `--texture-res` applied.
fn scene_config(a: &Args) -> Result<SceneConfig> {
    let mut cfg = SceneConfig::from_file_or(a.config.as_deref(), SceneConfig::training)?;
    if let Some(r) = a.texture_res {
        cfg.render.atlas_res = r;
    }
    Ok(cfg)
}

/// The attack settings of a new run from the flags.
fn attack_config(a: &Args) -> AttackConfig {
    AttackConfig {
        method: a.method,
        patch_res: a.patch_res,
        patch_tiles: a.patch_tiles,
        models: a.models.clone(),
        target: a.target.clone(),
        hide: a.hide,
        hide_classes: a.hide_classes.clone(),
        proposals: a.proposals,
        overlap_iou: a.overlap_iou,
        scales: a.scales,
        image_power: a.image_power,
        front_back_share: a.front_back_share,
        top_n: a.top_n,
        batch: a.batch,
        iterations: a.iterations,
        lr: a.lr,
        lr_decay: a.lr_decay,
        seed: a.seed,
        checkpoint_every: a.checkpoint_every,
        viewpoints: if a.restricted {
            ViewpointSet::Restricted
        } else {
            ViewpointSet::Free
        },
        ..Default::default()
    }
}

/// Loads detectors by name on the inference device (gradients flow through their inputs).
pub fn load_detectors(names: &[String]) -> Result<Vec<Box<dyn Detector>>> {
    detect::load_all(names, None, &device::inference())
}
