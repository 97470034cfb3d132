//! The methods study: CAC and the paper's baselines in one harness, judged where attacks are
//! judged. Every method trains for the same iterations on the same distribution (one resumable
//! run per method in OUT/<method>/), then the original, the simple textures and every learned
//! texture are evaluated by the protocol (its renderer and distances, views of the evaluation
//! seed; the full report in OUT/eval/), and the table goes to OUT/methods.{md,csv}. CAC uses the
//! job's proposal rule; each baseline keeps its own paper's choice of what it attacks. Each
//! entry of `hide` adds a CAC row in hide mode.

use super::figures;
use super::{protocol_job, train_run};
use crate::job;
use crate::report;
use anyhow::{bail, Context, Result};
use burn::tensor::Device;
use cac_attack::baselines::Method;
use cac_attack::AttackConfig;
use cac_core::choice::Choice;
use cac_detect as detect;
use cac_render::config::SceneConfig;
use cac_render::environment::ViewpointSet;
use std::path::PathBuf;

/// The study's settings: `cac study methods`'s flags (the scene comes from `--config`).
#[derive(Debug, Clone)]
pub struct MethodsJob {
    /// The training scene (judged with the protocol's renderer on its object).
    pub scene: SceneConfig,
    /// Attacks, comma-separated (cac, advpat, shapeshifter, upc, camou).
    pub methods: Vec<Method>,
    /// Also train CAC in hide mode suppressing these classes: `all`, or COCO labels joined by
    /// `+` (e.g. car+bus+truck). Repeat for several rows.
    pub hide: Vec<String>,
    /// What the attacks train against and for.
    pub source: super::Source,
    /// Detectors the textures are judged by (those not among --models measure transfer).
    pub eval_models: Vec<String>,
    /// Training iterations per method (the same budget for all).
    pub iterations: usize,
    /// Textures evaluated beside the learned ones (see `cac eval --texture`).
    pub textures: Vec<String>,
    /// Evaluation views per brightness level and set.
    pub views: usize,
    /// Evaluation viewpoint sets (fv, rv); a repeated set counts once.
    pub sets: Vec<ViewpointSet>,
    /// Seed of the training runs.
    pub seed: u64,
    /// Seed of the evaluation views (and of the simple textures).
    pub eval_seed: u64,
    /// Output folder: one run per method, eval/, methods.md and methods.csv.
    pub out: PathBuf,
}

impl Default for MethodsJob {
    /// Every method, 600 iterations each from seed 0 on the training scene, beside the original and
    /// the three simple textures, judged by NanoDet and CenterNet on 50 views per level in FV and
    /// RV (view seed 31), into `study-methods`.
    fn default() -> Self {
        MethodsJob {
            scene: SceneConfig::training(),
            methods: Method::ALL.to_vec(),
            hide: vec![],
            source: Default::default(),
            eval_models: ["nanodet", "centernet"].map(String::from).to_vec(),
            iterations: 600,
            textures: ["original", "natural", "naive", "random"]
                .map(String::from)
                .to_vec(),
            views: 50,
            sets: vec![ViewpointSet::Free, ViewpointSet::Restricted],
            seed: 0,
            eval_seed: 31,
            out: PathBuf::from("study-methods"),
        }
    }
}

/// A trained row: its name in the tables, its folder name and its settings.
struct Row {
    name: String,
    dir: String,
    attack: AttackConfig,
}

/// The name of a method in the tables.
fn display(m: Method) -> &'static str {
    match m {
        Method::Cac => "CAC",
        Method::Advpat => "AdvPat",
        Method::Shapeshifter => "ShapeShifter",
        Method::Upc => "UPC",
        Method::Camou => "CAMOU",
    }
}

impl MethodsJob {
    /// The rows to train, each checked.
    fn rows(&self) -> Result<Vec<Row>> {
        let base = self.source.attack(self.iterations, self.seed);
        let mut out: Vec<Row> = self
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
        for h in &self.hide {
            let keep = |c: char| c.is_ascii_alphanumeric() || c == '+';
            let tag: String = h.chars().map(|c| if keep(c) { c } else { '-' }).collect();
            out.push(Row {
                name: format!("CAC hide ({h})"),
                dir: format!("cac-hide-{tag}"),
                attack: AttackConfig {
                    hide: true,
                    hide_classes: h.replace('+', ","),
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

    /// Trains every row (resuming), evaluates, writes methods.md and methods.csv; returns the
    /// Markdown page.
    pub fn run(&self, device: &Device) -> Result<String> {
        if self.views == 0 || self.iterations == 0 {
            bail!("--views and --iterations must be positive");
        }
        let rows = self.rows()?;
        let stage = self.scene.stage()?;
        let sources = detect::load_all(&self.source.models, None, device)?;
        let src = detect::refs(&sources);
        // Every row's classes against every source before anything is trained.
        for r in &rows {
            for d in &src {
                r.attack.goal_for(*d).with_context(|| r.name.clone())?;
            }
        }
        let mut trained = vec![];
        for r in &rows {
            let dir = self.out.join(&r.dir);
            let ac = r.attack.clone();
            let secs = train_run(&dir, &self.scene, ac, &stage, &src, device, &r.name, None)?;
            trained.push((r.name.clone(), secs, dir));
        }
        // Judged as `cac eval` judges: the protocol's renderer on the training config's object.
        let scene = SceneConfig {
            render: SceneConfig::default().render,
            ..self.scene.clone()
        };
        let mut specs = self.textures.clone();
        specs.extend(
            trained
                .iter()
                .map(|(n, _, d)| format!("{n}={}", d.display())),
        );
        let plan = (
            self.views,
            self.eval_seed,
            ViewpointSet::distinct(&self.sets),
        );
        let job = protocol_job(scene, specs, plan, &self.source.target, &self.out)?;
        let evals = detect::load_all(&self.eval_models, None, device)?;
        println!("evaluating {} textures ...", job.textures.len());
        let o = job::run(&job, &detect::refs(&evals), device, &mut |_, _| {})?;
        let mut table_rows: Vec<(String, Option<f64>)> = o
            .info
            .textures
            .iter()
            .filter(|t| !trained.iter().any(|(n, _, _)| n == *t))
            .map(|t| (t.clone(), None))
            .collect();
        table_rows.extend(trained.iter().map(|(n, s, _)| (n.clone(), Some(*s))));
        let (models, sets) = (&o.info.models, &job.plan.sets);
        let t = figures::methods_table(&o.records, &table_rows, models, &self.source.models, sets);
        let md = format!(
            "# Methods under the protocol\n\n```\n{}\ntraining: {} iterations, batch {}, sources {}, target {:?}, CAC proposals {}, seed {}; train (s) = the logged iteration times\n```\n\n{}",
            report::protocol_text(&o.info),
            self.iterations,
            self.source.batch,
            self.source.models.join(", "),
            self.source.target,
            self.source.proposals.name(),
            self.seed,
            t.markdown()
        );
        cac_core::io::write_atomic(&self.out.join("methods.md"), md.as_bytes())?;
        cac_core::io::write_atomic(&self.out.join("methods.csv"), t.csv().as_bytes())?;
        Ok(md)
    }
}
