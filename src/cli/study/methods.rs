//! `cac study methods`: CAC and the paper's baselines in one harness, judged where attacks are
//! judged. Every method trains for the same iterations on the same distribution (one resumable
//! run per method in OUT/<method>/, seed `--seed`), then the original, the simple textures and
//! every learned texture are evaluated by `cac eval`'s protocol (FV and RV, bright and dark, its
//! renderer and distances, views of `--eval-seed`; the full report in OUT/eval/), and the table
//! goes to OUT/methods.{md,csv}. CAC uses `--proposals`; each baseline keeps its own paper's
//! choice of what it attacks. `--hide CLASSES` adds a CAC row in hide mode per class set.

use super::train_one;
use crate::cli::{device, eval::parse_sets, train};
use anyhow::{bail, Context, Result};
use cac::attack::{AttackConfig, Method};
use cac::config::SceneConfig;
use cac::eval::job::{self, EvalJob};
use cac::eval::run::ViewPlan;
use cac::eval::{study, Protocol};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Attacks, comma-separated (cac, advpat, shapeshifter, upc, camou).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "cac,advpat,shapeshifter,upc,camou"
    )]
    pub methods: Vec<Method>,
    /// Also train CAC in hide mode suppressing these classes: `all`, or COCO labels joined by
    /// `+` (e.g. car+bus+truck). Repeat for several rows.
    #[arg(long)]
    pub hide: Vec<String>,
    /// CAC's proposals: `overlap` (on the object) or `topn` (the paper's literal rule).
    #[arg(long, value_enum, default_value_t = cac::attack::loss::ProposalRule::Overlap)]
    pub proposals: cac::attack::loss::ProposalRule,
    /// Training scene config (default: `SceneConfig::training()`, the protocol's distribution).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Source detectors, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "nanodet")]
    pub models: Vec<String>,
    /// Detectors the textures are judged by (those not among --models measure transfer).
    #[arg(long, value_delimiter = ',', default_value = "nanodet,centernet")]
    pub eval_models: Vec<String>,
    #[arg(long, default_value = "person")]
    pub target: String,
    /// Training iterations per method (the same budget for all).
    #[arg(long, default_value_t = 600)]
    pub iterations: usize,
    #[arg(long, default_value_t = 2)]
    pub batch: usize,
    /// Textures evaluated beside the learned ones (see `cac eval --texture`).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "original,natural,naive,random"
    )]
    pub textures: Vec<String>,
    /// Evaluation views per brightness level and set.
    #[arg(long, default_value_t = 50)]
    pub views: usize,
    #[arg(long, value_delimiter = ',', default_value = "fv,rv")]
    pub sets: Vec<String>,
    /// Seed of the training runs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Seed of the evaluation views (and of the simple textures).
    #[arg(long, default_value_t = 31)]
    pub eval_seed: u64,
    #[arg(long, default_value = "study-methods")]
    pub out: PathBuf,
}

/// A trained row: its name in the tables, its folder name and its settings.
struct Row {
    name: String,
    dir: String,
    attack: AttackConfig,
}

fn rows(a: &Args) -> Result<Vec<Row>> {
    let base = AttackConfig {
        models: a.models.clone(),
        target: a.target.clone(),
        proposals: a.proposals,
        batch: a.batch,
        iterations: a.iterations,
        seed: a.seed,
        checkpoint_every: 10,
        ..Default::default()
    };
    let mut out: Vec<Row> = a
        .methods
        .iter()
        .map(|&m| Row {
            name: display(m).into(),
            dir: m.name().into(),
            attack: AttackConfig {
                method: m,
                ..base.clone()
            },
        })
        .collect();
    for h in &a.hide {
        let classes = h.replace('+', ",");
        let tag: String = h
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '+' {
                    c
                } else {
                    '-'
                }
            })
            .collect();
        out.push(Row {
            name: format!("CAC hide ({h})"),
            dir: format!("cac-hide-{tag}"),
            attack: AttackConfig {
                hide: true,
                hide_classes: classes,
                ..base.clone()
            },
        });
    }
    if out.is_empty() {
        bail!("nothing to train: give --methods or --hide");
    }
    for r in &out {
        r.attack.validate().with_context(|| r.name.clone())?;
    }
    Ok(out)
}

fn display(m: Method) -> &'static str {
    match m {
        Method::Cac => "CAC",
        Method::Advpat => "AdvPat",
        Method::Shapeshifter => "ShapeShifter",
        Method::Upc => "UPC",
        Method::Camou => "CAMOU",
    }
}

pub fn run(a: Args) -> Result<()> {
    if a.views == 0 || a.iterations == 0 {
        bail!("--views and --iterations must be positive");
    }
    let cfg = match &a.config {
        Some(p) => SceneConfig::from_file(p)?,
        None => SceneConfig::training(),
    };
    let rows = rows(&a)?;
    let stage = cfg.stage()?;
    let sources = train::load_detectors(&a.models)?;
    let src: Vec<&dyn cac::detect::Detector> = sources.iter().map(|d| d.as_ref()).collect();
    let mut trained = vec![];
    for r in &rows {
        let dir = a.out.join(&r.dir);
        let secs = train_one(&dir, &cfg, r.attack.clone(), &stage, &src, &r.name, None)?;
        trained.push((r.name.clone(), secs, dir));
    }
    // Judged as `cac eval` judges: the protocol's renderer on the training config's object.
    let scene = SceneConfig {
        render: SceneConfig::default().render,
        ..cfg
    };
    let target = cac::detect::labels::class_id(&a.target)
        .with_context(|| format!("unknown target class {:?}", a.target))?;
    let mut specs = a.textures.clone();
    specs.extend(
        trained
            .iter()
            .map(|(n, _, d)| format!("{n}={}", d.display())),
    );
    let job = EvalJob {
        scene,
        textures: specs,
        plan: ViewPlan {
            views_per_level: a.views,
            seed: a.eval_seed,
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
    println!("evaluating {} textures ...", job.textures.len());
    let o = job::run(&job, &refs, &device::inference(), &mut |_, _| {})?;
    let mut table_rows: Vec<(String, Option<f64>)> = o
        .info
        .textures
        .iter()
        .filter(|t| !trained.iter().any(|(n, _, _)| n == *t))
        .map(|t| (t.clone(), None))
        .collect();
    table_rows.extend(trained.iter().map(|(n, s, _)| (n.clone(), Some(*s))));
    let t = study::methods_table(
        &o.records,
        &table_rows,
        &o.info.models,
        &a.models,
        &job.plan.sets,
    );
    let md = format!(
        "# Methods under the protocol\n\n```\n{}\ntraining: {} iterations, batch {}, sources {}, target {:?}, CAC proposals {}, seed {}; train (s) = the logged iteration times\n```\n\n{}",
        cac::eval::report::protocol_text(&o.info),
        a.iterations,
        a.batch,
        a.models.join(", "),
        a.target,
        a.proposals.name(),
        a.seed,
        t.markdown()
    );
    cac::io::write_atomic(&a.out.join("methods.md"), md.as_bytes())?;
    cac::io::write_atomic(&a.out.join("methods.csv"), t.csv().as_bytes())?;
    println!(
        "{md}\nwrote {}/methods.md, methods.csv and eval/",
        a.out.display()
    );
    Ok(())
}
