//! Input defences in front of real detectors: boxes come back to the input's pixels behind a
//! defence that moves the image, the attack trains through every defence (gradients reach the
//! atlas), and `cac eval --defence` adds one column group per defence and refuses bad names.

mod support;

use cac::attack::{AttackConfig, Trainer};
use cac::detect::defence::{self, Chain, Defended};
use cac::detect::{self, labels, nms::iou, Detector};
use cac::environment::{Brightness, Condition, EnvConfig, Environment};
use cac::render::{self, RenderSettings, Renderer, Viewpoint};
use cac::scene::generate;
use std::rc::Rc;

fn renderer(size: usize, atlas: usize) -> Renderer {
    let mut s = generate::pickup();
    s.normalise(0.0, None);
    let settings = RenderSettings {
        width: size,
        height: size,
        samples: 1,
        vfov_deg: 45.0,
        atlas_res: atlas,
    };
    Renderer::new(s, settings).unwrap()
}

/// The best car or truck box in `dets`.
fn vehicle(dets: &[detect::Detection]) -> Option<[f32; 4]> {
    let (car, truck) = (labels::class_id("car"), labels::class_id("truck"));
    dets.iter()
        .filter(|d| Some(d.class_id) == car || Some(d.class_id) == truck)
        .max_by(|a, b| a.score.total_cmp(&b.score))
        .map(|d| d.bbox)
}

/// NanoDet behind resize-and-pad (scale drawn in 0.6–1, offset up to 40 % of the side) finds the
/// pickup where it finds it undefended: the boxes are mapped back from the shrunk, moved image
/// (left where the defence moved them, they would miss).
#[test]
fn behind_resize_and_pad_nanodet_finds_the_pickup_where_it_is() {
    let r = renderer(416, 64);
    let env = Environment::new(EnvConfig::default()).unwrap();
    let dev = support::device();
    let plain: Rc<dyn Detector> =
        Rc::from(detect::load("nanodet", support::models(), &dev).unwrap());
    let behind = Defended::new(plain.clone(), vec![Chain::parse("resize-pad:0.6").unwrap()]);
    let atlas = render::atlas_tensor(&r.scene.initial_atlas(64), &dev);
    let mut smallest = 1f32;
    let (mut shrunk, mut unmapped_misses) = (0, 0);
    for azimuth in [60.0, 80.0, 100.0, 120.0, 250.0, 280.0] {
        let c = Condition::plain(Viewpoint::new(azimuth, 10.0, 1.6), Brightness::Bright);
        let plan = cac::environment::plan(&r, &env, &c).unwrap();
        let img = render::composite(&[plan], atlas.clone());
        let want = vehicle(&plain.detect(img.clone()).unwrap()[0])
            .expect("NanoDet finds the pickup undefended (else the test is meaningless)");
        let (moved, m) = behind.defend(img.clone());
        smallest = smallest.min(m[0].sx);
        let raw = vehicle(&plain.detect(moved).unwrap()[0]);
        if m[0].sx < 0.85 {
            // A draw that shrank the image: without the mapping back its box is off.
            shrunk += 1;
            unmapped_misses += (raw.map_or(0.0, |b| iou(&b, &want)) < 0.8) as usize;
        }
        let got = vehicle(&behind.detect(img).unwrap()[0]);
        let overlap = got.map_or(0.0, |g| iou(&g, &want));
        assert!(
            overlap >= 0.8,
            "azimuth {azimuth}: {got:?} against {want:?} (IoU {overlap:.2})"
        );
    }
    assert!(
        smallest < 0.85,
        "no draw shrank the image much (least scale {smallest})"
    );
    // Without the mapping back the boxes are off: the mapping is what puts them right.
    assert_eq!(
        unmapped_misses, shrunk,
        "boxes on a shrunk image not mapped back still matched"
    );
}

/// A few attack steps behind each defence: the loss is finite and the gradient reaches the atlas
/// (exactly through blur and resize-and-pad, straight through the others).
#[test]
fn the_attack_trains_through_every_defence() {
    let r = renderer(96, 48);
    let env = Environment::new(EnvConfig {
        distance_ratio: [1.2, 2.0],
        elevation_deg: [0.0, 20.0],
        ..Default::default()
    })
    .unwrap();
    let nanodet = || detect::load("nanodet", support::models(), &support::device()).unwrap();
    let cfg = AttackConfig {
        models: vec!["nanodet".into()],
        iterations: 2,
        batch: 2,
        top_n: 30,
        lr: 0.05,
        seed: 3,
        checkpoint_every: 0,
        ..Default::default()
    };
    for name in [
        "jpeg:50",
        "blur:1.5",
        "median:3",
        "bits:3",
        "resize-pad:0.7",
        "tv:0.05",
        "lgs:2.3",
    ] {
        let chains = defence::parse_chains(&[name.to_string()]).unwrap();
        let dets = defence::through(vec![nanodet()], &chains);
        assert_eq!(dets[0].name(), format!("nanodet+{name}"));
        let init = r.scene.initial_atlas(48);
        let mut tr = Trainer::new(
            cfg.clone(),
            &r,
            &env,
            detect::refs(&dets),
            support::training(),
            &init,
        )
        .unwrap();
        let start = tr.state.atlas.clone();
        for _ in 0..2 {
            let log = tr.step().unwrap();
            assert!(
                log.loss.is_finite() && log.grad_norm > 0.0,
                "{name}: {log:?}"
            );
        }
        assert_ne!(tr.state.atlas, start, "{name}: the atlas did not move");
    }
}

#[test]
fn eval_adds_a_column_group_per_defence_and_refuses_bad_names() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("eval");
    let o = out.to_str().unwrap();
    let args = |defences: &'static str| {
        vec![
            "eval",
            "--object",
            "barrel",
            "--texture",
            "original",
            "--models",
            "nanodet",
            "--views",
            "1",
            "--sets",
            "fv",
            "--size",
            "96",
            "--samples",
            "1",
            "--true-classes",
            "none",
            "--defence",
            defences,
            "--out",
            o,
        ]
    };
    let bad = support::cac(&args("jpeg:75,sharpen:2"));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success()
            && err.contains("unknown defence \"sharpen\"")
            && err.contains("lgs["),
        "{err}"
    );
    assert!(!out.exists(), "nothing written for a refused evaluation");
    support::cac_ok(&args("jpeg:75,resize-pad:0.9+bits:4"));
    let records = std::fs::read_to_string(out.join("records.csv")).unwrap();
    let count = |model: &str| {
        records
            .lines()
            .filter(|l| l.split(',').nth(1) == Some(model))
            .count()
    };
    let plain = count("nanodet");
    assert!(plain > 0, "{records}");
    for m in ["nanodet+jpeg:75", "nanodet+resize-pad:0.9+bits:4"] {
        assert_eq!(count(m), plain, "{m}: {records}");
    }
    let bad = support::cac(&[
        "train",
        "--defence",
        "median:4",
        "--iterations",
        "1",
        "--out",
        o,
    ]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("odd"), "{err}");
}
