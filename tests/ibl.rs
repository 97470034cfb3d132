//! Image-based lighting in cac's renderer (`render::ibl`), on a seeded synthetic environment
//! written as Radiance HDR: a coloured sky, a darker lower half and a small sun. The lit view is
//! exact in bands, its coloured taps composite on tensors as on the CPU with gradients that
//! match finite differences, occlusion never adds light, extremes stay finite, the protocol's
//! draws are unchanged by the new config keys, and bad files are clear errors. (Agreement with
//! Cycles under Blender's own maps: `tests/blender.rs`.)

mod support;

use burn::tensor::{DType, Tensor, TensorData};
use cac::environment::ViewpointSet;
use cac::environment::{self, Brightness, Condition, EnvConfig, Environment, HdriDraw};
use cac::render::{self, ibl::IblSettings, RenderSettings, Renderer, Viewpoint};
use cac::scene::generate;
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use support::device;

/// A 128×64 equirectangular map: sky blue to white at the horizon, brown ground, and a sun of
/// 3×3 texels at azimuth column 40, row 18 (elevation ~39°), with seeded texel noise.
fn write_map(dir: &Path) -> PathBuf {
    let (w, h) = (128usize, 64usize);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
    let px: Vec<image::Rgb<f32>> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let t = y as f32 / h as f32;
            let n: f32 = rng.random_range(0.9..1.1);
            let c = if t < 0.5 {
                [0.3 + 0.9 * t, 0.5 + 0.8 * t, 1.2 - 0.4 * t]
            } else {
                [0.25, 0.18, 0.12]
            };
            let sun = x.abs_diff(40) <= 1 && y.abs_diff(18) <= 1;
            image::Rgb(if sun {
                [900.0, 850.0, 700.0]
            } else {
                c.map(|v| v * n)
            })
        })
        .collect();
    let p = dir.join("synthetic.hdr");
    let f = std::io::BufWriter::new(std::fs::File::create(&p).unwrap());
    image::codecs::hdr::HdrEncoder::new(f)
        .encode(&px, w, h)
        .unwrap();
    p
}

fn lit_env(map: &Path, ibl: IblSettings) -> Environment {
    Environment::new(EnvConfig {
        hdri: vec![map.display().to_string()],
        ibl,
        ..EnvConfig::default()
    })
    .unwrap()
}

fn lit(view: Viewpoint, rotation_deg: f32, exposure_stops: f32) -> Condition {
    Condition {
        hdri: Some(HdriDraw {
            index: 0,
            rotation_deg,
            exposure_stops,
        }),
        ..Condition::plain(view, Brightness::Bright)
    }
}

fn jeep(w: usize, samples: usize, atlas: usize) -> Renderer {
    let mut sc = generate::jeep();
    sc.normalise(0.0, None);
    Renderer::new(
        sc,
        RenderSettings {
            width: w,
            height: w,
            samples,
            vfov_deg: 45.0,
            atlas_res: atlas,
        },
    )
    .unwrap()
}

#[test]
fn a_lit_view_is_exact_in_bands_and_composites_in_colour_with_exact_gradients() {
    let dir = tempfile::tempdir().unwrap();
    let env = lit_env(&write_map(dir.path()), IblSettings::default());
    let r = jeep(66, 2, 32);
    let c = lit(Viewpoint::new(35.0, 6.0, 1.2), 70.0, 0.5);
    let banded = environment::plan(&r, &env, &c).unwrap();
    assert!(!banded.tap_colour.is_empty() && banded.tap_colour.len() == banded.tap_weight.len());
    // Coloured: the sky is blue, so the light on the paint is not grey.
    assert!(banded.tap_colour.iter().any(|k| (k[2] - k[0]).abs() > 0.02));
    let cam = r.camera(&c.viewpoint).unwrap();
    let g = render::gbuffer::GBuffer::cast(&r.scene, &r.accel, &cam, 2, true);
    let whole = render::shade::plan(
        &r.scene,
        &r.accel,
        &g,
        &env.lighting(&c),
        &env.backdrop(&c),
        32,
    );
    let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(
        bits(&banded.base) == bits(&whole.base),
        "base differs in bands"
    );
    assert!(
        bits(&banded.tap_colour) == bits(&whole.tap_colour),
        "tap colours differ in bands"
    );
    assert_eq!(banded.tap_weight, whole.tap_weight);
    assert_eq!(banded.tap_texel, whole.tap_texel);

    // A batch of a lit view and a grey-lit one: the tensor composite equals the CPU's, and the
    // gradient of a seeded projection equals central differences in f64.
    let grey_env = Environment::new(EnvConfig::default()).unwrap();
    let grey = environment::plan(
        &r,
        &grey_env,
        &Condition::plain(Viewpoint::new(200.0, 10.0, 1.3), Brightness::Bright),
    )
    .unwrap();
    assert!(grey.tap_colour.is_empty());
    let plans = vec![banded.clone(), grey];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let atlas: Vec<f64> = (0..32 * 32 * 3)
        .map(|_| rng.random_range(0.1..0.9))
        .collect();
    let form = |t: Tensor<4>| render::composite(&plans, t);
    let pixels: Vec<f64> = form(Tensor::<4>::from_data(
        TensorData::new(atlas.clone(), [1, 32, 32, 3]),
        (&device(), DType::F64),
    ))
    .into_data()
    .convert::<f64>()
    .try_to_vec::<f64>()
    .unwrap();
    let tex = cac::scene::Texture {
        width: 32,
        height: 32,
        texels: atlas
            .chunks_exact(3)
            .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
            .collect(),
    };
    let mut worst = 0.0f64;
    for (v, p) in plans.iter().enumerate() {
        for (i, px) in p.render_cpu(&tex).iter().enumerate() {
            for ch in 0..3 {
                worst = worst.max((pixels[(v * 3 + ch) * 66 * 66 + i] - px[ch] as f64).abs());
            }
        }
    }
    assert!(worst < 1e-5, "tensor and CPU composites differ by {worst}");
    let worst = support::gradient::worst_atlas_gradient_error(
        &form,
        &atlas,
        32,
        [2, 3, 66, 66],
        30,
        &mut rng,
    );
    assert!(worst < 1e-3, "worst relative gradient error {worst:e}");
}

#[test]
fn occlusion_never_adds_light_and_darkens_the_underside() {
    let dir = tempfile::tempdir().unwrap();
    let map = write_map(dir.path());
    let r = jeep(48, 1, 32);
    let c = lit(Viewpoint::new(120.0, 4.0, 1.3), 0.0, 0.0);
    let open = environment::plan(
        &r,
        &lit_env(
            &map,
            IblSettings {
                sh_order: 2,
                occlusion_rays: 0,
                prefilter_levels: 1,
            },
        ),
        &c,
    )
    .unwrap();
    let occl = environment::plan(
        &r,
        &lit_env(
            &map,
            IblSettings {
                sh_order: 2,
                occlusion_rays: 16,
                prefilter_levels: 1,
            },
        ),
        &c,
    )
    .unwrap();
    assert_eq!(open.tap_texel, occl.tap_texel, "the same paint is seen");
    let (mut darker, mut brighter) = (0usize, 0usize);
    for (a, b) in open.tap_colour.iter().zip(&occl.tap_colour) {
        for ch in 0..3 {
            if b[ch] > a[ch] + 1e-6 {
                brighter += 1;
            }
            if b[ch] < a[ch] - 1e-3 {
                darker += 1;
            }
        }
    }
    assert_eq!(brighter, 0, "occlusion added light");
    assert!(
        darker > open.tap_colour.len() / 20,
        "only {darker} taps darkened"
    );
    // The ground right under the body is in its shade: the lowest object rows' neighbours.
    let sum = |p: &render::RenderPlan| p.base.iter().flatten().map(|&v| v as f64).sum::<f64>();
    assert!(
        sum(&occl) < sum(&open),
        "the body's occlusion should darken the ground too"
    );
}

#[test]
fn extreme_exposures_and_grazing_views_stay_finite() {
    let dir = tempfile::tempdir().unwrap();
    let env = lit_env(&write_map(dir.path()), IblSettings::default());
    let r = jeep(32, 2, 16);
    for (view, stops) in [
        (Viewpoint::new(10.0, 0.0, 1.05), 0.0),
        (Viewpoint::new(90.0, 89.0, 3.0), 0.0),
        (Viewpoint::new(45.0, 10.0, 1.5), 20.0),
        (Viewpoint::new(45.0, 10.0, 1.5), -20.0),
    ] {
        let p = environment::plan(&r, &env, &lit(view, 300.0, stops)).unwrap();
        assert!(
            p.base.iter().flatten().all(|v| v.is_finite() && *v >= 0.0),
            "{view:?} {stops}"
        );
        assert!(p
            .tap_colour
            .iter()
            .flatten()
            .all(|v| v.is_finite() && *v >= 0.0));
        if stops == 20.0 {
            assert!(
                p.tap_colour.iter().any(|k| k[0] > 1.0),
                "20 stops over should saturate"
            );
        }
    }
}

#[test]
fn listing_environments_leaves_the_protocols_draws_alone() {
    let dir = tempfile::tempdir().unwrap();
    let map = write_map(dir.path());
    let plain = Environment::new(EnvConfig::default()).unwrap();
    let half = Environment::new(EnvConfig {
        hdri: vec![map.display().to_string()],
        hdri_share: 0.5,
        hdri_exposure_stops: [-1.0, 1.0],
        ..EnvConfig::default()
    })
    .unwrap();
    let (a, b) = (
        plain.sample_n(40, ViewpointSet::Free, Brightness::Bright, 3),
        half.sample_n(40, ViewpointSet::Free, Brightness::Bright, 3),
    );
    let lit = b.iter().filter(|c| c.hdri.is_some()).count();
    assert!((8..=32).contains(&lit), "{lit} of 40 lit at share 0.5");
    for (x, y) in a.iter().zip(&b) {
        assert!(x.hdri.is_none());
        assert_eq!(
            x,
            &Condition {
                hdri: None,
                ..y.clone()
            },
            "every other draw unchanged"
        );
        if let Some(h) = y.hdri {
            assert!(
                (-1.0..=1.0).contains(&h.exposure_stops) && (0.0..=360.0).contains(&h.rotation_deg)
            );
        }
    }
}

#[test]
fn bad_environments_are_clear_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let with = |h: &str| {
        Environment::new(EnvConfig {
            hdri: vec![h.into()],
            ..EnvConfig::default()
        })
        .err()
        .map(|e| format!("{e:#}"))
        .expect("refused")
    };
    let e = with("moonbase");
    assert!(e.contains("moonbase") && e.contains("sunset"), "{e}");
    let square = dir.path().join("square.hdr");
    let f = std::io::BufWriter::new(std::fs::File::create(&square).unwrap());
    image::codecs::hdr::HdrEncoder::new(f)
        .encode(&vec![image::Rgb([0.5f32; 3]); 16 * 16], 16, 16)
        .unwrap();
    let e = with(&square.display().to_string());
    assert!(
        e.contains("square.hdr") && e.contains("equirectangular"),
        "{e}"
    );
    let junk = dir.path().join("junk.exr");
    std::fs::write(&junk, b"not an exr").unwrap();
    let e = with(&junk.display().to_string());
    assert!(e.contains("junk.exr"), "{e}");
    let e = format!(
        "{:#}",
        Environment::new(EnvConfig {
            ibl: IblSettings {
                sh_order: 3,
                occlusion_rays: 4,
                prefilter_levels: 1,
            },
            ..EnvConfig::default()
        })
        .err()
        .unwrap()
    );
    assert!(e.contains("sh_order"), "{e}");
}

/// `cac demo --hdri`: training and the protocol views are lit by the environment, and the demo
/// says so in its table's heading and in summary.json (a short run: 2 iterations, 4 views).
#[test]
fn the_demo_trains_and_scores_under_an_environment_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let map = write_map(dir.path());
    let out = dir.path().join("demo");
    let text = support::cac_ok(&[
        "demo",
        "--iterations",
        "2",
        "--views",
        "1",
        "--hdri",
        map.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        text.contains("lit by one of the photographed environments")
            && text.contains(map.to_str().unwrap()),
        "{text}"
    );
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    let env = &summary["scene"]["environment"];
    assert_eq!(
        env["hdri"][0].as_str(),
        Some(map.to_str().unwrap()),
        "{env}"
    );
    assert_eq!(env["hdri_share"].as_f64(), Some(1.0), "{env}");
    let run: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("run/run.json")).unwrap()).unwrap();
    assert_eq!(
        run["scene"]["environment"]["hdri"], env["hdri"],
        "trained under it too"
    );
    // The same folder without the environments is not resumed as if it had been trained so,
    // and what it holds stays as it was.
    let before = std::fs::read(out.join("summary.json")).unwrap();
    let o = support::cac(&[
        "demo",
        "--iterations",
        "2",
        "--views",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("other settings") && err.contains("hdri"),
        "{err}"
    );
    assert_eq!(std::fs::read(out.join("summary.json")).unwrap(), before);
    // A missing environment is refused before anything is trained or written.
    let bad = dir.path().join("bad");
    let o = support::cac(&["demo", "--hdri", "nowhere", "--out", bad.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("nowhere"), "{err}");
    assert!(!bad.join("run").exists(), "nothing trained");
}
