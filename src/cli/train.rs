//! `cac train`: learn a camouflage with CAC or a baseline (`--method`); writes a run folder
//! (run.json, atlas.png, views.png, loss.png, checkpoints, and patch.png for 2D methods) and resumes
//! with `--resume DIR`.

use super::device;
use anyhow::{bail, Context, Result};
use cac::attack::{self, baselines::PatchTrainer, AttackConfig, Method, Run, Trainer};
use cac::config::SceneConfig;
use cac::detect::{self, Detector};
use cac::environment::{Environment, ViewpointSet};
use cac::render::Renderer;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

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
    #[arg(long, default_value = "nanodet", value_delimiter = ',')]
    pub models: Vec<String>,
    /// Target COCO class.
    #[arg(long, default_value = "person")]
    pub target: String,
    /// Non-targeted mode: hide the object (suppress every class).
    #[arg(long)]
    pub hide: bool,
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
    let run_dir = a.resume.clone().unwrap_or_else(|| a.out.clone());
    let (cfg, attack_cfg) = if let Some(dir) = &a.resume {
        let run: serde_json::Value = serde_json::from_slice(
            &std::fs::read(dir.join("run.json"))
                .with_context(|| format!("{} is not a run folder (no run.json)", dir.display()))?,
        )
        .with_context(|| format!("{}: malformed run.json", dir.display()))?;
        let cfg: SceneConfig =
            serde_json::from_value(run["scene"].clone()).context("run.json: scene")?;
        let mut ac: AttackConfig =
            serde_json::from_value(run["attack"].clone()).context("run.json: attack")?;
        ac.iterations = ac.iterations.max(a.iterations);
        (cfg, ac)
    } else {
        if run_dir.join("run.json").exists() {
            bail!(
                "{} already holds a run: use --resume {} or another --out",
                run_dir.display(),
                run_dir.display()
            );
        }
        let mut cfg = match &a.config {
            Some(p) => SceneConfig::from_file(p)?,
            None => SceneConfig::training(),
        };
        if let Some(r) = a.texture_res {
            cfg.render.atlas_res = r;
        }
        let ac = AttackConfig {
            method: a.method,
            patch_res: a.patch_res,
            patch_tiles: a.patch_tiles,
            models: a.models.clone(),
            target: a.target.clone(),
            hide: a.hide,
            proposals: a.proposals,
            overlap_iou: a.overlap_iou,
            scales: a.scales,
            top_n: a.top_n,
            batch: a.batch,
            iterations: a.iterations,
            lr: a.lr,
            seed: a.seed,
            checkpoint_every: a.checkpoint_every,
            viewpoints: if a.restricted {
                ViewpointSet::Restricted
            } else {
                ViewpointSet::Free
            },
            ..Default::default()
        };
        ac.validate()?;
        if !a.method.is_targeted() && a.target != "person" {
            eprintln!(
                "note: {} is non-targeted; --target {:?} is ignored",
                a.method.name(),
                a.target
            );
        }
        (cfg, ac)
    };
    let scene = cfg.object.load()?;
    let init = match &a.init {
        Some(p) => cac::scene::Texture::from_rgb8(
            &cac::io::load_rgb(p).with_context(|| format!("--init {}", p.display()))?,
        ),
        None => scene.initial_atlas(cfg.render.atlas_res),
    };
    let renderer = Renderer::new(scene, cfg.render.clone())?;
    let env = Environment::new(cfg.environment.clone())?;
    let dets = load_detectors(&attack_cfg.models)?;
    let dets_ref: Vec<&dyn Detector> = dets.iter().map(|d| d.as_ref()).collect();
    let dev = device::training();
    let mut tr: Box<dyn Run> = if attack_cfg.method.is_2d() {
        let t = PatchTrainer::new(attack_cfg.clone(), &renderer, &env, dets_ref, dev, &init)?;
        Box::new(match &a.resume {
            Some(d) => t.resume(d)?,
            None => t,
        })
    } else {
        let t = Trainer::new(attack_cfg.clone(), &renderer, &env, dets_ref, dev, &init)?;
        Box::new(match &a.resume {
            Some(d) => t.resume(d)?,
            None => t,
        })
    };
    if a.resume.is_some() {
        println!(
            "resuming {} at iteration {}",
            run_dir.display(),
            tr.state().iteration
        );
    }
    train_loop(tr.as_mut(), &run_dir, &cfg, true)?;
    println!("wrote {}", run_dir.display());
    Ok(())
}

/// Loads detectors by name on the inference device (gradients flow through their inputs).
pub fn load_detectors(names: &[String]) -> Result<Vec<Box<dyn Detector>>> {
    detect::load_all(names, None, &device::inference())
}

/// Runs the remaining iterations with a progress bar, checkpointing and writing the run folder.
pub fn train_loop(
    tr: &mut dyn Run,
    run_dir: &Path,
    cfg: &SceneConfig,
    progress: bool,
) -> Result<()> {
    std::fs::create_dir_all(run_dir)
        .with_context(|| format!("cannot create run folder {}", run_dir.display()))?;
    let total = tr.config().iterations;
    let pb = if progress {
        ProgressBar::new(total as u64)
    } else {
        ProgressBar::hidden()
    };
    pb.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} iterations, loss {msg}, ETA {eta}")
            .expect("template"),
    );
    pb.set_position(tr.state().iteration as u64);
    write_run(tr, run_dir, cfg, false)?;
    while tr.state().iteration < total {
        let log = tr.step()?;
        pb.set_message(format!("{:.4}", log.loss));
        pb.inc(1);
        let (k, it) = (tr.config().checkpoint_every, tr.state().iteration);
        if k > 0 && it % k == 0 && it < total {
            attack::save_checkpoint(run_dir, tr.state())?;
            write_run(tr, run_dir, cfg, false)?;
        }
    }
    pb.finish_and_clear();
    attack::save_checkpoint(run_dir, tr.state())?;
    write_run(tr, run_dir, cfg, true)
}

fn write_run(tr: &dyn Run, run_dir: &Path, cfg: &SceneConfig, finished: bool) -> Result<()> {
    let run = serde_json::json!({
        "cac_version": env!("CARGO_PKG_VERSION"),
        "burn_version": "0.22.1",
        "finished": finished,
        "seed": tr.config().seed,
        "method": tr.config().method,
        "attack": tr.config(),
        "scene": cfg,
        "iteration": tr.state().iteration,
        "log": tr.state().log,
    });
    cac::io::write_atomic(
        &run_dir.join("run.json"),
        serde_json::to_string_pretty(&run)?.as_bytes(),
    )?;
    let atlas = tr.atlas();
    cac::io::save_png_atomic(&run_dir.join("atlas.png"), &atlas.to_rgb8())?;
    for (name, img) in tr.extra_images() {
        cac::io::save_png_atomic(&run_dir.join(name), &img)?;
    }
    let title = format!("{} loss", tr.config().method.name());
    let plot = attack::report::loss_plot(&tr.state().log, &title, 640, 400)?;
    cac::io::save_png_atomic(&run_dir.join("loss.png"), &plot)?;
    if finished {
        let sheet =
            attack::report::views_sheet(tr.renderer(), tr.env(), &atlas, 8, &device::inference())?;
        cac::io::save_png_atomic(&run_dir.join("views.png"), &sheet)?;
    }
    Ok(())
}
