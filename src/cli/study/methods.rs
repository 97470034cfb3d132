//! `cac study methods`: parses the arguments into a `cac::study::methods::MethodsJob` (CAC and
//! the paper's baselines trained alike and judged by the protocol), runs it, prints its table.

use crate::cli::device;
use anyhow::Result;
use cac::attack::Method;
use cac::config::SceneConfig;
use cac::environment::ViewpointSet;
use cac::study::methods::MethodsJob;
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
    #[command(flatten)]
    pub source: cac::study::Source,
    /// Training scene config (default: `SceneConfig::training()`, the protocol's distribution).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Detectors the textures are judged by (those not among --models measure transfer).
    #[arg(long, value_delimiter = ',', value_parser = cac::detect::spec::MODEL_SPECS, default_value = "nanodet,centernet")]
    pub eval_models: Vec<String>,
    /// Training iterations per method (the same budget for all).
    #[arg(long, default_value_t = 600)]
    pub iterations: usize,
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
    #[arg(long, value_enum, value_delimiter = ',', default_value = "fv,rv")]
    pub sets: Vec<ViewpointSet>,
    /// Seed of the training runs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Seed of the evaluation views (and of the simple textures).
    #[arg(long, default_value_t = 31)]
    pub eval_seed: u64,
    #[arg(long, default_value = "study-methods")]
    pub out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let job = MethodsJob {
        scene: SceneConfig::from_file_or(a.config.as_deref(), SceneConfig::training)?,
        methods: a.methods,
        hide: a.hide,
        source: a.source,
        eval_models: a.eval_models,
        iterations: a.iterations,
        textures: a.textures,
        views: a.views,
        sets: ViewpointSet::distinct(&a.sets),
        seed: a.seed,
        eval_seed: a.eval_seed,
        out: a.out.clone(),
    };
    let md = job.run(&device::inference())?;
    println!(
        "{md}\nwrote {}/methods.md, methods.csv and eval/",
        a.out.display()
    );
    Ok(())
}
