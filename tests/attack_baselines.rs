//! The baselines in the CAC harness: every method runs a few iterations with a finite loss and
//! changes only paintable texels; the 2D patch transforms keep values in [0, 1]; `cac train`
//! rejects bad `--method` arguments with clear errors.

use cac::attack::baselines::{atlas, patch2d};
use cac::attack::{AttackConfig, Method, Trainer};
use cac::detect::{self, Detector};
use cac::environment::{EnvConfig, Environment};
use cac::render::{RenderSettings, Renderer};
use cac::scene::generate;
use rand::SeedableRng;
use std::collections::HashSet;
use std::process::Command;

fn inference() -> burn::tensor::Device {
    burn::tensor::Device::from(burn::backend::FlexDevice)
}

fn setup() -> (Renderer, Environment, Box<dyn Detector>) {
    let mut s = generate::jeep();
    s.normalise(0.0, None);
    let settings = RenderSettings {
        width: 96,
        height: 96,
        samples: 1,
        vfov_deg: 45.0,
        atlas_res: 48,
    };
    let r = Renderer::new(s, settings).unwrap();
    let env = Environment::new(EnvConfig {
        distance_ratio: [1.2, 2.0],
        elevation_deg: [0.0, 20.0],
        ..Default::default()
    })
    .unwrap();
    let dir = detect::fetch::ensure_models().expect("detector models are needed");
    (r, env, detect::load("nanodet", &dir, &inference()).unwrap())
}

fn config(method: Method) -> AttackConfig {
    AttackConfig {
        method,
        models: vec!["nanodet".into()],
        iterations: 3,
        batch: 2,
        top_n: 30,
        lr: 0.05,
        seed: 11,
        checkpoint_every: 0,
        patch_res: 16,
        patch_tiles: 3,
        ..Default::default()
    }
}

#[test]
fn every_baseline_runs_with_finite_loss_and_changes_only_paintable_texels() {
    let (r, env, d) = setup();
    let init = r.scene.initial_atlas(48);
    let mask = atlas::paintable_texels(&r.scene, 48);
    // The mask covers every texel the renderer can read from a paintable surface.
    let cfg = config(Method::Upc);
    for i in 0..4 {
        for c in cac::attack::draw_conditions(&env, &cfg, i) {
            let plan = cac::environment::plan(&r, &env, &c).unwrap();
            for &t in &plan.tap_texel {
                assert!(
                    mask[t as usize],
                    "texel {t} is sampled but not in the paintable mask"
                );
            }
        }
    }
    let dev = burn::tensor::Device::autodiff(inference());
    for method in [
        Method::Advpat,
        Method::Shapeshifter,
        Method::Upc,
        Method::Camou,
    ] {
        let cfg = config(method);
        let mut run = Trainer::new(cfg, &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
        for _ in 0..3 {
            let log = run.step().unwrap();
            assert!(
                log.loss.is_finite() && log.grad_norm.is_finite(),
                "{method:?}: {log:?}"
            );
            assert!(log.grad_norm > 0.0, "{method:?}: no gradient");
        }
        let out = run.atlas();
        let mut changed = 0;
        for (k, (a, b)) in out.texels.iter().zip(&init.texels).enumerate() {
            if a != b {
                changed += 1;
                assert!(
                    mask[k],
                    "{method:?} changed texel {k}, which no paintable surface covers"
                );
            }
        }
        assert!(changed > 50, "{method:?} changed only {changed} texels");
        if method.is_2d() {
            // The whole paintable area carries the tiled patch.
            let patch_colours: HashSet<[u32; 3]> = out
                .texels
                .iter()
                .zip(&mask)
                .filter(|(_, m)| **m)
                .map(|(t, _)| t.map(f32::to_bits))
                .collect();
            assert!(
                patch_colours.len() > 10,
                "{method:?}: the patch is not on the object"
            );
        }
    }
}

#[test]
fn a_resumed_patch_run_equals_an_uninterrupted_one() {
    let (r, env, d) = setup();
    let init = r.scene.initial_atlas(48);
    let dev = burn::tensor::Device::autodiff(inference());
    let cfg = config(Method::Advpat);
    let mut a = Trainer::new(cfg.clone(), &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
    for _ in 0..3 {
        a.step().unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let mut b = Trainer::new(cfg.clone(), &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
    b.step().unwrap();
    b.step().unwrap();
    cac::attack::checkpoint::save(dir.path(), &b.state).unwrap();
    let mut c = Trainer::new(cfg, &r, &env, vec![d.as_ref()], dev, &init)
        .unwrap()
        .resume(dir.path())
        .unwrap();
    c.step().unwrap();
    assert_eq!(a.state.atlas, c.state.atlas, "resumed patch differs");
    assert_eq!(a.state.adam, c.state.adam);
}

#[test]
fn patch_transforms_keep_values_in_unit_range_and_pass_gradients() {
    let dev = burn::tensor::Device::autodiff(inference());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    // An extreme patch (0s and 1s) and background, the widest photometric ranges.
    let p = 12;
    let vals: Vec<f32> = (0..p * p * 3).map(|i| (i % 2) as f32).collect();
    let patch = burn::tensor::Tensor::<4>::from_data(
        burn::tensor::TensorData::new(vals, [1, p, p, 3]),
        &dev,
    )
    .require_grad();
    let ranges = patch2d::TransformRanges {
        contrast: [0.5, 2.0],
        brightness: 0.5,
        noise: 0.5,
        ..Default::default()
    };
    let ts: Vec<_> = (0..3)
        .map(|_| ranges.sample([10.0, 12.0, 50.0, 40.0], &mut rng))
        .collect();
    let bg: Vec<f32> = (0..3 * 3 * 64 * 64)
        .map(|i| ((i * 7919) % 101) as f32 / 100.0)
        .collect();
    let img = patch2d::paste(&bg, [3, 3, 64, 64], patch.clone(), &ts, &dev).unwrap();
    let v = img
        .clone()
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .unwrap();
    assert!(
        v.iter().all(|x| (0.0..=1.0).contains(x)),
        "pasted image leaves [0, 1]"
    );
    let differs = v.iter().zip(&bg).filter(|(a, b)| a != b).count();
    assert!(
        differs > 500,
        "the patch is barely pasted ({differs} values)"
    );
    let g = patch.grad(&img.sum().backward()).unwrap();
    let g = g.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
    assert!(g.iter().all(|x| x.is_finite()) && g.iter().any(|x| *x != 0.0));
    let ph = patch2d::photometric(patch.inner(), &ts);
    let pv = ph.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
    assert!(pv.iter().all(|x| (0.0..=1.0).contains(x)));
}

fn cac(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cac"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn train_rejects_bad_method_arguments_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = out.to_str().unwrap();
    let (ok, err) = cac(&["train", "--method", "yolo", "--out", o]);
    assert!(
        !ok && err.contains("--method") && err.contains("advpat"),
        "{err}"
    );
    let (ok, err) = cac(&["train", "--method", "upc", "--hide", "--out", o]);
    assert!(
        !ok && err.contains("--hide") && err.contains("upc"),
        "{err}"
    );
    let (ok, err) = cac(&[
        "train",
        "--method",
        "advpat",
        "--patch-res",
        "2",
        "--out",
        o,
    ]);
    assert!(!ok && err.contains("--patch-res"), "{err}");
    let (ok, err) = cac(&[
        "train",
        "--method",
        "shapeshifter",
        "--target",
        "unicorn",
        "--out",
        o,
    ]);
    assert!(!ok && err.contains("unicorn"), "{err}");
    assert!(
        !out.join("run.json").exists(),
        "a rejected run must not write a run folder"
    );
    let (ok, err) = cac(&[
        "texture",
        "naive",
        "--res",
        "1",
        "--out",
        dir.path().join("t.png").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("--res"), "{err}");
}
