//! `cac study topn`: the denseness study (the paper's Figure 5). Trains CAC once per number of
//! fixed proposals n (reusing finished runs and resuming unfinished ones in OUT/n<N>/), evaluates
//! every learned texture and the original with the protocol on the evaluation models (a model
//! not among the sources measures transfer), and plots P@0.5 against n (OUT/topn.png, topn.csv,
//! topn.md, topn.html; the full evaluation report in OUT/eval/). Defaults are small so the study finishes
//! on a laptop in minutes; `--iterations 2000 --views 200 --size 512` approaches the paper's.

use super::{demo, device, eval::parse_sets, train};
use anyhow::{bail, Context, Result};
use cac::attack::{AttackConfig, Trainer};
use cac::config::SceneConfig;
use cac::environment::{Environment, ViewpointSet};
use cac::eval::job::{self, EvalJob};
use cac::eval::run::ViewPlan;
use cac::eval::summary::{figures, sel};
use cac::eval::Protocol;
use cac::render::Renderer;
use cac::report::{plot, Html, Plot, Series, Table};
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// P@0.5 against the number of fixed proposals n.
    Topn(TopnArgs),
}

#[derive(clap::Args, Debug)]
pub struct TopnArgs {
    /// Values of n, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "50,100,200,300")]
    pub n: Vec<usize>,
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
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long, default_value = "study-topn")]
    pub out: PathBuf,
}

pub fn run(c: Cmd) -> Result<()> {
    match c {
        Cmd::Topn(a) => topn(a),
    }
}

fn topn(a: TopnArgs) -> Result<()> {
    if a.n.is_empty() || a.n.contains(&0) {
        bail!("--n needs positive values");
    }
    let cfg = match &a.config {
        Some(p) => SceneConfig::from_file(p)?,
        None => {
            let mut c = demo::demo_scene();
            c.object.mesh = "pickup".into();
            c
        }
    };
    let scene = cfg.object.load()?;
    let original = scene.initial_atlas(cfg.render.atlas_res);
    let renderer = Renderer::new(scene, cfg.render.clone())?;
    let env = Environment::new(cfg.environment.clone())?;
    let sources = train::load_detectors(&a.models)?;
    let src: Vec<&dyn cac::detect::Detector> = sources.iter().map(|d| d.as_ref()).collect();
    let mut specs = vec!["original".to_string()];
    for &n in &a.n {
        let dir = a.out.join(format!("n{n}"));
        let ac = AttackConfig {
            models: a.models.clone(),
            target: a.target.clone(),
            top_n: n,
            batch: a.batch,
            iterations: a.iterations,
            seed: a.seed,
            checkpoint_every: 10,
            viewpoints: ViewpointSet::Free,
            ..Default::default()
        };
        let mut tr = Trainer::new(
            ac.clone(),
            &renderer,
            &env,
            src.clone(),
            device::training(),
            &original,
        )?;
        if dir.join("run.json").exists() {
            let run: serde_json::Value =
                serde_json::from_slice(&std::fs::read(dir.join("run.json"))?)
                    .with_context(|| format!("{}: malformed run.json", dir.display()))?;
            let old: AttackConfig = serde_json::from_value(run["attack"].clone())
                .with_context(|| format!("{}: run.json attack settings", dir.display()))?;
            let same = |c: &AttackConfig| AttackConfig {
                iterations: 0,
                ..c.clone()
            };
            if same(&old) != same(&ac) {
                bail!(
                    "{} holds a run with other settings (n = {}, models {:?}); use another --out",
                    dir.display(),
                    old.top_n,
                    old.models
                );
            }
            tr = tr.resume(&dir)?;
        }
        let it = tr.state.iteration;
        if it >= a.iterations {
            println!("n = {n}: reusing the finished run in {}", dir.display());
        } else {
            println!(
                "n = {n}: training iterations {it}..{} in {}",
                a.iterations,
                dir.display()
            );
        }
        train::train_loop(&mut tr, &dir, &cfg, true)?;
        specs.push(format!("n{n}={}", dir.display()));
    }

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
    let o = job::run(&job, &refs, &device::inference(), &mut |_, _| {})?;
    let recs: Vec<cac::eval::run::ImageRecord> = serde_json::from_value(
        serde_json::from_slice::<serde_json::Value>(&std::fs::read(job.out.join("results.json"))?)?
            ["records"]
            .clone(),
    )?;

    let mut t = Table::new(
        ["n".to_string()]
            .into_iter()
            .chain(o.info.models.iter().flat_map(|m| {
                let role = if a.models.contains(m) {
                    "white-box"
                } else {
                    "transfer"
                };
                [
                    format!("{m} ({role}) P@0.5"),
                    format!("{m} s.e."),
                    format!("{m} drop"),
                ]
            })),
    );
    let mut series = vec![];
    for m in &o.info.models {
        let orig = figures(&recs, sel("Original", m, None, None));
        let pts: Vec<(usize, cac::eval::summary::Figures)> =
            a.n.iter()
                .map(|&n| (n, figures(&recs, sel(&format!("n{n}"), m, None, None))))
                .collect();
        let role = if a.models.contains(m) {
            "white-box"
        } else {
            "transfer"
        };
        series.push(
            Series::new(
                &format!("{m} ({role})"),
                pts.iter().map(|(n, f)| (*n as f64, f.p_at_05)).collect(),
            )
            .err(pts.iter().map(|(_, f)| f.p_stderr).collect()),
        );
        let (lo, hi) = (
            *a.n.iter().min().unwrap() as f64,
            *a.n.iter().max().unwrap() as f64,
        );
        series.push(
            Series::new(
                &format!("{m}: original texture"),
                vec![(lo, orig.p_at_05), (hi, orig.p_at_05)],
            )
            .line(1),
        );
    }
    for &n in &a.n {
        let mut row = vec![n.to_string()];
        for m in &o.info.models {
            let f = figures(&recs, sel(&format!("n{n}"), m, None, None));
            let orig = figures(&recs, sel("Original", m, None, None));
            row.extend([
                format!("{:.3}", f.p_at_05),
                format!("{:.3}", f.p_stderr),
                format!("{:.3}", orig.p_at_05 - f.p_at_05),
            ]);
        }
        t.row(row);
    }
    // Series colours: a model's texture curve and its original line share a colour.
    for (k, s) in series.iter_mut().enumerate() {
        s.color = Some(plot::PALETTE[(k / 2) % plot::PALETTE.len()]);
    }
    let img = plot::xy(
        &Plot::new(
            "P@0.5 against the number of fixed proposals n",
            "n (fixed proposals per image)",
            "P@0.5",
        )
        .y_range(-0.02, 1.02),
        &series,
    )?;
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
