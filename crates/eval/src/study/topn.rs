//! The top-n denseness study (the paper's Figure 5): one CAC run per number of fixed proposals
//! n in OUT/n<N>/ (reused when finished, resumed when not), every learned texture and the
//! original evaluated with the protocol on the evaluation models (a model not among the sources
//! measures transfer), and P@0.5 against n written as OUT/topn.png, topn.csv, topn.md and
//! topn.html (the full evaluation report in OUT/eval/). A sweep runs it in parts: one training
//! task per setting, evaluation shards, then the merge.

use super::figures;
use super::{protocol_job, train_run};
use crate::job::{self, ShardOutcome};
use crate::report;
use crate::shard::Shard;
use anyhow::{bail, Result};
use burn::tensor::Device;
use cac_attack::AttackConfig;
use cac_core::report::Html;
use cac_detect as detect;
use cac_render::config::SceneConfig;
use cac_render::environment::ViewpointSet;
use std::path::PathBuf;

/// Which part of the study one process does.
#[derive(Debug, Clone, Copy)]
pub enum Part {
    /// Train every setting, evaluate, write the study.
    Whole,
    /// Train setting K only (the K-th value of `n`).
    Task(usize),
    /// Evaluate one shard (every run must be finished).
    Shard(Shard),
    /// Write the study from the shards' files, rendering nothing.
    Merge,
}

/// The study's settings: `cac study topn`'s flags (the scene comes from `--config`, the part
/// from `--task`, `--shard` or `--merge`).
#[derive(Debug, Clone)]
pub struct TopnJob {
    /// The training scene (the evaluation uses it too, at `eval_size` when given).
    pub scene: SceneConfig,
    /// Values of n, comma-separated.
    pub n: Vec<usize>,
    /// What the attacks train against and for.
    pub source: super::Source,
    /// Detectors the textures are evaluated on (those not among --models measure transfer).
    pub eval_models: Vec<String>,
    /// Training iterations per run.
    pub iterations: usize,
    /// Evaluation views per brightness level and set.
    pub views: usize,
    /// Evaluation viewpoint sets (fv, rv); a repeated set counts once.
    pub sets: Vec<ViewpointSet>,
    /// Evaluation image side (default: the scene's).
    pub eval_size: Option<usize>,
    /// Seed of the training runs and of the evaluation views.
    pub seed: u64,
    /// Output folder: one run per n, eval/, topn.png, topn.csv, topn.md and topn.html.
    pub out: PathBuf,
    pub part: Part,
}

impl Default for TopnJob {
    /// n = 1, 4, 16, 64, 30 iterations each from seed 0 on the demo's scene, judged by CenterNet
    /// and NanoDet on 6 free-viewpoint views per level, into `study-topn`.
    fn default() -> Self {
        TopnJob {
            scene: TopnJob::default_scene(),
            n: vec![1, 4, 16, 64],
            source: Default::default(),
            eval_models: ["centernet", "nanodet"].map(String::from).to_vec(),
            iterations: 30,
            views: 6,
            sets: vec![ViewpointSet::Free],
            eval_size: None,
            seed: 0,
            out: PathBuf::from("study-topn"),
            part: Part::Whole,
        }
    }
}

/// What a process of the study did.
pub enum TopnOutcome {
    /// One setting trained (`Part::Task`).
    Trained,
    /// One evaluation shard written.
    Shard(ShardOutcome),
    /// The study written; its Markdown page.
    Written { markdown: String },
}

impl TopnJob {
    /// The scene of the study when no config is given: the training preset on the pickup.
    pub fn default_scene() -> SceneConfig {
        let mut c = SceneConfig::training();
        c.object.mesh = "pickup".into();
        c
    }

    /// Runs this job's part on `device` (inference; training on its autodiff).
    pub fn run(&self, device: &Device) -> Result<TopnOutcome> {
        if self.n.is_empty() || self.n.contains(&0) {
            bail!("--n needs positive values");
        }
        let specs = self.train_runs(device)?;
        if matches!(self.part, Part::Task(_)) {
            return Ok(TopnOutcome::Trained);
        }
        self.evaluate(specs, device)
    }

    /// Trains (or reuses, or resumes) one run per n in OUT/n<N>/; returns the texture specs for
    /// the evaluation, the original first.
    fn train_runs(&self, device: &Device) -> Result<Vec<String>> {
        let stage = self.scene.stage()?;
        let sources = detect::load_all(&self.source.models, None, device)?;
        let src = detect::refs(&sources);
        let mut specs = vec!["original".to_string()];
        let task = match self.part {
            Part::Task(k) => Some(k),
            _ => None,
        };
        // Sweep: a task trains its setting only; a shard or the merge trains nothing.
        if let Some(k) = task.filter(|&k| k >= self.n.len()) {
            bail!(
                "--task {k} is out of range: the study has {} setting(s) (--n), tasks 0 to {}",
                self.n.len(),
                self.n.len() - 1
            );
        }
        for (k, &n) in self.n.iter().enumerate() {
            if task.is_some_and(|t| t != k) {
                continue;
            }
            let dir = self.out.join(format!("n{n}"));
            let ac = AttackConfig {
                top_n: n,
                viewpoints: ViewpointSet::Free,
                ..self.source.attack(self.iterations, self.seed)
            };
            let read_only =
                matches!(self.part, Part::Shard(_) | Part::Merge).then(|| format!("--task {k}"));
            let label = format!("n = {n}");
            let ro = read_only.as_deref();
            train_run(&dir, &self.scene, ac, &stage, &src, device, &label, ro)?;
            specs.push(format!("{}={}", figures::run_name(n), dir.display()));
        }
        Ok(specs)
    }

    /// Evaluates the textures with the protocol and writes the study's table, plot and pages.
    fn evaluate(&self, specs: Vec<String>, device: &Device) -> Result<TopnOutcome> {
        let mut eval_scene = self.scene.clone();
        if let Some(s) = self.eval_size {
            (eval_scene.render.width, eval_scene.render.height) = (s, s);
        }
        let plan = (self.views, self.seed, ViewpointSet::distinct(&self.sets));
        let job = protocol_job(eval_scene, specs, plan, &self.source.target, &self.out)?;
        let evals = detect::load_all(&self.eval_models, None, device)?;
        let refs = detect::refs(&evals);
        println!(
            "evaluating {} textures on {} ...",
            job.textures.len(),
            self.eval_models.join(", ")
        );
        let o = match self.part {
            Part::Shard(s) => {
                let o = job::run_shard(&job, s, &refs, device, &mut |_, _| {})?;
                return Ok(TopnOutcome::Shard(o));
            }
            Part::Merge => job::merge(&job, &refs, device)?,
            _ => job::run(&job, &refs, device, &mut |_, _| {})?,
        };
        let t = figures::topn_table(&o.records, &self.n, &o.info.models, &self.source.models);
        let img = figures::topn_plot(&o.records, &self.n, &o.info.models, &self.source.models)?;
        cac_core::io::save_png_atomic(&self.out.join("topn.png"), &img)?;
        cac_core::io::write_atomic(&self.out.join("topn.csv"), t.csv().as_bytes())?;
        let md = format!(
            "# Top-n denseness study\n\n```\n{}\ntraining: {} iterations, batch {}, sources {}, target {:?}, seed {}\n```\n\n{}",
            report::protocol_text(&o.info),
            self.iterations,
            self.source.batch,
            self.source.models.join(", "),
            self.source.target,
            self.seed,
            t.markdown()
        );
        cac_core::io::write_atomic(&self.out.join("topn.md"), md.as_bytes())?;
        let mut h = Html::new("Top-n denseness study");
        h.pre(&report::protocol_text(&o.info)).table(&t).image(
            &img,
            "P@0.5 against n (error bars: binomial standard error)",
        )?;
        h.paragraph("The full evaluation (tables, breakdowns, example views): eval/report.html.");
        cac_core::io::write_atomic(&self.out.join("topn.html"), h.finish().as_bytes())?;
        Ok(TopnOutcome::Written { markdown: md })
    }
}
