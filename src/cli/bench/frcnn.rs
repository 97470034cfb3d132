//! `cac bench detect` (Faster R-CNN part): forward and forward+backward (class logits summed over
//! the fixed proposals, to the image) ms of the three torchvision models on burn at their
//! default sizes, with PyTorch side by side when `torch` is importable (same thread count; on
//! CUDA when `CAC_DEVICE` names a GPU; tools/torchvision_oracle.py `--bench`, run as a subprocess).
//! Fastest of `--runs` runs after a warm-up, on both sides. Synthetic weights: timings do not
//! depend on the values beyond the proposal and detection counts. Measured by
//! `cac::detect::bench`.

use crate::cli::device;
use anyhow::Result;
use cac::detect::bench::{self, BenchDevice};
use cac::report::Table;

/// Prints the table and returns it (for the CSV).
pub fn bench(runs: usize, python: &str, backends: &[BenchDevice]) -> Result<Table> {
    let threads = rayon::current_num_threads();
    // Like against like: on the GPU, PyTorch runs on CUDA on the same card.
    let torch_device = if device::is_gpu() { "cuda" } else { "cpu" };
    println!("PyTorch columns: {torch_device}, {threads} threads");
    let rows = bench::frcnn_models(runs, python, (threads, torch_device), backends, &mut |t| {
        print!("{}", t.markdown_last())
    })?;
    if rows.rows.iter().flatten().any(|c| c == "n/a") {
        eprintln!(
            "note: PyTorch columns are n/a where `{python} -c 'import torch, torchvision'` fails"
        );
    }
    Ok(rows)
}
