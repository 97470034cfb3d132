//! `cac print chart` and `cac print calibrate`: a chart to print, and a printer profile fitted
//! from a photograph of it (docs/physical.md, "Calibrating a printer"; the work is
//! `cac::physical::print_calib`).

use super::flags::physical::{CalibrateFlags, ChartFlags};
use anyhow::Result;
use cac::physical::print_calib::{calibrate_files, CalibrateOptions, Chart, ChartSpec};
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// Write a calibration chart to print (DIR/chart.png, A4 at 300 dpi) and its description
    /// (DIR/chart.json).
    Chart(ChartArgs),
    /// Fit a printer profile from a photograph of the printed chart (with a ColorChecker on its
    /// squares); reports ΔE2000 on held-out patches.
    Calibrate(CalibrateArgs),
}

#[derive(clap::Args, Debug)]
pub struct ChartArgs {
    #[command(flatten)]
    pub spec: ChartFlags,
    /// Folder for chart.png and chart.json.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(clap::Args, Debug)]
pub struct CalibrateArgs {
    /// The chart's description (DIR/chart.json written by `cac print chart`).
    #[arg(long)]
    pub chart: PathBuf,
    /// The photograph of the printed chart (PNG or JPEG).
    #[arg(long)]
    pub photo: PathBuf,
    /// The printer profile to write (TOML).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub opts: CalibrateFlags,
}

pub fn run(cmd: Cmd) -> Result<()> {
    match cmd {
        Cmd::Chart(a) => {
            let chart = Chart::new(&ChartSpec::from(a.spec))?;
            chart.write(&a.out)?;
            println!(
                "wrote {} and {} ({} chart, {} squares)",
                a.out.join("chart.png").display(),
                a.out.join("chart.json").display(),
                chart.printer,
                chart.patches.len()
            );
        }
        Cmd::Calibrate(a) => {
            let cal = calibrate_files(&a.chart, &a.photo, &CalibrateOptions::from(a.opts))?;
            print!("{}", cal.summary());
            cal.write(&a.out)?;
            println!("wrote {}", a.out.display());
        }
    }
    Ok(())
}
