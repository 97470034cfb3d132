//! `cac bench video`: throughput of offline video scoring. A turntable sequence of the default
//! pickup is rendered by the digital twin, encoded with each codec, then timed: decoding alone
//! (frames/s) and scoring with each detector (frames scored per second, decode included).
//! Prints a table and writes a CSV. A benchmark, not a test: it asserts nothing. Measured by
//! `cac::video::bench`.

use crate::cli::device;
use anyhow::Result;
use cac::detect::{self, Detector};
use cac::video::bench::VideoBench;
use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs, Debug)]
pub struct Args {
    #[command(flatten)]
    pub bench: VideoBench,
    /// Detectors, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = cac::detect::spec::MODEL_SPECS, default_value = "nanodet,centernet")]
    pub models: Vec<String>,
    /// CSV output file.
    #[arg(long, default_value = "bench-video.csv")]
    pub csv: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let tools = crate::cli::score_video::tools();
    tools.check()?;
    let device = device::inference();
    let dets = detect::load_all(&a.models, None, &device)?;
    let named: Vec<(&str, &dyn Detector)> = a
        .models
        .iter()
        .zip(&dets)
        .map(|(m, d)| (m.as_str(), d.as_ref()))
        .collect();
    let t = a.bench.run(&tools, &named, &device)?;
    print!("{}", t.markdown());
    cac::io::write_atomic(&a.csv, t.csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}
