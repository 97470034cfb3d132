//! `cac demo`: the main job on the embedded defaults (`cac::study::demo::DemoJob`: a short
//! attack against NanoDet, scored before and after on protocol views with CenterNet as the
//! transfer model); parses, runs it, prints its table.

use super::device;
use anyhow::Result;
use cac::study::demo::DemoJob;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    /// Seed of the training run.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Attack iterations (batch 2).
    #[arg(long, default_value_t = 400)]
    pub iterations: usize,
    /// Protocol views per brightness level and viewpoint set (4 groups: FV/RV × bright/dark).
    #[arg(long, default_value_t = 16)]
    pub views: usize,
    /// Seed of the protocol views (not the training seed: the texture never saw these views).
    #[arg(long, default_value_t = 2026)]
    pub view_seed: u64,
}

pub fn run(a: Args) -> Result<()> {
    let o = DemoJob {
        out: a.out.clone(),
        seed: a.seed,
        iterations: a.iterations,
        views: a.views,
        view_seed: a.view_seed,
    }
    .run(&device::inference())?;
    print!("{}", o.table);
    println!(
        "\nwrote {} (atlases, before/after view sheets with each detector's boxes, summary.json, \
         run/) in {:.0} s",
        a.out.display(),
        o.seconds
    );
    Ok(())
}
