//! `cac train`: learn a camouflage with CAC or a baseline (`--method`); writes a run folder
//! (run.json, atlas.png, views.png, loss.png, checkpoints, and patch.png for 2D methods) and resumes
//! with `--resume DIR`.

use super::device;
use anyhow::{Context, Result};
use cac::attack::run::{Along, Progress, RunDir};
use cac::attack::{AttackConfig, Trainer};
use cac::choice::Choice;
use cac::config::SceneConfig;
use cac::detect::{self, Detector};
use cac::environment::ViewpointSet;
use cac::study::curve::{Curve, CurveSpec};
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Scene config (TOML); defaults to the 10-minute recipe (meshes/pickup/train-10m.toml): the
    /// built-in pickup in the evaluation protocol's scene (512² renders at 4 samples per pixel),
    /// a 256² atlas, half the views lit by an open sky's ambient.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Run folder (created; must be empty unless --resume).
    #[arg(long, default_value = "runs/cac")]
    pub out: PathBuf,
    /// Continue the run in this folder from its last checkpoint.
    #[arg(long)]
    pub resume: Option<PathBuf>,
    #[command(flatten)]
    pub attack: super::flags::attack::AttackFlags,
    /// Atlas side in texels (overrides the config).
    #[arg(long)]
    pub texture_res: Option<usize>,
    /// Initial atlas PNG (default: the object's own texture).
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Train on side views only (the restricted viewpoint set).
    #[arg(long)]
    pub restricted: bool,
    /// Train for this long at most (e.g. `10m`, `1h30m`): a new run's iterations are set to
    /// what fits (timed on its first iterations, then started over; run.json records them) and
    /// the run stops cleanly, checkpointed, when the time is spent. The curve's scoring is not
    /// counted (docs/attack.md, "Quality against run time").
    #[arg(long, value_parser = crate::cli::values::duration)]
    pub budget: Option<f64>,
    /// Score the texture under the protocol every this many seconds of training (and at the
    /// start and end): curve.csv and curve.png in the run folder, on protocol views the training
    /// never draws (--eval-views per group, view seed --eval-seed, 512², 4 spp, --eval-models).
    /// The run's clock stops while it scores.
    #[arg(long)]
    pub eval_every: Option<f64>,
    /// The curve's views per brightness level and viewpoint set (FV/RV × bright/dark).
    #[arg(long, default_value_t = CurveSpec::default().views_per_level)]
    pub eval_views: usize,
    /// The curve's view seed (default 7, the development seed; the protocol judges on 31 and 1234).
    #[arg(long, default_value_t = CurveSpec::default().seed)]
    pub eval_seed: u64,
    /// The curve's models (the protocol's: the source and an unseen one).
    #[arg(long, value_delimiter = ',', default_value = "nanodet,centernet", value_parser = crate::cli::values::MODEL_SPECS)]
    pub eval_models: Vec<String>,
    /// Where stderr is not a terminal (a file, a pipe, a Slurm job), a progress line every this
    /// many seconds (iteration, loss, ms per iteration, the latest curve point, time left); on a
    /// terminal, a progress bar.
    #[arg(long, default_value_t = 30.0)]
    pub progress_every: f64,
}

pub fn run(a: Args) -> Result<()> {
    // A new run's classes are resolved against its models before its folder is made, so a
    // class a model lacks leaves nothing behind to clash with the corrected command.
    let checked = match &a.resume {
        Some(_) => None,
        None => {
            let ac = attack_config(&a);
            ac.validate()?;
            let dets = defended(load_detectors(&ac.models)?, &ac)?;
            for d in &dets {
                ac.goal_for(d.as_ref())?;
            }
            Some(dets)
        }
    };
    let run = match &a.resume {
        Some(dir) => {
            let mut run = RunDir::open(dir)?;
            run.attack.iterations = run.attack.iterations.max(a.attack.iterations);
            run
        }
        None => RunDir::create(&a.out, scene_config(&a)?, attack_config(&a))?,
    };
    let m = a.attack.method;
    if a.resume.is_none() && !m.is_targeted() && a.attack.target != "person" {
        eprintln!(
            "note: {} is non-targeted; --target {:?} is ignored",
            m.name(),
            a.attack.target
        );
    }
    let stage = run.scene.stage()?;
    let init = match &a.init {
        Some(p) => cac::scene::Texture::from_rgb8(
            &cac::io::load_rgb(p).with_context(|| format!("--init {}", p.display()))?,
        ),
        None => stage.original.clone(),
    };
    let dets = match checked {
        Some(d) => d,
        None => defended(load_detectors(&run.attack.models)?, &run.attack)?,
    };
    let dets_ref = cac::detect::refs(&dets);
    let tr = Trainer::new(
        run.attack.clone(),
        &stage.renderer,
        &stage.env,
        dets_ref,
        device::training(),
        &init,
    )?;
    let tr = tr.through_printer(&run.attack)?;
    if let Some(f) = tr.filaments() {
        println!("training {}", f.describe());
    }
    let mut tr = run.resume(tr)?;
    if a.resume.is_some() {
        println!(
            "resuming {} at iteration {}",
            run.path.display(),
            tr.state.iteration
        );
    }
    let curve_dets = match a.eval_every {
        Some(_) => detect::load_all(&a.eval_models, None, &device::inference())?,
        None => vec![],
    };
    let along = Along {
        progress: progress(a.progress_every),
        budget_s: a.budget,
        curve: match a.eval_every {
            Some(every_s) => Some(Box::new(Curve::new(
                CurveSpec {
                    every_s,
                    views_per_level: a.eval_views,
                    seed: a.eval_seed,
                    models: a.eval_models.clone(),
                },
                &run.scene,
                cac::detect::refs(&curve_dets),
                (!run.attack.hide && run.attack.method.is_targeted())
                    .then_some(run.attack.target.as_str()),
                device::inference(),
            )?)),
            None => None,
        },
    };
    run.train_along(&mut tr, along)?;
    println!("wrote {}", run.path.display());
    Ok(())
}

/// A progress bar on a terminal; otherwise a line every `every_s` seconds.
fn progress(every_s: f64) -> Progress {
    if std::io::stderr().is_terminal() {
        Progress::Bar
    } else {
        Progress::Lines { every_s }
    }
}

/// The scene of a new run: the config file or the training preset, `--texture-res` applied.
fn scene_config(a: &Args) -> Result<SceneConfig> {
    let mut cfg = SceneConfig::from_file_or(a.config.as_deref(), SceneConfig::ten_minute)?;
    if let Some(r) = a.texture_res {
        cfg.render.atlas_res = r;
    }
    Ok(cfg)
}

/// The attack settings of a new run from the flags.
fn attack_config(a: &Args) -> AttackConfig {
    let mut c = AttackConfig::from(a.attack.clone());
    if a.restricted {
        c.viewpoints = ViewpointSet::Restricted;
    }
    c
}

/// The source models behind the run's defences (one drawn per view; unchanged without any).
fn defended(dets: Vec<Box<dyn Detector>>, ac: &AttackConfig) -> Result<Vec<Box<dyn Detector>>> {
    let chains = detect::defence::parse_chains(&ac.defences)?;
    Ok(detect::defence::through(dets, &chains))
}

/// Loads detectors by name on the inference device (gradients flow through their inputs).
pub fn load_detectors(names: &[String]) -> Result<Vec<Box<dyn Detector>>> {
    detect::load_all(names, None, &device::inference())
}
