//! `cac bench detect` (Faster R-CNN part): forward and forward+backward (class logits summed over
//! the fixed proposals, to the image) ms of the three torchvision models on burn at their
//! default sizes, with PyTorch side by side when `torch` is importable (same thread count; on
//! CUDA when `CAC_DEVICE=gpu`; tools/torchvision_oracle.py `--bench`, run as a subprocess).
//! Fastest of `--runs` runs after a warm-up, on both sides. Synthetic weights: timings do not
//! depend on the values beyond the proposal and detection counts.

use super::timer::time;
use crate::cli::device;
use anyhow::{Context, Result};
use burn::tensor::{Distribution, Tensor};
use cac::detect::frcnn::{synthetic, Arch, FasterRcnn, MODELS};
use cac::detect::Detector;
use cac::report::Table;
use std::path::Path;
use std::process::Command;

/// PyTorch's (forward, forward+backward) ms on `device` (cpu or cuda), or None when torch cannot
/// run there.
fn torch_ms(
    python: &str,
    model: &str,
    (threads, device): (usize, &str),
    runs: usize,
    (h, w): (usize, usize),
) -> Option<(f64, f64)> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/torchvision_oracle.py");
    let out = Command::new(python)
        .arg(script)
        .args(["--bench", model, "--threads", &threads.to_string()])
        .args(["--iters", &runs.to_string(), "--size", &format!("{h}x{w}")])
        .args(["--device", device])
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().find(|l| l.contains("\"forward_ms\""))?;
    let v: serde_json::Value = serde_json::from_str(line).ok()?;
    Some((v["forward_ms"].as_f64()?, v["backward_ms"].as_f64()?))
}

/// The input size of `name` (synthetic weights), and milliseconds of a forward pass on the
/// `inference` device and of forward and backward (to the input) on `training`.
fn forward_backward_ms(
    name: &str,
    runs: usize,
    inference: &burn::tensor::Device,
    training: &burn::tensor::Device,
) -> Result<((usize, usize), f64, f64)> {
    let arch = Arch::from_name(name)?;
    let m = FasterRcnn::from_state_dict(
        arch,
        &synthetic::state_dict(arch, inference),
        arch.config(),
        inference,
    )?;
    let (w, h) = m.input_size();
    let x = Tensor::<4>::random([1, 3, h, w], Distribution::Uniform(0.0, 1.0), inference);
    let fwd = time(runs, || m.run(x.clone()).map(|_| ()))?;
    let xa = Tensor::<4>::random([1, 3, h, w], Distribution::Uniform(0.0, 1.0), training);
    let ma = FasterRcnn::from_state_dict(
        arch,
        &synthetic::state_dict(arch, training),
        arch.config(),
        training,
    )?;
    let bwd = time(runs, || {
        let x = xa.clone().require_grad();
        let (f, g, _) = ma.features(x.clone())?;
        let props = ma.rpn_proposals(&f, g)?;
        let (logits, _) = ma.box_outputs(&f, g, &props).context("no proposal")?;
        let grads = logits.sum().backward();
        let grad = x.grad(&grads).context("no gradient")?;
        let _ = grad.sum().into_scalar::<f32>();
        Ok(())
    })?;
    Ok(((w, h), fwd, bwd))
}

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
        let ((w, h), fwd, bwd) = forward_backward_ms(name, runs, &inference, &training)?;
        let torch = torch_ms(python, name, (threads, torch_device), runs, (h, w));
        let f = |v: Option<f64>, p: usize| v.map(|v| format!("{v:.p$}")).unwrap_or("n/a".into());
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
