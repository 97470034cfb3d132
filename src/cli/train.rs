//! `cac train`: learn a camouflage; writes a run folder (run.json, atlas.png, views.png,
//! checkpoints) and resumes with `--resume DIR`.

use super::device;
use anyhow::{bail, Context, Result};
use cac::attack::{self, AttackConfig, Trainer};
use cac::config::SceneConfig;
use cac::detect::{self, Detector};
use cac::environment::{Environment, ViewpointSet};
use cac::render::Renderer;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Scene config (TOML); defaults to the built-in jeep and the paper's environment.
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
    /// Fixed proposals per image (the paper's n).
    #[arg(long, default_value_t = 300)]
    pub top_n: usize,
    #[arg(long, default_value_t = 2)]
    pub batch: usize,
    #[arg(long, default_value_t = 200)]
    pub iterations: usize,
    #[arg(long, default_value_t = 0.02)]
    pub lr: f32,
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
            None => SceneConfig::default(),
        };
        if let Some(r) = a.texture_res {
            cfg.render.atlas_res = r;
        }
        let ac = AttackConfig {
            models: a.models.clone(),
            target: a.target.clone(),
            hide: a.hide,
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
        (cfg, ac)
    };
    let scene = cfg.object.load()?;
    let init = match &a.init {
        Some(p) => cac::scene::Texture::from_rgb8(&cac::io::load_rgb(p)?),
        None => scene.initial_atlas(cfg.render.atlas_res),
    };
    let renderer = Renderer::new(scene, cfg.render.clone())?;
    let env = Environment::new(cfg.environment.clone())?;
    let dets = load_detectors(&attack_cfg.models)?;
    let mut tr = Trainer::new(
        attack_cfg.clone(),
        &renderer,
        &env,
        dets.iter().map(|d| d.as_ref()).collect(),
        device::training(),
        &init,
    )?;
    if a.resume.is_some() {
        tr = tr.resume(&run_dir)?;
        println!(
            "resuming {} at iteration {}",
            run_dir.display(),
            tr.state.iteration
        );
    }
    train_loop(&mut tr, &run_dir, &cfg, true)?;
    println!("wrote {}", run_dir.display());
    Ok(())
}

/// Loads detectors by name on the inference device (gradients flow through their inputs).
pub fn load_detectors(names: &[String]) -> Result<Vec<Box<dyn Detector>>> {
    let dir = detect::fetch::ensure_models()?;
    names
        .iter()
        .map(|n| detect::load(n, &dir, &device::inference()))
        .collect()
}

/// Runs the remaining iterations with a progress bar, checkpointing and writing the run folder.
pub fn train_loop(
    tr: &mut Trainer,
    run_dir: &Path,
    cfg: &SceneConfig,
    progress: bool,
) -> Result<()> {
    std::fs::create_dir_all(run_dir)
        .with_context(|| format!("cannot create run folder {}", run_dir.display()))?;
    let total = tr.config.iterations;
    let pb = if progress {
        ProgressBar::new(total as u64)
    } else {
        ProgressBar::hidden()
    };
    pb.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} iterations, loss {msg}, ETA {eta}")
            .expect("template"),
    );
    pb.set_position(tr.state.iteration as u64);
    write_run(tr, run_dir, cfg, false)?;
    while tr.state.iteration < total {
        let log = tr.step()?;
        pb.set_message(format!("{:.4}", log.loss));
        pb.inc(1);
        let k = tr.config.checkpoint_every;
        if k > 0 && tr.state.iteration % k == 0 && tr.state.iteration < total {
            attack::save_checkpoint(run_dir, &tr.state)?;
            write_run(tr, run_dir, cfg, false)?;
        }
    }
    pb.finish_and_clear();
    attack::save_checkpoint(run_dir, &tr.state)?;
    write_run(tr, run_dir, cfg, true)
}

fn write_run(tr: &Trainer, run_dir: &Path, cfg: &SceneConfig, finished: bool) -> Result<()> {
    let run = serde_json::json!({
        "cac_version": env!("CARGO_PKG_VERSION"),
        "burn_version": "0.22.1",
        "finished": finished,
        "seed": tr.config.seed,
        "attack": tr.config,
        "scene": cfg,
        "iteration": tr.state.iteration,
        "log": tr.state.log,
    });
    cac::io::write_atomic(
        &run_dir.join("run.json"),
        serde_json::to_string_pretty(&run)?.as_bytes(),
    )?;
    cac::io::save_png_atomic(&run_dir.join("atlas.png"), &tr.atlas().to_rgb8())?;
    Ok(())
}
