//! `cac bench detect` (Faster R-CNN part): forward and forward+backward (class logits summed over
//! the fixed proposals, to the image) ms of the three torchvision models on burn at their
//! default sizes, with PyTorch side by side when `torch` is importable (same thread count; on
//! CUDA beside a GPU backend, on the CPU beside a CPU one: the `torch_device` column;
//! tools/torchvision_oracle.py `--bench`, run as a subprocess).
//! Fastest of `--runs` runs after a warm-up, on both sides. Synthetic weights: timings do not
//! depend on the values beyond the proposal and detection counts. Measured by
//! `cac::bench::detect`.

use anyhow::Result;
use cac::bench::detect::{self as bench, BenchDevice};
use cac::report::Table;

/// Prints the table and returns it (for the CSV).
pub fn bench(runs: usize, python: &str, backends: &[BenchDevice]) -> Result<Table> {
    let threads = rayon::current_num_threads();
    println!("PyTorch columns: {threads} threads, on CUDA beside a GPU backend, else on the CPU");
    let rows = bench::frcnn_models(runs, python, threads, backends, &mut |t| {
        print!("{}", t.markdown_last())
    })?;
    if rows.rows.iter().flatten().any(|c| c == "n/a") {
        eprintln!(
            "note: PyTorch columns are n/a where `{python} -c 'import torch, torchvision'` fails, or, beside a GPU backend, where that torch has no CUDA"
        );
    }
    Ok(rows)
}
