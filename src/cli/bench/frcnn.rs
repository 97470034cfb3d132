//! `cac bench detect` (Faster R-CNN part): forward and forward+backward (class logits summed over
//! the fixed proposals, to the image) ms of the three torchvision models on burn at their
//! default sizes, with PyTorch side by side when `torch` is importable (same thread count; on
//! CUDA when `CAC_DEVICE=gpu`; tools/torchvision_oracle.py `--bench`, run as a subprocess).
//! Fastest of `--runs` runs after a warm-up, on both sides. Synthetic weights: timings do not
//! depend on the values beyond the proposal and detection counts. Measured by
//! `cac::detect::bench`.

use crate::cli::device;
use anyhow::Result;
use cac::detect::bench::{frcnn_forward_backward_ms, torch_ms};
use cac::detect::frcnn::MODELS;
use cac::report::Table;

/// Prints the table and returns it (for the CSV).
pub fn bench(runs: usize, python: &str) -> Result<Table> {
    let inference = device::inference();
    let training = device::training();
    let threads = rayon::current_num_threads();
    // Like against like: on the GPU, PyTorch runs on CUDA on the same card.
    let torch_device = if device::is_gpu() { "cuda" } else { "cpu" };
    println!("PyTorch columns: {torch_device}, {threads} threads");
    let mut rows = Table::new([
        "model",
        "input",
        "threads",
        "forward_ms",
        "forward_backward_ms",
        "torch_forward_ms",
        "torch_forward_backward_ms",
        "forward_over_torch",
        "backward_over_torch",
    ]);
    println!(
        "{:24} {:>9} {:>11} {:>12} {:>12} {:>14} {:>8} {:>8}",
        "model",
        "input",
        "forward_ms",
        "fwd+bwd_ms",
        "torch_fwd_ms",
        "torch_fwd+bwd",
        "fwd/pt",
        "bwd/pt"
    );
    for name in MODELS {
        let ((w, h), fwd, bwd) = frcnn_forward_backward_ms(name, runs, &inference, &training)?;
        let torch = torch_ms(python, name, (threads, torch_device), runs, (h, w));
        let f = cac::detect::bench::na;
        let (tf, tb) = (torch.map(|t| t.0), torch.map(|t| t.1));
        let (rf, rb) = (tf.map(|t| fwd / t), tb.map(|t| bwd / t));
        println!(
            "{:24} {:>9} {:>11.1} {:>12.1} {:>12} {:>14} {:>8} {:>8}",
            name,
            format!("{w}x{h}"),
            fwd,
            bwd,
            f(tf, 1),
            f(tb, 1),
            f(rf, 2),
            f(rb, 2)
        );
        rows.row([
            name.to_string(),
            format!("{w}x{h}"),
            threads.to_string(),
            format!("{fwd:.2}"),
            format!("{bwd:.2}"),
            f(tf, 2),
            f(tb, 2),
            f(rf, 4),
            f(rb, 4),
        ]);
    }
    if rows.rows.iter().flatten().any(|c| c == "n/a") {
        eprintln!(
            "note: PyTorch columns are n/a where `{python} -c 'import torch, torchvision'` fails"
        );
    }
    Ok(rows)
}
