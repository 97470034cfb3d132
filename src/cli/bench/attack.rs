//! `cac bench attack`: the iteration time split and the white-box error against training time
//! (`cac::bench::attack`); prints the tables as they are measured and writes CSVs. A
//! benchmark, not a test: it asserts nothing.

use crate::cli::{device, train};
use anyhow::Result;
use cac::bench::attack::{error_against_time, time_split, Setting};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Timed iterations per batch size (after one warm-up iteration).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Iterations of each error-against-time run.
    #[arg(long, default_value_t = 120)]
    pub iterations: usize,
    /// Evaluate every this many iterations.
    #[arg(long, default_value_t = 40)]
    pub eval_every: usize,
    /// Street-level views per brightness level.
    #[arg(long, default_value_t = 12)]
    pub views: usize,
    /// Error-against-time settings, comma-separated BATCHxNxTEXTURE_RES.
    #[arg(
        long,
        default_value = "1x300x256,2x300x256,2x50x256,2x300x128,2x300x512"
    )]
    pub settings: String,
    /// Also time each batch size trained through this printer profile, beside the plain run
    /// (`cac train --printer`).
    #[arg(long)]
    pub printer: Option<PathBuf>,
    /// Skip the error-against-time part.
    #[arg(long)]
    pub split_only: bool,
    /// CSV prefix: writes PREFIX-split.csv and PREFIX-error.csv.
    #[arg(long, default_value = "bench-attack")]
    pub csv: PathBuf,
}

/// `PREFIX-<what>.csv` beside the `--csv` prefix.
fn csv_path(a: &Args, what: &str) -> PathBuf {
    let prefix = a
        .csv
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("bench-attack");
    a.csv.with_file_name(format!("{prefix}-{what}.csv"))
}

pub fn run(a: Args) -> Result<()> {
    if a.runs == 0 || a.eval_every == 0 || a.views == 0 {
        anyhow::bail!("--runs, --eval-every and --views must be positive");
    }
    let settings = parse_settings(&a.settings)?;
    let dets = train::load_detectors(&["nanodet".into()])?;
    let det = [dets[0].as_ref()];
    let dev = device::inference();
    let (split, scene) = time_split(a.runs, &det, &dev, a.printer.as_deref())?;
    let p = csv_path(&a, "split");
    cac::io::write_atomic(&p, split.csv().as_bytes())?;
    println!("wrote {}", p.display());
    if a.split_only {
        return Ok(());
    }
    let part = (a.iterations, a.eval_every, a.views);
    let rows = error_against_time(part, &det, &scene, &settings, &dev)?;
    let p = csv_path(&a, "error");
    cac::io::write_atomic(&p, rows.csv().as_bytes())?;
    println!("wrote {}", p.display());
    Ok(())
}

/// `BATCHxNxRES,...` → `(batch, n, res)` triples.
fn parse_settings(s: &str) -> Result<Vec<Setting>> {
    s.split(',')
        .map(|t| {
            let v: Vec<usize> = t
                .trim()
                .split('x')
                .map(|x| x.parse::<usize>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| anyhow::anyhow!("--settings: {t:?} is not BATCHxNxTEXTURE_RES"))?;
            match v[..] {
                [b, n, r] if b > 0 && n > 0 && (2..=8192).contains(&r) => Ok((b, n, r)),
                _ => anyhow::bail!(
                    "--settings: {t:?} is not BATCHxNxTEXTURE_RES with positive values"
                ),
            }
        })
        .collect()
}
