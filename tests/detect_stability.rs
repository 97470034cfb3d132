//! Stability of the detectors: extreme inputs give finite outputs and finite, non-zero
//! gradients with respect to the input image; broken model files and wrong input shapes give
//! clear errors. Needs the model files (fetched with npm on first use, cached).
//!
//! Every random input is drawn from a seeded generator: the seed is `CAC_TEST_SEED` (a fixed
//! default otherwise) and every assertion names it, so a failure can be replayed.

mod support;

use burn::tensor::{Device, Tensor, TensorData};
use cac::detect;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution as _, Normal};
use std::path::Path;
use support::{device as inference, models};

/// The seed of the random inputs (`CAC_TEST_SEED`, else a fixed default).
fn seed() -> u64 {
    std::env::var("CAC_TEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x5EED_0DE7)
}

/// A random `shape` tensor of values drawn by `draw` from a generator seeded with `seed`.
fn random(
    shape: [usize; 4],
    seed: u64,
    device: &Device,
    mut draw: impl FnMut(&mut ChaCha8Rng) -> f32,
) -> Tensor<4> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let v: Vec<f32> = (0..shape.iter().product())
        .map(|_| draw(&mut rng))
        .collect();
    Tensor::from_data(TensorData::new(v, shape), device)
}

fn all_finite(t: &Tensor<3>) -> bool {
    t.to_data().iter::<f32>().all(f32::is_finite)
}

fn inputs(device: &Device, seed: u64) -> Vec<(&'static str, Tensor<4>)> {
    let shape = [1, 3, 96, 128];
    let noise = random(shape, seed, device, |r| r.random::<f32>());
    let saturated = random(shape, seed + 1, device, |r| r.random_bool(0.5) as u8 as f32);
    let normal = Normal::new(0.5f32, 2.0).expect("valid normal");
    let clipped = random(shape, seed + 2, device, |r| {
        normal.sample(r).clamp(0.0, 1.0)
    });
    vec![
        ("black", Tensor::zeros(shape, device)),
        ("white", Tensor::ones(shape, device)),
        ("noise", noise),
        ("saturated noise", saturated),
        ("0/1-clipped", clipped),
    ]
}

fn check_stable(name: &str) {
    let det = detect::load(name, models(), &inference()).unwrap();
    let ad = support::training();
    let seed = seed();
    for (what, x) in inputs(&ad, seed) {
        let what = format!("{what} (seed {seed})");
        let x = x.require_grad();
        let c = det.candidates(x.clone()).unwrap();
        assert!(all_finite(&c.boxes), "{name}/{what}: non-finite boxes");
        assert!(all_finite(&c.scores), "{name}/{what}: non-finite scores");
        assert!(all_finite(&c.logits), "{name}/{what}: non-finite logits");
        // The attack's kind of loss: the strongest class evidence, plus box geometry.
        let loss = c.logits.clone().max_dim(2).sum() + c.boxes.clone().sum().mul_scalar(1e-3);
        let grads = loss.backward();
        let g = x.grad(&grads).expect("gradient reaches the input image");
        let gv: Vec<f32> = g.to_data().iter::<f32>().collect();
        assert!(
            gv.iter().all(|v| v.is_finite()),
            "{name}/{what}: non-finite gradient"
        );
        assert!(gv.iter().any(|&v| v != 0.0), "{name}/{what}: zero gradient");
        let dets = det.detect(x.detach()).unwrap();
        for d in &dets[0] {
            assert!(d.score.is_finite() && d.bbox.iter().all(|v| v.is_finite()));
        }
    }
}

#[test]
fn centernet_is_stable_and_differentiable() {
    check_stable("centernet");
}

#[test]
fn nanodet_is_stable_and_differentiable() {
    check_stable("nanodet");
}

#[test]
fn candidates_have_documented_shapes_and_batches() {
    let device = inference();
    for (name, n) in [
        ("centernet", 128 * 128),
        ("nanodet", 52 * 52 + 26 * 26 + 13 * 13),
    ] {
        let det = detect::load(name, models(), &device).unwrap();
        let seed = seed();
        let name = format!("{name} (seed {seed})");
        let x = random([2, 3, 64, 80], seed, &device, |r| r.random::<f32>());
        let c = det.candidates(x.clone()).unwrap();
        assert_eq!(c.boxes.dims(), [2, n, 4], "{name}");
        assert_eq!(c.scores.dims(), [2, n, 80], "{name}");
        // Batch entries are independent: image 1 alone gives the same scores.
        let single = det.candidates(x.clone().narrow(0, 1, 1)).unwrap();
        let a: Vec<f32> = c
            .scores
            .clone()
            .narrow(0, 1, 1)
            .to_data()
            .iter::<f32>()
            .collect();
        let b: Vec<f32> = single.scores.to_data().iter::<f32>().collect();
        let diff = a
            .iter()
            .zip(&b)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f32::max);
        assert!(
            diff < 1e-5,
            "{name}: batch of 2 differs from single image by {diff}"
        );
        // sigmoid(logits) == scores
        let s: Vec<f32> = burn::tensor::activation::sigmoid(c.logits)
            .to_data()
            .iter::<f32>()
            .collect();
        let t: Vec<f32> = c.scores.to_data().iter::<f32>().collect();
        assert!(
            s.iter().zip(&t).all(|(p, q)| (p - q).abs() < 1e-6),
            "{name}: sigmoid(logits) != scores"
        );
    }
}

#[test]
fn wrong_input_shapes_are_clear_errors() {
    let device = inference();
    let det = detect::load("centernet", models(), &device).unwrap();
    let gray = Tensor::<4>::zeros([1, 1, 64, 64], &device);
    let e = format!("{:#}", det.candidates(gray).unwrap_err());
    assert!(e.contains("[B, 3, H, W]"), "{e}");
    assert!(detect::load("yolo", models(), &device).is_err());
}

fn copy_models(to: &Path) {
    for (f, _) in detect::fetch::FILES {
        std::fs::copy(models().join(f), to.join(f)).unwrap();
    }
}

#[test]
fn corrupted_or_truncated_model_files_are_clear_errors() {
    let device = inference();
    let dir = tempfile::tempdir().unwrap();
    copy_models(dir.path());
    // Truncated .bin
    let bin = dir.path().join("nanodet.bin");
    let bytes = std::fs::read(&bin).unwrap();
    std::fs::write(&bin, &bytes[..bytes.len() - 1000]).unwrap();
    let e = format!(
        "{:#}",
        detect::load("nanodet", dir.path(), &device).err().unwrap()
    );
    assert!(e.contains("nanodet") && e.contains("truncated"), "{e}");
    assert!(format!("{:#}", detect::fetch::verify(dir.path()).unwrap_err()).contains("SHA-256"));
    // Truncated JSON
    let json = dir.path().join("centernet.json");
    let text = std::fs::read_to_string(&json).unwrap();
    std::fs::write(&json, &text[..text.len() / 2]).unwrap();
    let e = format!(
        "{:#}",
        detect::load("centernet", dir.path(), &device)
            .err()
            .unwrap()
    );
    assert!(
        e.contains("centernet.json") && e.contains("not a valid"),
        "{e}"
    );
    // A graph with an op the importer does not know: the error names node and op.
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    for n in v["modelTopology"]["node"].as_array_mut().unwrap() {
        if n["name"] == "tower_0/CenternetHead/Relu" {
            n["op"] = "Erf".into();
        }
    }
    std::fs::write(&json, serde_json::to_string(&v).unwrap()).unwrap();
    let det = detect::load("centernet", dir.path(), &device).unwrap();
    let e = format!(
        "{:#}",
        det.detect(Tensor::zeros([1, 3, 32, 32], &device))
            .unwrap_err()
    );
    assert!(
        e.contains("tower_0/CenternetHead/Relu") && e.contains("unsupported op Erf"),
        "{e}"
    );
    // Missing files
    let e = format!(
        "{:#}",
        detect::load("nanodet", Path::new("/nonexistent"), &device)
            .err()
            .unwrap()
    );
    assert!(e.contains("/nonexistent/nanodet.json"), "{e}");
}
