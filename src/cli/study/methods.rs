//! `cac study methods`: parses the arguments into a `cac::study::methods::MethodsJob` (CAC and
//! the paper's baselines trained alike and judged by the protocol), runs it, prints its table.

use crate::cli::device;
use anyhow::Result;
use cac::config::SceneConfig;
use cac::study::methods::MethodsJob;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub job: crate::cli::flags::eval::MethodsFlags,
    /// Training scene config (default: `SceneConfig::training()`, the protocol's distribution).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    let mut job = MethodsJob::from(a.job);
    job.scene = SceneConfig::from_file_or(a.config.as_deref(), SceneConfig::training)?;
    let md = job.run(&device::inference())?;
    println!(
        "{md}\nwrote {}/methods.md, methods.csv and eval/",
        job.out.display()
    );
    Ok(())
}
