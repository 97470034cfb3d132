//! Faster R-CNN at the edges: no proposal at all, images smaller than the smallest anchor,
//! extreme logits; and the attack's dense-proposals loss running on its candidates, up to a
//! whole `Trainer` on a checkpoint loaded by name.

mod frcnn_common;

use burn::tensor::{Device, Tensor, TensorData};
use cac::attack::loss::{proposals_loss, select_proposals, ClassSet, Goal};
use cac::detect::frcnn::{one_vs_rest_logits, Arch, FasterRcnn};
use cac::detect::Detector;
use frcnn_common::{dev, image, oracle_weights};

fn values<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
    t.to_data().convert::<f32>().try_to_vec().unwrap()
}

fn model(edit: impl FnOnce(&mut cac::detect::frcnn::FrcnnConfig)) -> FasterRcnn {
    let arch = Arch::MobileNetV3Large320;
    let mut cfg = arch.config();
    edit(&mut cfg);
    FasterRcnn::from_state_dict(arch, &oracle_weights(arch), cfg, &dev()).unwrap()
}

/// Loss of the attack on the detector's candidates and its gradient on the image.
fn attack_gradient(m: &FasterRcnn, x: Tensor<4>, goal: Goal) -> (f32, Vec<f32>) {
    let x = Tensor::<4>::from_data(x.into_data(), &Device::autodiff(dev())).require_grad();
    let c = m.candidates(x.clone()).unwrap();
    assert!(values(&c.logits).iter().all(|v| v.is_finite()));
    assert!(values(&c.boxes).iter().all(|v| v.is_finite()));
    let sel = select_proposals(&c, 20, 0.5).unwrap();
    let loss = proposals_loss(c.logits, &sel, goal).unwrap();
    let l = values(&loss)[0];
    let g = x
        .grad(&loss.backward())
        .map(|g| values(&g))
        .unwrap_or_default();
    (l, g)
}

#[test]
fn the_attack_loss_runs_on_the_proposals_and_reaches_the_image() {
    let m = model(|_| {});
    let x = image("chelsea");
    let c = m.candidates(x.clone()).unwrap();
    let [b, n, k] = c.logits.dims();
    assert_eq!((b, n, k), (1, 150, 80));
    // σ(one-vs-rest logit) is the softmax score: the best candidate scores match detection.
    let best = values(&c.scores).into_iter().fold(0f32, f32::max);
    let top = m.detect(x.clone()).unwrap()[0][0].score;
    assert!((best - top).abs() < 1e-5, "{best} vs {top}");
    let (l, g) = attack_gradient(&m, x, Goal::Targeted(2));
    assert!(l.is_finite() && l > 0.0);
    assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|&v| v != 0.0));
}

#[test]
fn no_proposal_gives_no_detection_and_a_finite_zero_gradient() {
    // An objectness threshold above 1 keeps no proposal.
    let m = model(|c| c.rpn.score_thresh = 1.5);
    let x = image("chelsea");
    let out = m.run(x.clone()).unwrap().remove(0);
    assert!(out.proposals.is_empty() && out.detections.is_empty());
    assert!(m.detect(x.clone()).unwrap()[0].is_empty());
    let (l, g) = attack_gradient(&m, x, Goal::Hide(ClassSet::ALL));
    assert!(l.is_finite());
    assert!(g.iter().all(|&v| v == 0.0));
}

#[test]
fn images_smaller_than_the_anchors_stay_finite() {
    // 12×9 px resized to 16 px: a 32×32 network input, every anchor larger than the image.
    let m = model(|c| {
        c.min_size = 16;
        c.max_size = 16;
    });
    let img: Vec<f32> = (0..3 * 9 * 12).map(|i| (i % 7) as f32 / 7.0).collect();
    let x = Tensor::<4>::from_data(TensorData::new(img, [1, 3, 9, 12]), &dev());
    let out = m.run(x.clone()).unwrap().remove(0);
    assert!(out.class_logits.iter().all(|v| v.is_finite()));
    for p in &out.proposals {
        assert!(
            p[0] >= 0.0 && p[1] >= 0.0 && p[2] <= 16.0 && p[3] <= 12.0,
            "{p:?}"
        );
    }
    for d in m.detect(x.clone()).unwrap().remove(0) {
        assert!(d.bbox.iter().all(|v| v.is_finite()) && d.score.is_finite());
    }
    let (l, g) = attack_gradient(&m, x, Goal::Targeted(0));
    assert!(l.is_finite() && g.iter().all(|v| v.is_finite()));
}

#[test]
fn extreme_logits_give_finite_one_vs_rest_logits_and_gradients() {
    let ad = Device::autodiff(dev());
    let mut z = vec![0f32; 3 * 91];
    z[1] = 1e4; // person certain
    z[91 + 3] = -1e4;
    z[91 + 5] = 5e3;
    for (i, v) in z[182..].iter_mut().enumerate() {
        *v = if i % 2 == 0 { 3e4 } else { -3e4 };
    }
    let t = Tensor::<2>::from_data(TensorData::new(z.clone(), [3, 91]), &ad).require_grad();
    let l = one_vs_rest_logits(t.clone());
    let v = values(&l);
    assert!(v.iter().all(|x| x.is_finite()), "{v:?}");
    // Person (COCO-80 id 0) is certain in row 0: logit 1e4 − ln 90; every other class ≈ −1e4.
    assert!(
        (v[0] - (1e4 - 90f32.ln())).abs() < 1e-2 && v[1] < -9e3,
        "{} {}",
        v[0],
        v[1]
    );
    let g = t.grad(&l.sum().backward()).unwrap();
    assert!(values(&g).iter().all(|x| x.is_finite()));
    // σ(logit) equals the softmax probability on moderate logits.
    let z: Vec<f32> = (0..91).map(|i| (i as f32 * 0.37).sin() * 4.0).collect();
    let p = cac::detect::frcnn::postprocess::softmax(&z);
    let l = values(&one_vs_rest_logits(Tensor::from_data(
        TensorData::new(z, [1, 91]),
        &dev(),
    )));
    let map = cac::detect::labels::coco80_to_91();
    for (c80, &c91) in map.iter().enumerate() {
        let s = 1.0 / (1.0 + (-l[c80]).exp());
        assert!((s - p[c91]).abs() < 1e-6, "{c80}: {s} vs {}", p[c91]);
    }
}

/// `detect::load("frcnn-…=FILE")` gives a detector the attack's `Trainer` steps on: the texture
/// changes where the object is painted and every loss is finite. A bare model name, or a weights
/// file on a one-stage detector, is a clear error.
#[test]
fn the_trainer_attacks_a_checkpoint_loaded_by_name() {
    use cac::attack::{AttackConfig, Trainer};
    use cac::environment::{EnvConfig, Environment};
    use cac::render::{RenderSettings, Renderer};
    let arch = Arch::MobileNetV3Large320;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ckpt.safetensors");
    frcnn_common::write_safetensors(&oracle_weights(arch), "", &[], &path);
    let unused = std::path::Path::new("no-tfjs-models-needed");
    let spec = format!("{}={}", arch.name(), path.display());
    let det = cac::detect::load(&spec, unused, &dev()).unwrap();
    let bare = cac::detect::load(arch.name(), unused, &dev())
        .err()
        .unwrap();
    assert!(format!("{bare:#}").contains("=FILE.pth"), "{bare:#}");
    let wrong = cac::detect::load("nanodet=x.pth", unused, &dev())
        .err()
        .unwrap();
    assert!(
        format!("{wrong:#}").contains("only Faster R-CNN"),
        "{wrong:#}"
    );

    let mut scene = cac::scene::generate::pickup();
    scene.normalise(0.0, None);
    let settings = RenderSettings {
        width: 96,
        height: 96,
        samples: 1,
        vfov_deg: 45.0,
        atlas_res: 32,
    };
    let r = Renderer::new(scene, settings).unwrap();
    let env = Environment::new(EnvConfig {
        distance_ratio: [1.2, 2.0],
        elevation_deg: [0.0, 20.0],
        ..Default::default()
    })
    .unwrap();
    let init = r.scene.initial_atlas(32);
    let cfg = AttackConfig {
        models: vec![spec.clone()],
        iterations: 3,
        batch: 1,
        top_n: 30,
        lr: 0.05,
        seed: 3,
        checkpoint_every: 0,
        ..Default::default()
    };
    let mut t = Trainer::new(
        cfg,
        &r,
        &env,
        vec![det.as_ref()],
        Device::autodiff(dev()),
        &init,
    )
    .unwrap();
    for _ in 0..3 {
        let log = t.step().unwrap();
        assert!(log.loss.is_finite(), "loss {}", log.loss);
    }
    let before: Vec<f32> = init.texels.iter().flatten().copied().collect();
    let changed = t
        .state
        .atlas
        .iter()
        .zip(&before)
        .filter(|(a, b)| a != b)
        .count();
    assert!(
        changed > 10,
        "the attack changed only {changed} texel values"
    );
}
