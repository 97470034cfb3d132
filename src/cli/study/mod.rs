//! `cac study topn`: parses the arguments into a `cac::study::topn::TopnJob` (the denseness
//! study, the paper's Figure 5), runs it, prints its table. Defaults are small so the study
//! finishes on a laptop in minutes; `--iterations 2000 --views 200 --size 512` approaches the
//! paper's. Under the default proposal rule (the candidates on the object, about 30 per image) n
//! caps how many of them are fixed, hence the small values; `--proposals topn --n
//! 50,100,200,300` is the paper's Figure 5 (top-n after NMS over the whole image).

mod methods;

use super::device;
use anyhow::Result;
use cac::config::SceneConfig;
use cac::study::topn::{Part, TopnJob, TopnOutcome};
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// P@0.5 against the number of fixed proposals n.
    Topn(TopnArgs),
    /// CAC and the paper's baselines trained alike and judged by the protocol.
    Methods(methods::Args),
}

#[derive(clap::Args, Debug)]
pub struct TopnArgs {
    #[command(flatten)]
    pub job: crate::cli::flags::eval::TopnFlags,
    /// Scene config (default: the demo's scene, the pickup at street level, 320² renders).
    #[arg(long)]
    pub config: Option<PathBuf>,
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
    let mut job = TopnJob::from(a.job);
    job.scene = SceneConfig::from_file_or(a.config.as_deref(), TopnJob::default_scene)?;
    job.part = match (a.task, a.shard, a.merge) {
        (Some(k), _, _) => Part::Task(k),
        (_, Some(s), _) => Part::Shard(s),
        (_, _, true) => Part::Merge,
        _ => Part::Whole,
    };
    match job.run(&device::inference())? {
        TopnOutcome::Trained => {}
        TopnOutcome::Shard(o) => print!("{o}"),
        TopnOutcome::Written { markdown } => println!(
            "{markdown}\nwrote {}/topn.png, topn.csv, topn.md, topn.html and eval/",
            job.out.display()
        ),
    }
    Ok(())
}
