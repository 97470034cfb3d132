//! `cac bench agreement`: does cac's renderer see what a second renderer sees? Pools the per-view
//! CSV files of `cac bench realism --renderers cac,blender --per-view` (one per run, e.g. one per
//! seed) and prints, per mesh, texture and viewpoint set, each detector's P@0.5 and targeted
//! success in both renderers, the gap and the views that disagree (McNemar); writes the same as
//! CSV. Measured by `cac::eval::agreement`; `cac bench realism` prints the same table for its own
//! run when it has both renderers.

use anyhow::{bail, Context, Result};
use cac::eval::agreement::{Agreement, Views};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Per-view CSV files of `cac bench realism --per-view`, one per run (e.g. per seed): pooled.
    #[arg(long, value_delimiter = ',', required = true)]
    pub per_view: Vec<PathBuf>,
    /// The largest gap between the renderers' rates counted as agreement.
    #[arg(long, default_value_t = 0.05)]
    pub tolerance: f64,
    /// CSV output file.
    #[arg(long, default_value = "bench-agreement.csv")]
    pub csv: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    if !(a.tolerance.is_finite() && a.tolerance >= 0.0) {
        bail!(
            "--tolerance must be a rate difference of 0 or more, got {}",
            a.tolerance
        );
    }
    let mut views = Views::default();
    for p in &a.per_view {
        let text = std::fs::read_to_string(p)
            .with_context(|| format!("{}: cannot read the per-view CSV", p.display()))?;
        views.add_csv(&text, &p.display().to_string())?;
    }
    let ag = views.agreement()?;
    print(&ag, a.tolerance);
    cac::io::write_atomic(&a.csv, ag.table(a.tolerance).csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}

/// Prints the table and the verdict.
pub fn print(ag: &Agreement, tolerance: f64) {
    println!("{}", ag.table(tolerance).markdown());
    println!(
        "{} run(s); {} view(s) rendered by one renderer only (left out); every gap within {tolerance}: {}",
        ag.runs,
        ag.unpaired,
        if ag.all_within(tolerance) { "yes" } else { "no" }
    );
}
