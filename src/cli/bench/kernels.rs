//! `cac bench kernels`: the detectors' activations (sigmoid, SiLU, leaky ReLU) as cac runs them
//! (`cac::detect::activation`, fused kernels) beside burn's composite ops on the same backend and
//! PyTorch on the same feature map and thread count, forward and forward+backward, at 1 and 2
//! threads. Prints the table and writes CSV. A benchmark, not a test: it asserts nothing.
//! Measured by `cac::bench::detect::activation_rows`.

use crate::cli::device;
use anyhow::Result;
use cac::bench::detect as bench;
use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs, Debug)]
pub struct Args {
    /// Timed runs per measurement (after a warm-up); the fastest is reported.
    #[arg(long, default_value_t = 10)]
    pub runs: usize,
    /// Feature map shape N,C,H,W (default: a YOLO layer at 640², as in the compute-core issue).
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 64, 160, 160])]
    pub shape: Vec<usize>,
    /// Thread counts to measure (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2])]
    pub threads: Vec<usize>,
    /// Python with torch for the PyTorch columns.
    #[arg(long, default_value = "python3")]
    pub python: String,
    /// CSV output file.
    #[arg(long, default_value = "bench-kernels.csv")]
    pub csv: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let shape: [usize; 4] = a.shape.clone().try_into().map_err(|s: Vec<usize>| {
        anyhow::anyhow!("--shape needs four sizes N,C,H,W, got {}", s.len())
    })?;
    let devices = (&device::inference(), &device::training());
    let rows = bench::activation_rows(shape, &a.threads, a.runs, &a.python, devices, &mut |t| {
        print!("{}", t.markdown_last())
    })?;
    if rows.rows.iter().flatten().any(|c| c == "n/a") {
        eprintln!(
            "note: the PyTorch columns are n/a where `{} -c 'import torch'` fails",
            a.python
        );
    }
    cac::io::write_atomic(&a.csv, rows.csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}
