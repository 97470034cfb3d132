//! Studies: experiments that train runs with `attack` and judge the learned textures with
//! `eval`, so they sit after both stages. [`topn`] is the denseness study (`cac study topn`),
//! [`methods`] CAC against the baselines (`cac study methods`), [`demo`] the main job on the
//! embedded defaults (`cac demo`); [`curve`] judges a training run as it goes
//! (`cac train --eval-every`). They share [`train_run`]: one resumable run
//! folder trained up to its iteration count, or only read when it is finished.

pub mod curve;
pub mod demo;
mod figures;
pub mod methods;
pub mod topn;

use crate::job::EvalJob;
use crate::run::ViewPlan;
use crate::Protocol;
use anyhow::{bail, Context, Result};
use burn::tensor::Device;
use cac_attack::AttackConfig;
use cac_attack::Trainer;
use cac_attack::{loss::ProposalRule, run::RunDir};
use cac_detect::Detector;
use cac_render::config::{SceneConfig, Stage};
use cac_render::environment::ViewpointSet;
use std::path::Path;

/// What a study's attacks train against and for (`cac study topn` and `methods` share these
/// flags).
#[derive(Clone, Debug)]
pub struct Source {
    /// Which candidates are fixed: `overlap` (on the object, the n best) or `topn` (the paper's
    /// literal rule: the top n after NMS over the whole image).
    pub proposals: ProposalRule,
    /// Source detectors the attacks train against, comma-separated.
    pub models: Vec<String>,
    /// COCO class the proposals are pushed towards.
    pub target: String,
    pub batch: usize,
}

impl Default for Source {
    /// `cac train`'s: [`AttackConfig::default`]'s proposals, source models, target and batch.
    fn default() -> Self {
        let a = AttackConfig::default();
        Source {
            proposals: a.proposals,
            models: a.models,
            target: a.target,
            batch: a.batch,
        }
    }
}

impl Source {
    /// The attack settings these give, for `iterations` from `seed` (checkpoints every 10). The
    /// four flags repeat [`AttackConfig`]'s (a study takes a subset of `cac train`'s, with its own
    /// `--n` and `--hide`); a unit test keeps their defaults equal.
    pub fn attack(&self, iterations: usize, seed: u64) -> AttackConfig {
        AttackConfig {
            models: self.models.clone(),
            target: self.target.clone(),
            proposals: self.proposals,
            batch: self.batch,
            iterations,
            seed,
            checkpoint_every: 10,
            ..Default::default()
        }
    }
}

/// Trains (resuming a checkpoint) the run in `dir` up to `ac.iterations` on the autodiff device
/// over `device`, or only reads it when it is finished; with `read_only` (the hint of the
/// command that trains it) an unfinished run is an error. Says which on stdout, prefixed with
/// `label`. Returns the run's logged training seconds (the iterations' own times).
#[allow(clippy::too_many_arguments)]
pub(crate) fn train_run(
    dir: &Path,
    cfg: &SceneConfig,
    ac: AttackConfig,
    stage: &Stage,
    src: &[&dyn Detector],
    device: &Device,
    label: &str,
    read_only: Option<&str>,
) -> Result<f64> {
    let iterations = ac.iterations;
    for d in src {
        ac.goal_for(*d).with_context(|| label.to_string())?;
    }
    let run = RunDir::open_or_create(dir, cfg.clone(), ac.clone())?;
    let tr = Trainer::new(
        ac,
        &stage.renderer,
        &stage.env,
        src.to_vec(),
        Device::autodiff(device.clone()),
        &stage.original,
    )?;
    let mut tr = run.resume(tr)?;
    let it = tr.state.iteration;
    if let Some(hint) = read_only.filter(|_| it < iterations) {
        bail!("{label}: the run in {} is not finished (iteration {it} of {iterations}); train it first ({hint})", dir.display());
    }
    if it >= iterations {
        // Read only: evaluation shards running side by side reuse the same finished runs.
        println!("{label}: reusing the finished run in {}", dir.display());
    } else {
        println!(
            "{label}: training iterations {it}..{iterations} in {}",
            dir.display()
        );
        run.train(&mut tr, true)?;
    }
    let ms: f64 = tr
        .state
        .log
        .iter()
        .map(|l| l.ms_render + l.ms_forward + l.ms_backward + l.ms_optimiser)
        .sum();
    Ok(ms / 1000.0)
}

/// The evaluation of a study's textures as `cac eval` judges them: `views` per brightness level
/// and set of `sets`, view seed `seed`, targeted success for class `target`, one example view
/// per group, written to `out/eval`.
pub(crate) fn protocol_job(
    scene: SceneConfig,
    textures: Vec<String>,
    (views, seed, sets): (usize, u64, Vec<ViewpointSet>),
    target: &str,
    out: &Path,
) -> Result<EvalJob> {
    Ok(EvalJob {
        scene,
        textures,
        plan: ViewPlan {
            views_per_level: views,
            seed,
            sets,
            ..Default::default()
        },
        protocol: Protocol::from_labels("car,truck", Some(target))?,
        examples_per_group: 1,
        figures: vec![],
        printer: None,
        out: out.join("eval"),
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_studys_source_defaults_are_train_defaults() {
        let s = super::Source::default();
        let d = cac_attack::AttackConfig::default();
        assert_eq!(
            s.attack(d.iterations, d.seed),
            cac_attack::AttackConfig {
                checkpoint_every: 10,
                ..d
            }
        );
    }
}
