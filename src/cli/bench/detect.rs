//! `cac bench detect`: forward and forward+backward time of both detectors at native
//! resolution, batch 1 and 4, and the TFJS reference runner's wasm backend timed in the same
//! run; then the Faster R-CNN models against PyTorch ([`super::frcnn`]). Prints tables and writes
//! CSVs. A benchmark, not a test: it asserts nothing. Measured by `cac::detect::bench`.

use crate::cli::device;
use anyhow::Result;
use burn::tensor::{Distribution, Tensor};
use cac::detect::{
    self,
    bench::{forward_backward_ms, reference_image, tfjs_wasm},
};
use cac::report::Table;
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct DetectBench {
    /// Timed runs per measurement (after one warm-up run).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// CSV output file.
    #[arg(long, default_value = "bench-detect.csv")]
    pub csv: PathBuf,
    /// Installed TFJS reference runner folder (default: $CAC_TFJS_RUNNER, else target/tfjsref).
    #[arg(long)]
    pub runner: Option<PathBuf>,
    /// Image for the TFJS runner (default: a reference image from ../shared, else a noise PNG).
    #[arg(long)]
    pub image: Option<PathBuf>,
    /// Only the Faster R-CNN models (skip CenterNet and NanoDet).
    #[arg(long)]
    pub frcnn_only: bool,
    /// Skip the Faster R-CNN models.
    #[arg(long)]
    pub no_frcnn: bool,
    /// Python with torch + torchvision for the PyTorch columns of the Faster R-CNN table.
    #[arg(long, default_value = "python3")]
    pub python: String,
    /// CSV output file of the Faster R-CNN table.
    #[arg(long, default_value = "bench-detect-frcnn.csv")]
    pub frcnn_csv: PathBuf,
}

pub fn run(a: DetectBench) -> Result<()> {
    if !a.frcnn_only {
        bench_tfjs(&a)?;
    }
    if !a.no_frcnn {
        let t = super::frcnn::bench(a.runs, &a.python)?;
        cac::io::write_atomic(&a.frcnn_csv, t.csv().as_bytes())?;
        println!("wrote {}", a.frcnn_csv.display());
    }
    Ok(())
}

fn bench_tfjs(a: &DetectBench) -> Result<()> {
    let models = detect::fetch::ensure_models()?;
    let inference = device::inference();
    let training = device::training();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let runner = a
        .runner
        .clone()
        .or_else(|| std::env::var_os("CAC_TFJS_RUNNER").map(PathBuf::from))
        .unwrap_or_else(|| root.join("target/tfjsref"));
    let tmp = tempfile::tempdir()?;
    let image = match &a.image {
        Some(i) => i.clone(),
        None => reference_image(root, tmp.path())?,
    };
    let have_runner = runner.join("detect.mjs").exists();
    if !have_runner {
        eprintln!(
            "note: no TFJS reference runner at {} (set --runner or CAC_TFJS_RUNNER): tfjs column is n/a",
            runner.display()
        );
    }
    let mut rows = Table::new([
        "model",
        "batch",
        "forward_ms",
        "forward_backward_ms",
        "tfjs_wasm_ms",
        "forward_over_tfjs",
    ]);
    println!(
        "{:10} {:>5} {:>12} {:>16} {:>16} {:>14}",
        "model", "batch", "forward_ms", "fwd+bwd_ms", "tfjs_wasm_ms", "fwd/tfjs"
    );
    // The TFJS detectors (their own files, not the parity variants).
    let tfjs = detect::MODELS
        .iter()
        .filter(|m| m.weights == detect::Weights::Folder && m.variant_of.is_none());
    for name in tfjs.map(|m| m.name) {
        let det = detect::load(name, &models, &inference)?;
        let (w, h) = det.input_size();
        let tfjs = if have_runner {
            tfjs_wasm(&runner, name, &image, &models, a.runs.max(3))
        } else {
            None
        };
        for batch in [1usize, 4] {
            let x = Tensor::<4>::random(
                [batch, 3, h, w],
                Distribution::Uniform(0.0, 1.0),
                &inference,
            );
            let (fwd, bwd) = forward_backward_ms(det.as_ref(), a.runs, x, &training)?;
            let t = if batch == 1 { tfjs } else { None };
            let ratio = t.map(|t| fwd / t);
            let f =
                |v: Option<f64>, p: usize| v.map(|v| format!("{v:.p$}")).unwrap_or("n/a".into());
            println!(
                "{:10} {:>5} {:>12.1} {:>16.1} {:>16} {:>14}",
                name,
                batch,
                fwd,
                bwd,
                f(t, 1),
                f(ratio, 3)
            );
            rows.row([
                name.to_string(),
                batch.to_string(),
                format!("{fwd:.2}"),
                format!("{bwd:.2}"),
                f(t, 2),
                f(ratio, 4),
            ]);
        }
    }
    cac::io::write_atomic(&a.csv, rows.csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}
