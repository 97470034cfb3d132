//! The detector benchmark's measurements (`cac bench detect`): forward and forward+backward
//! milliseconds of a detector on a batch ([`forward_backward_ms`]) and of a torchvision Faster
//! R-CNN with synthetic weights ([`frcnn_forward_backward_ms`]), fastest of some runs after a
//! warm-up (the one timer, `report::timer`); and the references run as subprocesses: the TFJS
//! runner's wasm backend ([`tfjs_wasm`]), PyTorch ([`torch_ms`],
//! `tools/torchvision_oracle.py --bench`) and onnxruntime for users' ONNX detectors
//! ([`onnx_models`], `tools/onnx/ort_run.py --bench`).

use anyhow::{Context, Result};
use burn::tensor::{Device, Distribution, Tensor};
use cac_core::report::timer::time;
use cac_core::report::Table;
use cac_detect::frcnn::{synthetic, Arch, FasterRcnn};
use cac_detect::Detector;
use cac_detect::{Weights, MODELS};
use std::path::{Path, PathBuf};
use std::process::Command;

/// One backend to time, as the edge (the command line) named and made its devices: the library
/// names no backend, it only labels the rows.
pub struct BenchDevice {
    /// The name in the tables' `backend` column.
    pub name: String,
    /// Its inference device.
    pub inference: Device,
    /// The autodiff device on top of it.
    pub training: Device,
}

/// Every backend (with its loaded detector) at every batch size, batch-major, so a table shows
/// the backends side by side.
fn backends_by_batch<'a, D>(
    backends: &'a [BenchDevice],
    dets: &'a [D],
    batches: &'a [usize],
) -> impl Iterator<Item = ((&'a BenchDevice, &'a D), usize)> + 'a {
    batches
        .iter()
        .flat_map(move |&n| backends.iter().zip(dets).map(move |p| (p, n)))
}

/// Fastest ms of the TFJS wasm runner, from its `--time` report; None when it cannot run.
pub(crate) fn tfjs_wasm(
    runner: &Path,
    model: &str,
    image: &Path,
    models: &Path,
    runs: usize,
) -> Option<f64> {
    let out = Command::new("node")
        .arg(runner.join("detect.mjs"))
        .args([model, &image.display().to_string(), "--backend", "wasm"])
        .args(["--time", &runs.to_string()])
        .arg("--models")
        .arg(models)
        .output()
        .ok()?;
    let err = String::from_utf8_lossy(&out.stderr);
    let line = err.lines().find(|l| l.contains("\"min_ms\""))?;
    let v: serde_json::Value = serde_json::from_str(line.trim()).ok()?;
    v["min_ms"].as_f64()
}

/// The astronaut from ../shared, or a synthetic 512² image written into `tmp`.
pub(crate) fn reference_image(root: &Path, tmp: &Path) -> Result<PathBuf> {
    let shared = root.join("../shared/reference/images/astronaut.png");
    if shared.exists() {
        return Ok(shared);
    }
    let p = tmp.join("noise.png");
    let img = image::RgbImage::from_fn(512, 512, |x, y| {
        image::Rgb([(x * 7 + y) as u8, (y * 13) as u8, (x ^ y) as u8])
    });
    cac_core::io::save_png_atomic(&p, &img)?;
    Ok(p)
}

/// Milliseconds of a forward pass on `x` and of a forward and backward pass on a random batch
/// of its shape on the `training` device.
pub(crate) fn forward_backward_ms(
    det: &dyn Detector,
    runs: usize,
    x: Tensor<4>,
    training: &Device,
) -> Result<(f64, f64)> {
    let fwd = time(runs, || {
        let c = det.candidates(x.clone())?;
        let _ = c.scores.sum().into_scalar::<f32>();
        Ok(())
    })?;
    let xa = Tensor::<4>::random(x.dims(), Distribution::Uniform(0.0, 1.0), training);
    let bwd = time(runs, || {
        let x = xa.clone().require_grad();
        let c = det.candidates(x.clone())?;
        let loss = c.logits.max_dim(2).sum();
        let g = loss.backward();
        let grad = x.grad(&g).context("no gradient")?;
        let _ = grad.sum().into_scalar::<f32>();
        Ok(())
    })?;
    Ok((fwd, bwd))
}

/// PyTorch's (forward, forward+backward) ms on `device` (cpu or cuda), or None when torch cannot
/// run there.
pub(crate) fn torch_ms(
    python: &str,
    model: &str,
    (threads, device): (usize, &str),
    runs: usize,
    (h, w): (usize, usize),
) -> Option<(f64, f64)> {
    let script = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("tools/torchvision_oracle.py");
    let out = cac_detect::torch_env::peer_command(python)
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
pub(crate) fn frcnn_forward_backward_ms(
    name: &str,
    runs: usize,
    inference: &Device,
    training: &Device,
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

/// One TFJS detector at one batch size: forward and forward+backward ms, and the TFJS wasm
/// runner's forward ms (batch 1, when the runner is installed).
pub struct TfjsRow {
    pub name: &'static str,
    pub batch: usize,
    pub forward_ms: f64,
    pub backward_ms: f64,
    pub tfjs_ms: Option<f64>,
}

impl TfjsRow {
    /// Forward time over the TFJS runner's.
    pub fn ratio(&self) -> Option<f64> {
        self.tfjs_ms.map(|t| self.forward_ms / t)
    }
}

/// Times each TFJS detector of the catalogue (their own files, not the parity variants) at
/// batch 1 and 4, fastest of `runs`, beside the TFJS runner at `runner` (default:
/// `target/tfjsref`; the command line also reads `$CAC_TFJS_RUNNER`) on `image` (default: a reference image from
/// `../shared`, else a synthetic one). `on_row` sees the table after each row; returns the
/// CSV table.
pub fn tfjs_models(
    runner: Option<&Path>,
    image: Option<&Path>,
    runs: usize,
    backends: &[BenchDevice],
    on_row: &mut dyn FnMut(&Table),
) -> Result<Table> {
    let models = cac_detect::fetch::ensure_models()?;
    let root = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."));
    let runner = runner
        .map(Path::to_path_buf)
        .unwrap_or_else(|| root.join("target/tfjsref"));
    let tmp = tempfile::tempdir()?;
    let image = match image {
        Some(i) => i.to_path_buf(),
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
        "backend",
        "batch",
        "forward_ms",
        "forward_backward_ms",
        "tfjs_wasm_ms",
        "forward_over_tfjs",
    ]);
    let tfjs = MODELS
        .iter()
        .filter(|m| m.weights == Weights::Folder && m.variant_of.is_none());
    for name in tfjs.map(|m| m.name) {
        let tfjs = if have_runner {
            tfjs_wasm(&runner, name, &image, &models, runs.max(3))
        } else {
            None
        };
        let dets = backends
            .iter()
            .map(|b| cac_detect::load(name, &models, &b.inference))
            .collect::<Result<Vec<_>>>()?;
        for ((b, det), batch) in backends_by_batch(backends, &dets, &[1, 4]) {
            let (w, h) = det.input_size();
            let x = Tensor::<4>::random(
                [batch, 3, h, w],
                Distribution::Uniform(0.0, 1.0),
                &b.inference,
            );
            let (fwd, bwd) = forward_backward_ms(det.as_ref(), runs, x, &b.training)?;
            let row = TfjsRow {
                name,
                batch,
                forward_ms: fwd,
                backward_ms: bwd,
                tfjs_ms: if batch == 1 { tfjs } else { None },
            };
            rows.row([
                name.to_string(),
                b.name.clone(),
                batch.to_string(),
                format!("{fwd:.2}"),
                format!("{bwd:.2}"),
                na(row.tfjs_ms, 2),
                na(row.ratio(), 4),
            ]);
            on_row(&rows);
        }
    }
    Ok(rows)
}

/// One Faster R-CNN model: its input size, and forward and forward+backward ms on burn and in
/// PyTorch (when torch runs).
pub struct FrcnnRow {
    pub name: &'static str,
    pub input: (usize, usize),
    pub forward_ms: f64,
    pub backward_ms: f64,
    pub torch: Option<(f64, f64)>,
}

impl FrcnnRow {
    /// burn's times over PyTorch's: forward, forward+backward.
    pub fn ratios(&self) -> (Option<f64>, Option<f64>) {
        (
            self.torch.map(|t| self.forward_ms / t.0),
            self.torch.map(|t| self.backward_ms / t.1),
        )
    }
}

/// Times the three torchvision Faster R-CNN models (synthetic weights), fastest of `runs`, beside
/// PyTorch run by `python` with `threads` threads: like against like, on the CPU beside a backend
/// that computes on the host's cores and on CUDA beside a GPU backend (one PyTorch run per model
/// and kind); `on_row` sees the table after each row; returns the CSV table.
pub fn frcnn_models(
    runs: usize,
    python: &str,
    threads: usize,
    backends: &[BenchDevice],
    on_row: &mut dyn FnMut(&Table),
) -> Result<Table> {
    let mut rows = Table::new([
        "model",
        "backend",
        "input",
        "threads",
        "torch_device",
        "forward_ms",
        "forward_backward_ms",
        "torch_forward_ms",
        "torch_forward_backward_ms",
        "forward_over_torch",
        "backward_over_torch",
    ]);
    for name in cac_detect::frcnn::MODELS {
        let mut peers: Vec<(&str, Option<(f64, f64)>)> = Vec::new();
        for b in backends {
            let ((w, h), fwd, bwd) =
                frcnn_forward_backward_ms(name, runs, &b.inference, &b.training)?;
            let device = match cac_detect::computes_on_host(&b.inference) {
                true => "cpu",
                false => "cuda",
            };
            let peer = match peers.iter().find(|(d, _)| *d == device) {
                Some(&(_, p)) => p,
                None => {
                    let p = torch_ms(python, name, (threads, device), runs, (h, w));
                    peers.push((device, p));
                    p
                }
            };
            let row = FrcnnRow {
                name,
                input: (w, h),
                forward_ms: fwd,
                backward_ms: bwd,
                torch: peer,
            };
            let (rf, rb) = row.ratios();
            rows.row([
                name.to_string(),
                b.name.clone(),
                format!("{w}x{h}"),
                threads.to_string(),
                device.to_string(),
                format!("{fwd:.2}"),
                format!("{bwd:.2}"),
                na(row.torch.map(|t| t.0), 2),
                na(row.torch.map(|t| t.1), 2),
                na(rf, 4),
                na(rb, 4),
            ]);
            on_row(&rows);
        }
    }
    Ok(rows)
}

/// onnxruntime's fastest forward ms (CPU, `threads` intra-op threads) of `model` on a uniform
/// random input of `shape`, run by `python` (`tools/onnx/ort_run.py --bench`); None when
/// onnxruntime cannot run.
pub(crate) fn ort_ms(
    python: &str,
    model: &Path,
    input: &str,
    shape: [usize; 4],
    threads: usize,
    runs: usize,
) -> Option<f64> {
    let tmp = tempfile::tempdir().ok()?;
    let feed = tmp.path().join("input.json");
    let n: usize = shape.iter().product();
    let data: Vec<f32> = (0..n)
        .map(|i| ((i * 2654435761) % 1000) as f32 / 1000.0)
        .collect();
    let v = serde_json::json!({ input: { "shape": shape, "data": data } });
    std::fs::write(&feed, serde_json::to_vec(&v).ok()?).ok()?;
    let script =
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tools/onnx/ort_run.py");
    let out = cac_detect::torch_env::peer_command(python)
        .arg(script)
        .arg(model)
        .arg(&feed)
        .args([
            "--bench",
            &runs.to_string(),
            "--threads",
            &threads.to_string(),
        ])
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().find(|l| l.contains("\"forward_ms\""))?;
    let v: serde_json::Value = serde_json::from_str(line).ok()?;
    v["forward_ms"]
        .as_array()?
        .iter()
        .filter_map(|x| x.as_f64())
        .reduce(f64::min)
}

/// One ONNX detector: cac's graph forward, its detector forward (with the pre-sigmoid tail) and
/// forward+backward to the image, onnxruntime's forward, and PyTorch's forward and
/// forward+backward (the file converted by onnx2torch; backward of the first output's sum), all
/// at batch 1.
pub struct OnnxRow {
    pub name: String,
    pub input: (usize, usize),
    pub graph_ms: f64,
    pub forward_ms: f64,
    pub backward_ms: f64,
    pub ort_ms: Option<f64>,
    pub torch_ms: Option<(f64, f64)>,
    /// `detect` (pre-processing, graph, decoding, NMS) on cac's executor and, where it was
    /// enabled, with onnxruntime running the graph ([`cac_detect::onnx::runtime`]).
    pub detect_ms: f64,
    pub detect_runtime_ms: Option<f64>,
}

impl OnnxRow {
    /// cac's graph forward and forward+backward over onnxruntime's forward.
    pub fn ratios(&self) -> (Option<f64>, Option<f64>) {
        (
            self.ort_ms.map(|t| self.graph_ms / t),
            self.ort_ms.map(|t| self.backward_ms / t),
        )
    }
}

/// Times each ONNX detector `files` (specs as `onnx:` takes them, without the prefix) at batch
/// 1, fastest of `runs`, beside onnxruntime run by `python` with `threads` threads; `on_row`
/// sees the table after each row; returns the CSV table.
pub fn onnx_models(
    files: &[String],
    runs: usize,
    python: &str,
    threads: usize,
    backends: &[BenchDevice],
    on_row: &mut dyn FnMut(&Table),
) -> Result<Table> {
    let mut rows = Table::new([
        "model",
        "backend",
        "input",
        "threads",
        "graph_forward_ms",
        "detector_forward_ms",
        "forward_backward_ms",
        "ort_forward_ms",
        "forward_over_ort",
        "forward_backward_over_ort",
        "torch_forward_ms",
        "torch_forward_backward_ms",
        "forward_backward_over_torch",
        "detect_ms",
        "detect_onnxruntime_ms",
        "detect_onnxruntime_over_ort",
    ]);
    for f in files {
        let spec = format!("onnx:{f}");
        let (path, config) = cac_detect::onnx::parse_spec(&spec)
            .with_context(|| format!("{f:?}: write MODEL.onnx[:CONFIG.toml]"))?;
        let mut peers = None;
        for b in backends {
            let (inference, training) = (&b.inference, &b.training);
            let det = cac_detect::onnx::OnnxDetector::load(&path, config.as_deref(), inference)?;
            let (w, h) = det.input_size();
            let input = det.graph().graph_inputs()[0].name.clone();
            let output = det.graph().graph_outputs()[0].name.clone();
            let x = Tensor::<4>::random([1, 3, h, w], Distribution::Uniform(0.0, 1.0), inference);
            let graph_ms = time(runs, || {
                let v = det.graph().run_images(&input, x.clone(), &[&output])?;
                let _ = v[0].dev(inference)?.t.sum().into_scalar::<f32>();
                Ok(())
            })?;
            let (fwd, bwd) = forward_backward_ms(&det, runs, x.clone(), training)?;
            use cac_detect::onnx::Engine;
            let detect = |engine| {
                time(runs, || {
                    det.detect_with(x.clone(), engine)?;
                    Ok(())
                })
            };
            let detect_ms = detect(Engine::Executor)?;
            let detect_runtime_ms = match det.engine() {
                Engine::Runtime => Some(detect(Engine::Runtime)?),
                Engine::Executor => None,
            };
            let (ort, torch) = *peers.get_or_insert_with(|| {
                (
                    ort_ms(python, &path, &input, [1, 3, h, w], threads, runs.max(3)),
                    onnx_torch_ms(python, &path, [1, 3, h, w], threads, runs),
                )
            });
            let row = OnnxRow {
                name: det.name().to_string(),
                input: (w, h),
                graph_ms,
                forward_ms: fwd,
                backward_ms: bwd,
                ort_ms: ort,
                torch_ms: torch,
                detect_ms,
                detect_runtime_ms,
            };
            let (rf, rb) = row.ratios();
            rows.row([
                row.name.clone(),
                b.name.clone(),
                format!("{w}x{h}"),
                threads.to_string(),
                format!("{graph_ms:.2}"),
                format!("{fwd:.2}"),
                format!("{bwd:.2}"),
                na(row.ort_ms, 2),
                na(rf, 4),
                na(rb, 4),
                na(row.torch_ms.map(|t| t.0), 2),
                na(row.torch_ms.map(|t| t.1), 2),
                na(row.torch_ms.map(|t| bwd / t.1), 4),
                format!("{detect_ms:.2}"),
                na(detect_runtime_ms, 2),
                na(detect_runtime_ms.zip(ort).map(|(d, o)| d / o), 4),
            ]);
            on_row(&rows);
        }
    }
    Ok(rows)
}

/// PyTorch's (forward, forward+backward) ms of `model` converted by onnx2torch
/// (`tools/torch_bench.py onnx`), run by `python` with `threads` threads; None (with the reason on
/// stderr) when it does not convert or run.
fn onnx_torch_ms(
    python: &str,
    model: &Path,
    shape: [usize; 4],
    threads: usize,
    runs: usize,
) -> Option<(f64, f64)> {
    let script =
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tools/torch_bench.py");
    let dims = shape.map(|d| d.to_string()).join(",");
    let out = cac_detect::torch_env::peer_command(python)
        .arg(script)
        .arg("onnx")
        .arg(model)
        .args(["--shape", &dims, "--threads", &threads.to_string()])
        .args(["--runs", &runs.max(3).to_string()])
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let v: serde_json::Value = serde_json::from_str(text.lines().last()?).ok()?;
    if let Some(e) = v["error"].as_str() {
        eprintln!("PyTorch column n/a for {}: {e}", model.display());
        return None;
    }
    Some((
        v["forward_ms"].as_f64()?,
        v["forward_backward_ms"].as_f64()?,
    ))
}

/// `v` with `p` decimals, or `n/a`.
pub(crate) fn na(v: Option<f64>, p: usize) -> String {
    v.map(|v| format!("{v:.p$}")).unwrap_or("n/a".into())
}

/// The detectors' hot ops as cac runs them (the fused activations of [`super::activation`], the
/// dense convolutions of [`super::conv`]) against burn's own ops on the same backend and against
/// PyTorch (`tools/torch_bench.py ops`, run by `python` with the same thread count), on one
/// seeded feature map of `shape` (convolutions: C to C channels, 3×3 padded and 1×1, seeded
/// weights), at each of `threads`: fastest forward and forward + backward (of `y.sum()` to the
/// input; weights take no gradient, as in an attack) ms of `runs`. `on_row` sees the table after
/// each row; returns the CSV table.
pub fn activation_rows(
    shape: [usize; 4],
    threads: &[usize],
    runs: usize,
    python: &str,
    (inference, training): (&Device, &Device),
    on_row: &mut dyn FnMut(&Table),
) -> Result<Table> {
    let ops = hot_ops(shape[1], inference);
    let mut rows = Table::new([
        "op",
        "shape",
        "threads",
        "cac_forward_ms",
        "cac_forward_backward_ms",
        "burn_forward_ms",
        "burn_forward_backward_ms",
        "torch_forward_ms",
        "torch_forward_backward_ms",
        "forward_over_torch",
        "forward_backward_over_torch",
    ]);
    let dims = shape.map(|d| d.to_string()).join(",");
    for &t in threads {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build()?;
        let torch = torch_activation_ms(python, &dims, t, runs);
        for (name, fused, composite) in &ops {
            let x = Tensor::<4>::random(shape, Distribution::Uniform(-6.0, 6.0), inference);
            let xa = Tensor::<4>::random(shape, Distribution::Uniform(-6.0, 6.0), training);
            let measure = |f: &HotOp| op_forward_backward_ms(f, &x, &xa, runs);
            let ((ff, fb), (cf, cb)) =
                pool.install(|| Ok::<_, anyhow::Error>((measure(fused)?, measure(composite)?)))?;
            let peer = torch.as_ref().and_then(|v| v.get(*name).copied());
            rows.row([
                name.to_string(),
                format!("{shape:?}"),
                t.to_string(),
                format!("{ff:.3}"),
                format!("{fb:.3}"),
                format!("{cf:.3}"),
                format!("{cb:.3}"),
                na(peer.map(|p| p.0), 3),
                na(peer.map(|p| p.1), 3),
                na(peer.map(|p| ff / p.0), 2),
                na(peer.map(|p| fb / p.1), 2),
            ]);
            on_row(&rows);
        }
    }
    Ok(rows)
}

/// One op of [`activation_rows`]: a feature map in, one out.
type HotOp = Box<dyn Fn(Tensor<4>) -> Tensor<4> + Send + Sync>;

/// The hot ops on `c` channels as `(name, cac's op, burn's op)`, with seeded weights on
/// `device` (3×3 convolution, 1×1 convolution, then the bias, drawn in that order).
fn hot_ops(c: usize, device: &Device) -> Vec<(&'static str, HotOp, HotOp)> {
    use burn::tensor::activation;
    use cac_detect::activation as fast;
    let w3 = Tensor::<4>::random([c, c, 3, 3], Distribution::Uniform(-0.5, 0.5), device);
    let w1 = Tensor::<4>::random([c, c, 1, 1], Distribution::Uniform(-0.5, 0.5), device);
    let bias = Tensor::<1>::random([c], Distribution::Uniform(-0.5, 0.5), device);
    vec![
        (
            "sigmoid",
            Box::new(fast::sigmoid),
            Box::new(activation::sigmoid),
        ),
        (
            "silu",
            Box::new(fast::silu),
            Box::new(|x: Tensor<4>| x.clone() * activation::sigmoid(x)),
        ),
        (
            "leaky_relu",
            Box::new(|x| fast::leaky_relu(x, 0.1)),
            Box::new(|x| activation::leaky_relu(x, 0.1)),
        ),
        ("conv3x3", conv_op(&w3, 1, true), conv_op(&w3, 1, false)),
        (
            "bias_add",
            bias_add_op(&bias, c, true),
            bias_add_op(&bias, c, false),
        ),
        ("conv1x1", conv_op(&w1, 0, true), conv_op(&w1, 0, false)),
    ]
}

/// A stride-1 convolution by `w` padded by `pad`: cac's (`ours`) or burn's.
fn conv_op(w: &Tensor<4>, pad: usize, ours: bool) -> HotOp {
    use burn::tensor::ops::ConvOptions;
    let w = w.clone();
    Box::new(move |x: Tensor<4>| {
        let w = w.clone().to_device(&x.device());
        let o = ConvOptions::new([1, 1], [pad, pad], [1, 1], 1);
        match ours {
            true => cac_detect::conv::conv2d(x, w, None, o),
            false => burn::tensor::module::conv2d(x, w, None, o),
        }
    })
}

/// Adding the per-channel `bias` (`c` channels): cac's (`ours`) or burn's broadcast add.
fn bias_add_op(bias: &Tensor<1>, c: usize, ours: bool) -> HotOp {
    let b = bias.clone();
    Box::new(move |x: Tensor<4>| {
        let b = b.clone().to_device(&x.device());
        match ours {
            true => cac_detect::conv::add_bias(x, b),
            false => x + b.reshape([1, c, 1, 1]),
        }
    })
}

/// Fastest forward and forward + backward (of `f(x).sum()` to the input) ms of `runs`, on `x`
/// and on its autodiff twin `xa`.
fn op_forward_backward_ms(
    f: &HotOp,
    x: &Tensor<4>,
    xa: &Tensor<4>,
    runs: usize,
) -> Result<(f64, f64)> {
    let fwd = time(runs, || {
        let _ = f(x.clone());
        Ok(())
    })?;
    let bwd = time(runs, || {
        let x = xa.clone().require_grad();
        let g = f(x.clone()).sum().backward();
        x.grad(&g).context("no gradient")?;
        Ok(())
    })?;
    Ok((fwd, bwd))
}

/// PyTorch's (forward, forward+backward) ms per activation, or None when torch cannot run.
fn torch_activation_ms(
    python: &str,
    shape: &str,
    threads: usize,
    runs: usize,
) -> Option<std::collections::HashMap<String, (f64, f64)>> {
    let script =
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tools/torch_bench.py");
    let out = cac_detect::torch_env::peer_command(python)
        .arg(script)
        .args(["ops", "--shape", shape, "--threads", &threads.to_string()])
        .args(["--runs", &runs.to_string()])
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let v: serde_json::Value = serde_json::from_str(text.lines().last()?).ok()?;
    v.as_object()?
        .iter()
        .map(|(k, v)| Some((k.clone(), (v[0].as_f64()?, v[1].as_f64()?))))
        .collect()
}
