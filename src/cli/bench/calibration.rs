//! `cac bench calibration`: the print chart's patch count against the calibration's held-out
//! and true ΔE2000 and its time, on the digital twin (measured by
//! `cac::bench::calibration`). Prints a table and writes a CSV.

use anyhow::Result;
use cac::bench::calibration::CalibrationBench;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub bench: crate::cli::flags::physical::CalibrationBenchFlags,
    /// CSV output file.
    #[arg(long, default_value = "bench-calibration.csv")]
    pub csv: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let t = CalibrationBench::from(a.bench).run()?;
    print!("{}", t.markdown());
    cac::io::write_atomic(&a.csv, t.csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}
