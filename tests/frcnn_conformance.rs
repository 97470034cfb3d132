//! Faster R-CNN matched to torchvision: the three models rebuilt on the oracle's deterministic
//! weights (tools/torchvision_oracle.py, files in tests/data/frcnn) give the same proposals,
//! class logits, box regressions and detections, each within 4 × torchvision's own float noise
//! on that image (the json's `noise`, see [`Bounds`]); gradients reach the image; the `.pth` /
//! safetensors readers load real files and name what is wrong with bad ones.

mod frcnn_common;

use burn::tensor::{Device, Tensor, TensorData};
use cac::detect::frcnn::weights::StateDict;
use cac::detect::frcnn::{Arch, FasterRcnn, FrcnnConfig};
use frcnn_common::{data, dev, image, npy, oracle_weights, uniform};

fn rel(a: &[f32], b: &[f32]) -> f64 {
    cac::detect::raw::relative_error(a, b)
}

/// How many times torchvision's own float noise cac may be off: cac's kernels sum in other
/// orders at every layer, as the oracle's re-runs do. Measured (docs/detectors.md): cac's errors
/// are 0.5–1.2× the noise with Flex and 0.7–1.7× with libtorch on an AMD EPYC with AVX2; the box
/// that failed the old fixed 1e-3 px bound (issue 48) is 1.14×. A wrong anchor, a swapped
/// coordinate or a wrong weight is off by orders of magnitude more.
const NOISE_FACTOR: f64 = 4.0;

/// The bounds of one oracle case, [`NOISE_FACTOR`] times torchvision's own float noise on it
/// (the json's `noise`, measured by tools/torchvision_oracle.py: the spread of torchvision's
/// outputs over a two-ulp input jitter, one thread against two, and channels-last convolutions).
/// Box and proposal coordinates are bounded relative to the box's larger side (the regression
/// is decoded through `exp` times the anchor's size, so the rounding grows with the box).
#[derive(Debug, Clone, Copy)]
struct Bounds {
    logits_rel: f64,
    regression_rel: f64,
    proposals_size_rel: f64,
    boxes_size_rel: f64,
    scores_abs: f64,
}

impl Bounds {
    fn from_noise(meta: &serde_json::Value, what: &str) -> Bounds {
        let noise = |k: &str| {
            let v = meta["noise"][k].as_f64().unwrap_or_else(|| {
                panic!("{what}: the oracle's json has no noise.{k} (tools/torchvision_oracle.py --noise-only)")
            });
            assert!(v.is_finite() && v >= 0.0, "{what}: noise.{k} = {v}");
            NOISE_FACTOR * v.max(f32::EPSILON as f64)
        };
        Bounds {
            logits_rel: noise("logits_rel"),
            regression_rel: noise("regression_rel"),
            proposals_size_rel: noise("proposals_size_rel"),
            boxes_size_rel: noise("boxes_size_rel"),
            scores_abs: noise("scores_abs"),
        }
    }
}

/// A box's larger side (at least 1 px): the scale its coordinates' rounding grows with.
fn size(b: &[f32]) -> f64 {
    ((b[2] - b[0]).max(b[3] - b[1]) as f64).max(1.0)
}

/// The largest coordinate difference of two boxes relative to `want`'s larger side.
fn size_rel(a: &[f32], want: &[f32]) -> f64 {
    a.iter()
        .zip(want)
        .fold(0f64, |m, (p, q)| m.max((p - q).abs() as f64))
        / size(want)
}

/// Runs one model on the oracle's images and checks every output against [`Bounds`]; returns
/// the worst errors as multiples of torchvision's own noise (logits, regression, proposals,
/// detection boxes, detection scores).
fn conformance(arch: Arch, images: &[&str]) -> [f64; 5] {
    let name = arch.name();
    let mut worst = [0f64; 5];
    let mut model: Option<FasterRcnn> = None;
    for stem in images {
        let meta: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(data(&format!("{name}-{stem}.json"))).unwrap(),
        )
        .unwrap();
        if model.is_none() {
            let mut cfg: FrcnnConfig = arch.config();
            cfg.min_size = meta["min_size"].as_u64().unwrap() as usize;
            cfg.max_size = meta["max_size"].as_u64().unwrap() as usize;
            model = Some(
                FasterRcnn::from_state_dict(arch, &oracle_weights(arch), cfg, &dev()).unwrap(),
            );
        }
        let what = format!("{name} {stem}");
        let bounds = Bounds::from_noise(&meta, &what);
        let m = model.as_ref().unwrap();
        let out = m.run(image(stem)).unwrap().remove(0);
        let rs = meta["resized_size"].as_array().unwrap();
        assert_eq!(
            out.geometry.resized.0 as u64,
            rs[0].as_u64().unwrap(),
            "{name} {stem}"
        );
        assert_eq!(
            out.geometry.resized.1 as u64,
            rs[1].as_u64().unwrap(),
            "{name} {stem}"
        );

        let (ps, pv) = npy(&data(&format!("{name}-{stem}-proposals.npy")));
        assert_eq!(out.proposals.len(), ps[0], "{name} {stem}: proposal count");
        let (order, dp) = proposal_order(&out.proposals, &pv, bounds.proposals_size_rel, &what);
        worst[2] = worst[2].max(dp / bounds.proposals_size_rel * NOISE_FACTOR);

        // Relative error of an output against its bound, kept as a multiple of the noise.
        let mut within = |slot: usize, output: &str, e: f64, bound: f64| {
            assert!(
                e <= bound,
                "{what}: {output} relative error {e:.3e} over {bound:.3e} ({NOISE_FACTOR} x torchvision's noise)"
            );
            worst[slot] = worst[slot].max(e / bound * NOISE_FACTOR);
            e
        };
        let (_, lv) = npy(&data(&format!("{name}-{stem}-class_logits.npy")));
        let (a, b) = paired_rows(&out.class_logits, &lv, &order);
        let el = within(0, "class logits", rel(&a, &b), bounds.logits_rel);
        let (rs, rv) = npy(&data(&format!("{name}-{stem}-box_regression.npy")));
        let (a, b) = paired_rows(&out.box_regression[..rs[0] * rs[1]], &rv, &order[..rs[0]]);
        let er = within(1, "box regression", rel(&a, &b), bounds.regression_rel);

        let d = &meta["detections"];
        let want: Vec<(usize, f32, [f32; 4])> = (0..d["labels"].as_array().unwrap().len())
            .map(|k| {
                let b = d["boxes"][k].as_array().unwrap();
                let b: Vec<f32> = b.iter().map(|v| v.as_f64().unwrap() as f32).collect();
                (
                    d["labels"][k].as_u64().unwrap() as usize,
                    d["scores"][k].as_f64().unwrap() as f32,
                    [b[0], b[1], b[2], b[3]],
                )
            })
            .collect();
        let mine: Vec<(usize, f32, [f32; 4])> = out
            .detections
            .iter()
            .map(|d| (d.label, d.score, d.bbox))
            .collect();
        let (dbox, dscore) =
            same_detections(&mine, &want, bounds, &what).unwrap_or_else(|e| panic!("{e}"));
        worst[3] = worst[3].max(dbox / bounds.boxes_size_rel * NOISE_FACTOR);
        worst[4] = worst[4].max(dscore / bounds.scores_abs * NOISE_FACTOR);
        eprintln!(
            "{what}: {} proposals, {} detections; here: logits {el:.2e} rel, regression \
             {er:.2e} rel, proposals {dp:.2e} of the box's side, boxes {dbox:.2e} of the box's \
             side, scores {dscore:.2e}; worst so far in units of torchvision's noise (logits, \
             regression, proposals, boxes, scores): {:.2} {:.2} {:.2} {:.2} {:.2} (bound \
             {NOISE_FACTOR})",
            out.proposals.len(),
            out.detections.len(),
            worst[0],
            worst[1],
            worst[2],
            worst[3],
            worst[4]
        );
    }
    worst
}

/// Which of torchvision's proposals (`want`, 4 values each) each of ours is: the one at the same
/// place, or, where two objectness scores tie to float rounding and the kernels' summation order
/// ranks them the other way round (libtorch's channels-last convolutions do, as PyTorch builds
/// do between themselves), one within 4 places of it; each box within `bound` of its larger
/// side, one to one, and at most 1 % of them (at least one swapped pair) out of place. The
/// oracle's files hold no objectness scores, so the tie itself is not checked.
/// Returns the order and the worst box difference (relative to the box's larger side).
fn proposal_order(mine: &[[f32; 4]], want: &[f32], bound: f64, what: &str) -> (Vec<usize>, f64) {
    let n = want.len() / 4;
    let (mut used, mut order, mut worst) = (vec![false; n], Vec::new(), 0f64);
    for (i, a) in mine.iter().enumerate() {
        let near = (i.saturating_sub(4)..(i + 5).min(n)).filter(|&j| !used[j]);
        let best = near
            .map(|j| (size_rel(a, &want[4 * j..4 * j + 4]), j))
            .min_by(|p, q| p.0.total_cmp(&q.0));
        let Some((d, j)) = best.filter(|&(d, _)| d <= bound) else {
            panic!(
                "{what}: proposal {i} {a:?} is none of torchvision's near its place (within \
                 {bound:.2e} of the box's side; nearest: {best:?})"
            );
        };
        used[j] = true;
        order.push(j);
        worst = worst.max(d);
    }
    let moved = order.iter().enumerate().filter(|(i, j)| i != *j).count();
    assert!(
        moved <= (n / 100).max(2),
        "{what}: {moved} of {n} proposals out of place"
    );
    (order, worst)
}

/// Our rows of `mine` and torchvision's rows of `want` they are (row `i` of ours is row
/// `order[i]` of torchvision's; both hold `order.len()` rows), leaving out a row whose match
/// torchvision's file does not hold (it keeps the first rows only).
fn paired_rows(mine: &[f32], want: &[f32], order: &[usize]) -> (Vec<f32>, Vec<f32>) {
    let row = mine.len() / order.len();
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for (i, &j) in order.iter().enumerate().filter(|(_, &j)| j < order.len()) {
        a.extend_from_slice(&mine[i * row..(i + 1) * row]);
        b.extend_from_slice(&want[j * row..(j + 1) * row]);
    }
    (a, b)
}

/// The same detections as torchvision's (an error saying the first that differs otherwise), in
/// torchvision's order except where two scores lie
/// within the score bound of each other (there the summation order of the kernels decides, as it
/// does between PyTorch builds): each of torchvision's detections has one of ours with its label,
/// its box within `bounds.boxes_size_rel` of its larger side and its score within
/// `bounds.scores_abs`, and ours are sorted by decreasing score.
/// Returns the worst box (relative to the box's larger side) and score differences.
fn same_detections(
    mine: &[(usize, f32, [f32; 4])],
    want: &[(usize, f32, [f32; 4])],
    bounds: Bounds,
    what: &str,
) -> Result<(f64, f64), String> {
    if mine.len() != want.len() {
        return Err(format!(
            "{what}: {} detections, torchvision {}",
            mine.len(),
            want.len()
        ));
    }
    if !mine.windows(2).all(|p| p[0].1 >= p[1].1) {
        return Err(format!("{what}: detections not sorted by score"));
    }
    let (mut dbox, mut dscore) = (0f64, 0f64);
    let mut used = vec![false; mine.len()];
    for (k, (label, score, bbox)) in want.iter().enumerate() {
        let gap =
            |(_, s, b): &(usize, f32, [f32; 4])| (size_rel(b, bbox), (s - score).abs() as f64);
        let found = (0..mine.len()).find(|&j| {
            let (b, s) = gap(&mine[j]);
            !used[j] && mine[j].0 == *label && b <= bounds.boxes_size_rel && s <= bounds.scores_abs
        });
        let Some(j) = found else {
            return Err(format!(
                "{what}: torchvision's detection {k} (label {label}, score {score}, box {bbox:?}) \
                 has no match within {bounds:?}; ours at {k}: {:?} (off by {:?})",
                mine.get(k),
                mine.get(k).map(gap)
            ));
        };
        used[j] = true;
        let (b, s) = gap(&mine[j]);
        dbox = dbox.max(b);
        dscore = dscore.max(s);
    }
    Ok((dbox, dscore))
}

#[test]
fn mobilenet_v3_320_matches_torchvision() {
    conformance(Arch::MobileNetV3Large320, &["chelsea", "astronaut"]);
}

/// torchvision run with `min_size=400` (the oracle's setting) to keep the test short.
#[test]
fn mobilenet_v3_matches_torchvision() {
    conformance(Arch::MobileNetV3Large, &["chelsea"]);
}

/// torchvision run with `min_size=320` (the oracle's setting) to keep the test short.
#[test]
fn resnet50_matches_torchvision() {
    conformance(Arch::ResNet50, &["chelsea"]);
}

// ---- weights files ----

#[test]
fn pth_reader_loads_torch_save_and_names_missing_unexpected_and_misshaped_keys() {
    let arch = Arch::MobileNetV3Large320;
    let sd = StateDict::read(&data("subset.pth")).unwrap();
    let want = oracle_weights(arch);
    assert!(sd.tensors.len() >= 15, "{} tensors", sd.tensors.len());
    for (k, t) in &sd.tensors {
        assert_eq!(Some(t), want.tensors.get(k), "{k}");
    }
    let err = FasterRcnn::from_state_dict(arch, &sd, arch.config(), &dev())
        .err()
        .expect("a subset is not a model")
        .to_string();
    assert!(err.contains("subset.pth"), "{err}");
    assert!(
        err.contains("missing keys: backbone.body.2.block.0.0.weight [64, 16, 1, 1]"),
        "{err}"
    );
    assert!(!err.contains("unexpected"), "{err}");

    let bad = StateDict::read(&data("bad.pth")).unwrap();
    let err = FasterRcnn::from_state_dict(arch, &bad, arch.config(), &dev())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("1 unexpected keys: extra.unexpected.weight"),
        "{err}"
    );
    assert!(
        err.contains(
            "backbone.body.0.0.weight: the file has [16, 3, 5, 5], the model needs [16, 3, 3, 3]"
        ),
        "{err}"
    );
    let err = StateDict::read(&data("frcnn-mobilenet-v3-320-chelsea.json"))
        .err()
        .unwrap();
    assert!(
        format!("{err:#}").contains("frcnn-mobilenet-v3-320-chelsea.json"),
        "{err:#}"
    );
}

#[test]
fn safetensors_and_prefixed_checkpoints_load_the_same_model() {
    let arch = Arch::MobileNetV3Large320;
    let sd = oracle_weights(arch);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frcnn.safetensors");
    // A training checkpoint's layout: everything under `model.`, with other state beside it
    // (ignored: it is outside the model's prefix).
    frcnn_common::write_safetensors(
        &sd,
        "model.",
        &[("optimizer.state.0.momentum", &[2])],
        &path,
    );
    let a = FasterRcnn::load(arch.name(), &path, &dev()).unwrap();
    let b = FasterRcnn::from_state_dict(arch, &sd, arch.config(), &dev()).unwrap();
    let x = image("chelsea");
    let (oa, ob) = (
        a.run(x.clone()).unwrap().remove(0),
        b.run(x).unwrap().remove(0),
    );
    assert_eq!(oa.proposals, ob.proposals);
    assert_eq!(oa.class_logits, ob.class_logits);
    assert_eq!(oa.detections, ob.detections);
}

// ---- gradients ----

/// d(Σ class logits over the fixed proposals)/d(image) on a small image: equal to torchvision's
/// autograd gradient, and to a central finite difference along a fixed direction.
#[test]
fn class_logit_gradient_matches_torch_and_finite_differences() {
    let arch = Arch::MobileNetV3Large320;
    let m =
        FasterRcnn::from_state_dict(arch, &oracle_weights(arch), arch.config(), &dev()).unwrap();
    let (shape, img) = npy(&data("grad-image.npy"));
    let (h, w) = (shape[1], shape[2]);
    let x0 = Tensor::<4>::from_data(TensorData::new(img.clone(), [1, 3, h, w]), &dev());
    let props = m.proposals(x0).unwrap();
    let (_, tp) = npy(&data("grad-proposals.npy"));
    let mine: Vec<f32> = props[0].iter().flatten().copied().collect();
    assert_eq!(mine.len(), tp.len());
    assert!(mine.iter().zip(&tp).all(|(a, b)| (a - b).abs() <= 1e-3));
    let loss = |x: Tensor<4>| {
        let (f, g, _) = m.features(x).unwrap();
        m.box_outputs(&f, g, &props).unwrap().0.sum()
    };
    let ad = Device::autodiff(dev());
    let xa = Tensor::<4>::from_data(TensorData::new(img.clone(), [1, 3, h, w]), &ad).require_grad();
    let l = loss(xa.clone());
    let grad = xa.grad(&l.backward()).expect("gradient reaches the image");
    let g: Vec<f32> = grad.into_data().convert::<f32>().try_to_vec().unwrap();
    let (_, tg) = npy(&data("grad-image-grad.npy"));
    let e = rel(&g, &tg);
    let norm = |v: &mut dyn Iterator<Item = f64>| v.map(|x| x * x).sum::<f64>().sqrt();
    let e2 = norm(&mut g.iter().zip(&tg).map(|(a, b)| (a - b) as f64))
        / norm(&mut tg.iter().map(|&b| b as f64));
    eprintln!("image gradient vs torch autograd: max relative error {e:.2e}, L2 relative {e2:.2e}");
    // Looser than the forward bound: the random network has units within rounding of a ReLU or
    // hard-swish kink, which switch paths with the summation order. Measured: adding 1e-7 times
    // a seeded direction to the image (below its f32 resolution) moves the gradient from 5.9e-4
    // to 3.05e-3 of torch's (max) and 3.4e-4 to 2.9e-3 (L2) with burn's convolutions; this
    // crate's stem kernel (another order of the same sums, 1e-7 from burn's on this layer)
    // lands on 3.05e-3 too. A wrong backward is off by O(1).
    assert!(
        e <= 6e-3 && e2 <= 6e-3,
        "gradient relative error {e} (max), {e2} (L2)"
    );

    // Finite differences (the random network is strongly non-linear: small step, loose bound).
    let dir: Vec<f32> = uniform("direction", 3 * h * w)
        .iter()
        .map(|&v| v as f32)
        .collect();
    let analytic: f64 = g.iter().zip(&dir).map(|(a, b)| (a * b) as f64).sum();
    let eps = 3e-4f32;
    let shifted = |s: f32| {
        let v: Vec<f32> = img.iter().zip(&dir).map(|(a, d)| a + s * d).collect();
        loss(Tensor::from_data(TensorData::new(v, [1, 3, h, w]), &dev())).into_scalar::<f32>()
            as f64
    };
    let numeric = (shifted(eps) - shifted(-eps)) / (2.0 * eps as f64);
    let e = (analytic - numeric).abs() / numeric.abs().max(1e-6);
    eprintln!("directional derivative: autodiff {analytic:.4}, finite difference {numeric:.4}, relative error {e:.2e}");
    assert!(
        e < 5e-2,
        "autodiff {analytic} vs finite difference {numeric}"
    );
}

// ---- the command line ----

/// `cac detect --model frcnn-… --weights FILE` (the README's command) loads the checkpoint and
/// prints the library's detections; without `--weights` it says what is missing.
#[test]
fn cac_detect_takes_the_checkpoint_from_weights() {
    use cac::detect::Detector;
    let arch = Arch::MobileNetV3Large320;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frcnn.safetensors");
    frcnn_common::write_safetensors(&oracle_weights(arch), "", &[], &path);
    let img = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/reference/images/chelsea.png");
    let run = |extra: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_cac"))
            .args([
                "detect",
                img.to_str().unwrap(),
                "--model",
                arch.name(),
                "--json",
            ])
            .args(extra)
            .output()
            .unwrap()
    };
    let out = run(&["--weights", path.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let printed: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let m = FasterRcnn::load(arch.name(), &path, &dev()).unwrap();
    let want = m.detect(image("chelsea")).unwrap().remove(0);
    assert_eq!(printed.len(), want.len(), "{printed:?}");
    for (p, d) in printed.iter().zip(&want) {
        assert_eq!(p["label"], d.label);
        assert!((p["score"].as_f64().unwrap() - d.score as f64).abs() < 1e-4);
    }
    let out = run(&[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("needs --weights"),
        "{stderr}"
    );
}

/// The noise-derived bounds still catch what a bug does: torchvision's own detections match
/// themselves, and fail with one box moved by a tenth of a pixel (a wrong anchor or offset is
/// off by more), with x and y swapped, or with a score moved by 1e-4.
#[test]
fn the_bounds_catch_a_moved_box_a_swapped_coordinate_and_a_moved_score() {
    for stem in [
        "frcnn-mobilenet-v3-320-chelsea",
        "frcnn-mobilenet-v3-320-astronaut",
        "frcnn-mobilenet-v3-chelsea",
        "frcnn-resnet50-chelsea",
    ] {
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(data(&format!("{stem}.json"))).unwrap())
                .unwrap();
        let bounds = Bounds::from_noise(&meta, stem);
        let d = &meta["detections"];
        let want: Vec<(usize, f32, [f32; 4])> = (0..d["labels"].as_array().unwrap().len())
            .map(|k| {
                let b: Vec<f32> = d["boxes"][k]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap() as f32)
                    .collect();
                let label = d["labels"][k].as_u64().unwrap() as usize;
                (
                    label,
                    d["scores"][k].as_f64().unwrap() as f32,
                    [b[0], b[1], b[2], b[3]],
                )
            })
            .collect();
        assert_eq!(same_detections(&want, &want, bounds, stem), Ok((0.0, 0.0)));
        // The largest box: the loosest bound in pixels.
        let k = (0..want.len())
            .max_by(|&a, &b| size(&want[a].2).total_cmp(&size(&want[b].2)))
            .unwrap();
        let (label, score, b) = want[k];
        let fails = |at: usize, bad: (usize, f32, [f32; 4])| {
            let mut mine = want.clone();
            mine[at] = bad;
            let err = same_detections(&mine, &want, bounds, stem).expect_err("a bug passed");
            err.contains("has no match")
        };
        let moved = [b[0] + 0.1, b[1], b[2] + 0.1, b[3]];
        assert!(fails(k, (label, score, moved)), "{stem}: moved box");
        assert!(
            fails(k, (label, score, [b[1], b[0], b[3], b[2]])),
            "{stem}: x, y swapped"
        );
        // The top detection's score raised: still sorted, so only the score bound can fail it.
        let (label, score, b) = want[0];
        assert!(fails(0, (label, score + 1e-4, b)), "{stem}: moved score");
    }
}
