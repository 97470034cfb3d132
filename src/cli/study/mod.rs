//! `cac study topn`: the denseness study (the paper's Figure 5). Trains CAC once per number of
//! fixed proposals n (reusing finished runs and resuming unfinished ones in OUT/n<N>/), evaluates
//! every learned texture and the original with the protocol on the evaluation models (a model
//! not among the sources measures transfer), and plots P@0.5 against n (OUT/topn.png, topn.csv,
//! topn.md, topn.html; the full evaluation report in OUT/eval/). Defaults are small so the study finishes
//! on a laptop in minutes; `--iterations 2000 --views 200 --size 512` approaches the paper's.
//! Under the default proposal rule (the candidates on the object, about 30 per image) n caps how
//! many of them are fixed, hence the small default values; `--proposals topn --n 50,100,200,300`
//! is the paper's Figure 5 (top-n after NMS over the whole image).

mod methods;

use super::{device, eval::parse_sets, train};
use anyhow::{bail, Context, Result};
use cac::attack::{run::RunDir, AttackConfig, Trainer};
use cac::config::{SceneConfig, Stage};
use cac::environment::ViewpointSet;
use cac::eval::job::{self, EvalJob};
use cac::eval::run::ViewPlan;
use cac::eval::{study, Protocol};
use cac::report::Html;
use std::path::{Path, PathBuf};

#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// P@0.5 against the number of fixed proposals n.
    Topn(TopnArgs),
    /// CAC and the paper's baselines trained alike and judged by the protocol.
    Methods(methods::Args),
}

#[derive(clap::Args, Debug)]
pub struct TopnArgs {
    /// Values of n, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,4,16,64")]
    pub n: Vec<usize>,
    /// Which candidates are fixed: `overlap` (on the object, the n best) or `topn` (the paper's).
    #[arg(long, value_enum, default_value_t = cac::attack::loss::ProposalRule::Overlap)]
    pub proposals: cac::attack::loss::ProposalRule,
    /// Scene config (default: the demo's scene, the pickup at street level, 320² renders).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Source detectors the attack trains against, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "nanodet")]
    pub models: Vec<String>,
    /// Detectors the textures are evaluated on (those not among --models measure transfer).
    #[arg(long, value_delimiter = ',', default_value = "centernet,nanodet")]
    pub eval_models: Vec<String>,
    #[arg(long, default_value = "person")]
    pub target: String,
    /// Training iterations per run.
    #[arg(long, default_value_t = 30)]
    pub iterations: usize,
    #[arg(long, default_value_t = 2)]
    pub batch: usize,
    /// Evaluation views per brightness level and set.
    #[arg(long, default_value_t = 6)]
    pub views: usize,
    /// Evaluation viewpoint sets (fv, rv).
    #[arg(long, value_delimiter = ',', default_value = "fv")]
    pub sets: Vec<String>,
    /// Evaluation image side (default: the config's).
    #[arg(long)]
    pub size: Option<usize>,
    /// Seed of the training runs and of the evaluation views.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long, default_value = "study-topn")]
    pub out: PathBuf,
    // Sweep entry points (cac slurm study topn, docs/sweeps.md).
    /// Train only setting K (the K-th value of --n, from 0) and exit: one array task per setting.
    #[arg(long, value_name = "K", conflicts_with_all = ["shard", "merge"])]
    pub task: Option<usize>,
    /// Evaluate only shard K of N of the study's evaluation and exit (every run must be finished).
    #[arg(long, value_name = "K/N", conflicts_with = "merge")]
    pub shard: Option<cac::eval::shard::Shard>,
    /// Write the study from the evaluation's shard files, rendering nothing.
    #[arg(long)]
    pub merge: bool,
}

pub fn run(c: Cmd) -> Result<()> {
    match c {
        Cmd::Topn(a) => topn(a),
        Cmd::Methods(a) => methods::run(a),
    }
}

fn topn(a: TopnArgs) -> Result<()> {
    if a.n.is_empty() || a.n.contains(&0) {
        bail!("--n needs positive values");
    }
    let cfg = match &a.config {
        Some(p) => SceneConfig::from_file(p)?,
        None => {
            let mut c = SceneConfig::training();
            c.object.mesh = "pickup".into();
            c
        }
    };
    let specs = train_runs(&a, &cfg)?;
    if a.task.is_some() {
        return Ok(());
    }
    evaluate(&a, &cfg, specs)
}

/// Trains (or reuses, or resumes) one run per n in OUT/n<N>/; returns the texture specs for the
/// evaluation, the original first.
fn train_runs(a: &TopnArgs, cfg: &SceneConfig) -> Result<Vec<String>> {
    let stage = cfg.stage()?;
    let sources = train::load_detectors(&a.models)?;
    let src: Vec<&dyn cac::detect::Detector> = sources.iter().map(|d| d.as_ref()).collect();
    let mut specs = vec!["original".to_string()];
    // Sweep: --task K trains setting K only; --shard and --merge train nothing.
    if let Some(k) = a.task.filter(|&k| k >= a.n.len()) {
        bail!(
            "--task {k} is out of range: the study has {} setting(s) (--n), tasks 0 to {}",
            a.n.len(),
            a.n.len() - 1
        );
    }
    for (k, &n) in a.n.iter().enumerate() {
        if a.task.is_some_and(|t| t != k) {
            continue;
        }
        let dir = a.out.join(format!("n{n}"));
        let ac = AttackConfig {
            models: a.models.clone(),
            target: a.target.clone(),
            proposals: a.proposals,
            top_n: n,
            batch: a.batch,
            iterations: a.iterations,
            seed: a.seed,
            checkpoint_every: 10,
            viewpoints: ViewpointSet::Free,
            ..Default::default()
        };
        let read_only = (a.shard.is_some() || a.merge).then(|| format!("--task {k}"));
        train_one(
            &dir,
            cfg,
            ac,
            &stage,
            &src,
            &format!("n = {n}"),
            read_only.as_deref(),
        )?;
        specs.push(format!("{}={}", study::run_name(n), dir.display()));
    }
    Ok(specs)
}

/// Trains (resuming a checkpoint) the run in `dir` up to `ac.iterations`, or only reads it when
/// it is finished; with `read_only` (the hint of the command that trains it) an unfinished run is
/// an error. Returns the run's logged training seconds (the iterations' own times).
fn train_one(
    dir: &Path,
    cfg: &SceneConfig,
    ac: AttackConfig,
    stage: &Stage,
    src: &[&dyn cac::detect::Detector],
    label: &str,
    read_only: Option<&str>,
) -> Result<f64> {
    let iterations = ac.iterations;
    let run = RunDir::open_or_create(dir, cfg.clone(), ac.clone())?;
    let tr = Trainer::new(
        ac,
        &stage.renderer,
        &stage.env,
        src.to_vec(),
        device::training(),
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

/// Evaluates the textures with the protocol and writes the study's table, plot and pages.
fn evaluate(a: &TopnArgs, cfg: &SceneConfig, specs: Vec<String>) -> Result<()> {
    let mut eval_scene = cfg.clone();
    if let Some(s) = a.size {
        (eval_scene.render.width, eval_scene.render.height) = (s, s);
    }
    let target = cac::detect::labels::class_id(&a.target)
        .with_context(|| format!("unknown target class {:?}", a.target))?;
    let job = EvalJob {
        scene: eval_scene,
        textures: specs,
        plan: ViewPlan {
            views_per_level: a.views,
            seed: a.seed,
            sets: parse_sets(&a.sets)?,
            ..Default::default()
        },
        protocol: Protocol {
            target: Some(target),
            ..Default::default()
        },
        examples_per_group: 1,
        figures: vec![],
        out: a.out.join("eval"),
    };
    let evals = train::load_detectors(&a.eval_models)?;
    let refs: Vec<&dyn cac::detect::Detector> = evals.iter().map(|d| d.as_ref()).collect();
    println!(
        "evaluating {} textures on {} ...",
        job.textures.len(),
        a.eval_models.join(", ")
    );
    let o = match (a.shard, a.merge) {
        (Some(s), _) => {
            let o = job::run_shard(&job, s, &refs, &device::inference(), &mut |_, _| {})?;
            super::eval::print_shard(&o);
            return Ok(());
        }
        (None, true) => job::merge(&job, &refs, &device::inference())?,
        (None, false) => job::run(&job, &refs, &device::inference(), &mut |_, _| {})?,
    };
    let t = study::topn_table(&o.records, &a.n, &o.info.models, &a.models);
    let img = study::topn_plot(&o.records, &a.n, &o.info.models, &a.models)?;
    cac::io::save_png_atomic(&a.out.join("topn.png"), &img)?;
    cac::io::write_atomic(&a.out.join("topn.csv"), t.csv().as_bytes())?;
    let md = format!(
        "# Top-n denseness study\n\n```\n{}\ntraining: {} iterations, batch {}, sources {}, target {:?}, seed {}\n```\n\n{}",
        cac::eval::report::protocol_text(&o.info),
        a.iterations,
        a.batch,
        a.models.join(", "),
        a.target,
        a.seed,
        t.markdown()
    );
    cac::io::write_atomic(&a.out.join("topn.md"), md.as_bytes())?;
    let mut h = Html::new("Top-n denseness study");
    h.pre(&cac::eval::report::protocol_text(&o.info))
        .table(&t)
        .image(
            &img,
            "P@0.5 against n (error bars: binomial standard error)",
        )?;
    h.paragraph("The full evaluation (tables, breakdowns, example views): eval/report.html.");
    cac::io::write_atomic(&a.out.join("topn.html"), h.finish().as_bytes())?;
    println!(
        "{md}\nwrote {}/topn.png, topn.csv, topn.md, topn.html and eval/",
        a.out.display()
    );
    Ok(())
}
