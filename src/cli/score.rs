//! `cac score SESSION/`: detect in every captured frame, score against the projected ground
//! truth, P@0.5 ± std per distance ratio and per angle; JSON, CSV, plots, HTML report.

use anyhow::Result;
use cac::detect;
use cac::eval::Protocol;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The capture session folder.
    pub session: PathBuf,
    /// Detectors, comma separated.
    #[arg(long, default_value = "centernet,nanodet")]
    pub models: String,
    /// Output folder (default: SESSION/score).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// True classes (class names, comma-separated, each one of every model's classes).
    #[arg(long, default_value = "car,truck")]
    pub true_classes: String,
    /// Input defences in front of every detector, each a column group beside the detector as
    /// it is: NAME[:PARAM] of jpeg, blur, median, bits, resize-pad, tv, lgs (`+` chains several;
    /// docs/eval.md "Defences"), comma-separated.
    #[arg(long = "defence", value_delimiter = ',')]
    pub defences: Vec<String>,
}

pub fn run(a: Args) -> Result<()> {
    let device = super::device::inference();
    let names: Vec<&str> = a.models.split(',').map(str::trim).collect();
    let chains = detect::defence::parse_chains(&a.defences)?;
    let models = detect::defence::defend(detect::load_all(&names, None, &device)?, &chains);
    let refs: Vec<&dyn detect::Detector> = models.iter().map(|m| m.as_ref()).collect();
    let protocol = Protocol::from_labels(&a.true_classes, None)?;
    let s = cac::physical::score::score(&a.session, &refs, &protocol, &device, true)?;
    let out = a.out.unwrap_or_else(|| a.session.join("score"));
    cac::physical::score::write(&out, &s, &a.session.display().to_string())?;
    for r in &s.by_ratio {
        println!(
            "{:10} ratio {:5}: P@0.5 {:.3} ± {:.3} ({} repeats)",
            r.model,
            r.ratio,
            r.mean,
            r.std,
            r.per_repeat.len()
        );
    }
    println!(
        "wrote {}/report.html, scores.json, by_ratio.csv, by_angle.csv, frames.csv",
        out.display()
    );
    Ok(())
}
