//! Renderer and environment: gradients, extremes, determinism, conformance of the tensor path
//! with the CPU path, and bad input. The Cesium milk truck of `../shared` is required under CI.

mod support;

use burn::tensor::Tensor;
use cac::environment::{self, Brightness, Condition, EnvConfig, Environment, ViewpointSet};
use cac::render::{self, Backdrop, Background, Lighting, RenderSettings, Renderer, Viewpoint};
use cac::scene::{generate, LoadOptions, Scene, Texture};
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use support::device;

fn small(w: usize, s: usize, atlas: usize) -> RenderSettings {
    RenderSettings {
        width: w,
        height: w,
        samples: s,
        vfov_deg: 45.0,
        atlas_res: atlas,
    }
}

fn jeep_renderer(w: usize, s: usize, atlas: usize) -> Renderer {
    let mut sc = generate::jeep();
    sc.normalise(0.0, None);
    Renderer::new(sc, small(w, s, atlas)).unwrap()
}

fn data_f64(t: &Tensor<4>) -> Vec<f64> {
    t.clone()
        .into_data()
        .convert::<f64>()
        .try_to_vec::<f64>()
        .unwrap()
}

/// The Cesium milk truck (glTF) of `../shared`: a failure under CI when missing, else a skip.
fn milk_truck() -> Option<PathBuf> {
    support::require_path(
        &support::root().join("../shared/meshes/CesiumMilkTruck/CesiumMilkTruck.glb"),
        "the Cesium milk truck of ../shared",
    )
}

/// d(loss)/d(atlas) from autodiff against central finite differences, in float64, through the
/// print error, the composite and the photometric transforms.
#[test]
fn texture_gradient_matches_finite_differences_in_f64() {
    let r = jeep_renderer(48, 4, 32);
    let env = Environment::new(EnvConfig {
        noise_std: [0.0, 0.0],
        ..Default::default()
    })
    .unwrap();
    let mut conds = env.sample_n(2, ViewpointSet::Free, Brightness::Bright, 3);
    for c in &mut conds {
        c.viewpoint.distance_ratio = 1.4;
        c.light_mul = 0.9;
        c.light_add = 0.02;
        c.channel_mul = [0.8, 0.9, 1.0];
        c.channel_add = [0.05, 0.0, -0.03];
    }
    let plans: Vec<_> = conds
        .iter()
        .map(|c| cac::environment::plan(&r, &env, c).unwrap())
        .collect();
    assert!(
        plans.iter().all(|p| !p.tap_pixel.is_empty()),
        "object not visible"
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let atlas: Vec<f64> = (0..32 * 32 * 3)
        .map(|_| rng.random_range(0.2..0.7))
        .collect();
    let form = |t: Tensor<4>| environment::form_planned(&plans, t, &conds);
    let worst = support::gradient::worst_atlas_gradient_error(
        &form,
        &atlas,
        32,
        [2, 3, 48, 48],
        40,
        &mut rng,
    );
    assert!(worst < 1e-3, "worst relative gradient error {worst:e}");
}

#[test]
fn tensor_composite_equals_cpu_composite() {
    let r = jeep_renderer(64, 4, 64);
    let env = Environment::new(EnvConfig::default()).unwrap();
    let c = Condition::plain(Viewpoint::new(40.0, 15.0, 1.5), Brightness::Bright);
    let plan = cac::environment::plan(&r, &env, &c).unwrap();
    let atlas = r.scene.initial_atlas(64);
    let cpu = plan.render_cpu(&atlas);
    let t = render::composite(
        std::slice::from_ref(&plan),
        render::atlas_tensor(&atlas, &device()),
    );
    let v = data_f64(&t);
    let mut worst = 0.0f64;
    for (p, px) in cpu.iter().enumerate() {
        for c in 0..3 {
            worst = worst.max((v[c * 64 * 64 + p] - px[c] as f64).abs());
        }
    }
    assert!(worst < 1e-5, "tensor and CPU composites differ by {worst}");
}

#[test]
fn same_seed_gives_bit_identical_images() {
    let r = jeep_renderer(48, 4, 32);
    let env = Environment::new(EnvConfig::default()).unwrap();
    let run = || {
        let conds = env.sample_n(3, ViewpointSet::Free, Brightness::Dark, 42);
        let a = render::atlas_tensor(&r.scene.initial_atlas(32), &device());
        data_f64(&environment::form(&r, &env, &conds, a).unwrap().0)
    };
    let (a, b) = (run(), run());
    assert!(
        a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
        "images differ between runs"
    );
    let conds_other = env.sample_n(3, ViewpointSet::Free, Brightness::Dark, 43);
    assert_ne!(
        conds_other,
        env.sample_n(3, ViewpointSet::Free, Brightness::Dark, 42)
    );
}

/// Distance bounds, grazing and vertical views, saturated lighting and strong noise: finite
/// values within [0, 1] and a visible object where it should be.
#[test]
fn extreme_conditions_stay_finite_and_in_range() {
    let r = jeep_renderer(48, 4, 32);
    let env = Environment::new(EnvConfig::default()).unwrap();
    let dev = device();
    let atlas = render::atlas_tensor(&r.scene.initial_atlas(32), &dev);
    let mut cases = vec![];
    for az in [0.0f32, 45.0, 90.0, 180.0, 270.0] {
        for el in [0.0f32, 0.01, 89.99, 90.0] {
            for d in [1.0f32, 6.0] {
                cases.push((az, el, d));
            }
        }
    }
    for (az, el, d) in cases {
        let mut c = Condition::plain(Viewpoint::new(az, el, d), Brightness::Bright);
        c.light_mul = 2.0;
        c.light_add = 0.15;
        c.channel_mul = [1.3, 0.7, 1.3];
        c.channel_add = [0.15, -0.15, 0.15];
        c.noise_std = 0.1;
        c.noise_seed = 9;
        let plan = cac::environment::plan(&r, &env, &c).unwrap();
        assert!(
            plan.object_box.is_some(),
            "object not visible at az {az} el {el} d {d}"
        );
        assert!(plan.tap_weight.iter().all(|w| w.is_finite() && *w >= 0.0));
        let img = environment::form_planned(&[plan], atlas.clone(), &[c]);
        let v = data_f64(&img);
        assert!(
            v.iter().all(|x| x.is_finite() && (0.0..=1.0).contains(x)),
            "out of range at az {az} el {el} d {d}"
        );
    }
}

/// The ground-truth box (from the object mask) equals the box of the mesh's projected vertices
/// (the silhouette's extreme points are always visible), at near and far distance ratios.
#[test]
fn object_box_matches_projected_silhouette() {
    let r = jeep_renderer(160, 4, 32);
    let bd = Backdrop {
        background: Background::Color([0.0; 3]),
        ground: None,
    };
    let light = Lighting::sun_at(0.5, 0.5, 0.0, 45.0);
    for (az, el, d) in [
        (90.0f32, 0.0f32, 2.0f32),
        (90.0, 0.0, 4.0),
        (30.0, 25.0, 1.5),
        (200.0, 60.0, 6.0),
    ] {
        let vp = Viewpoint::new(az, el, d);
        let cam = r.camera(&vp).unwrap();
        let b = r.plan(&vp, &light, &bd).unwrap().object_box.unwrap();
        let mut e = [f32::MAX, f32::MAX, f32::MIN, f32::MIN];
        for t in &r.scene.triangles {
            for &i in &t.p {
                let q = cam.project(r.scene.positions[i as usize]).unwrap();
                e = [e[0].min(q.x), e[1].min(q.y), e[2].max(q.x), e[3].max(q.y)];
            }
        }
        for k in 0..4 {
            assert!(
                (b[k] - e[k]).abs() <= 1.0,
                "view {az}/{el}/{d}: mask box {b:?} vs projected {e:?}"
            );
        }
    }
}

/// A view cast and shaded a band of rows at a time (what `Renderer::plan` does, to keep the
/// G-buffer small) is the view shaded at once from one G-buffer, bit for bit: pixels, taps,
/// coverage and object box, under a sky with its skyline over the ground and under an image
/// background alone (whose colour depends on the image row), at 1 and 4 samples per pixel.
#[test]
fn a_view_planned_in_bands_equals_the_view_planned_at_once() {
    let ground = render::Ground {
        texture: std::sync::Arc::new(environment::procedural_ground(64)),
        tile_m: 3.0,
        offset: Vec2::new(0.4, 1.1),
    };
    let sky = Background::Sky {
        horizon: [0.8, 0.85, 0.9],
        zenith: [0.3, 0.5, 0.8],
        skyline: Some(render::skyline::Skyline {
            phase_deg: 20.0,
            light: 1.0,
        }),
    };
    let mut stripes = Texture::solid(8, 8, [0.0; 3]);
    for (k, t) in stripes.texels.iter_mut().enumerate() {
        *t = [(k / 8) as f32 / 8.0, 0.5, 1.0 - (k % 8) as f32 / 8.0];
    }
    let image = Background::Image(std::sync::Arc::new(stripes));
    let light = Lighting::sun_at(0.4, 0.7, 30.0, 40.0);
    // 66 rows: four bands of 16 rows and one of 2.
    const { assert!(66 % render::BAND_ROWS != 0) };
    for samples in [1, 4] {
        let r = jeep_renderer(66, samples, 32);
        // The image background without a ground, so that it fills every row around the object.
        for (background, ground, view) in [
            (
                sky.clone(),
                Some(ground.clone()),
                Viewpoint::new(35.0, 5.0, 1.2),
            ),
            (image.clone(), None, Viewpoint::new(200.0, 30.0, 1.2)),
        ] {
            let has_ground = ground.is_some();
            let bd = Backdrop { background, ground };
            let banded = r.plan(&view, &light, &bd).unwrap();
            let cam = r.camera(&view).unwrap();
            let g = render::gbuffer::GBuffer::cast(&r.scene, &r.accel, &cam, samples, has_ground);
            let whole = render::shade::plan(&r.scene, &r.accel, &g, &light, &bd, 32);
            assert_eq!((banded.width, banded.height), (whole.width, whole.height));
            let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
            let (a, b) = (bits(&banded.base), bits(&whole.base));
            let first = a.iter().zip(&b).position(|(x, y)| x != y);
            assert!(
                a == b,
                "{samples} spp: base differs, first at value {first:?}"
            );
            assert_eq!(banded.tap_pixel, whole.tap_pixel);
            assert_eq!(banded.tap_texel, whole.tap_texel);
            assert_eq!(banded.tap_weight, whole.tap_weight);
            assert_eq!(banded.coverage, whole.coverage);
            assert_eq!(banded.object_box, whole.object_box);
            assert!(banded.object_box.is_some() && !banded.tap_pixel.is_empty());
            // The object crosses band boundaries, so the stacking's pixel offsets are exercised.
            let [_, y1, _, y2] = banded.object_box.unwrap();
            assert!(
                (y2 - y1) as usize > render::BAND_ROWS,
                "the object spans rows {y1}..{y2}, within one band"
            );
        }
    }
}

#[test]
fn zero_area_triangles_and_out_of_range_uvs_render_cleanly() {
    let mut s = generate::barrel();
    // Degenerate triangles (repeated vertex, collinear) and UVs far outside [0, 1].
    let n = s.positions.len() as u32;
    s.positions.push(Vec3::new(0.0, 0.5, 0.3));
    s.positions.push(Vec3::new(0.1, 0.5, 0.3));
    s.positions.push(Vec3::new(0.2, 0.5, 0.3));
    let m = s.triangles[0].material;
    s.triangles.push(cac::scene::Triangle {
        p: [n, n, n + 1],
        uv: None,
        n: None,
        material: m,
    });
    s.triangles.push(cac::scene::Triangle {
        p: [n, n + 1, n + 2],
        uv: None,
        n: None,
        material: m,
    });
    for uv in &mut s.uvs {
        *uv = *uv * 7.3 - Vec2::splat(3.1);
    }
    s.normalise(0.0, None);
    let r = Renderer::new(s, small(48, 4, 16)).unwrap();
    let light = Lighting::sun_at(0.4, 0.7, 30.0, 40.0);
    let bd = Backdrop {
        background: Background::Color([0.5; 3]),
        ground: None,
    };
    for az in [0.0f32, 90.0, 200.0] {
        let plan = r.plan(&Viewpoint::new(az, 20.0, 2.0), &light, &bd).unwrap();
        assert!(plan.tap_texel.iter().all(|&t| (t as usize) < 16 * 16));
        let img = plan.render_cpu(&Texture::solid(16, 16, [0.3, 0.6, 0.9]));
        assert!(img.iter().flatten().all(|v| v.is_finite()));
    }
}

#[test]
fn unlit_scene_casts_no_shadows_and_ground_can_be_disabled() {
    let r = jeep_renderer(48, 1, 16);
    let light = Lighting::sun_at(0.5, 0.0, 0.0, 45.0);
    let bd = Backdrop {
        background: Background::Color([0.2, 0.3, 0.4]),
        ground: None,
    };
    let plan = r
        .plan(&Viewpoint::new(30.0, 30.0, 2.0), &light, &bd)
        .unwrap();
    // Without ground, every non-object pixel is exactly the background colour.
    for (p, c) in plan.base.iter().zip(&plan.coverage) {
        if *c == 0.0 {
            assert_eq!(*p, [0.2, 0.3, 0.4]);
        }
    }
    // Without a sun, paintable shading is the ambient term alone: every tap weight per pixel
    // sums to ambient × coverage.
    let mut sums = vec![0.0f32; 48 * 48];
    for (k, &p) in plan.tap_pixel.iter().enumerate() {
        sums[p as usize] += plan.tap_weight[k];
    }
    assert!(sums.iter().all(|&s| s <= 0.5 + 1e-4));
}

#[test]
fn camera_inside_the_object_is_a_clear_error() {
    let r = jeep_renderer(32, 1, 16);
    let e = r.plan(
        &Viewpoint::new(0.0, 0.0, 0.2),
        &Lighting::sun_at(0.5, 0.5, 0.0, 45.0),
        &Backdrop {
            background: Background::Color([0.0; 3]),
            ground: None,
        },
    );
    assert!(e.unwrap_err().to_string().contains("inside the object"));
}

#[test]
fn restricted_viewpoints_stay_within_the_side_sectors() {
    let env = Environment::new(EnvConfig::default()).unwrap();
    for c in env.sample_n(500, ViewpointSet::Restricted, Brightness::Bright, 1) {
        let a = c.viewpoint.azimuth_deg.rem_euclid(360.0);
        let off = (a - 90.0).abs().min((a - 270.0).abs());
        assert!(off <= 60.0 + 1e-3, "azimuth {a}");
        assert!((1.0..=6.0).contains(&c.viewpoint.distance_ratio));
    }
}

// ---- loading and bad input ----

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn err(p: &Path) -> String {
    format!("{:#}", Scene::load(p, &LoadOptions::default()).unwrap_err())
}

#[test]
fn malformed_meshes_are_clear_errors_naming_the_file() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    // Bad vertex index.
    let p = write(dp, "badindex.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
    assert!(err(&p).contains("badindex.obj"), "{}", err(&p));
    // Missing texture named by the MTL.
    write(dp, "m.mtl", b"newmtl body\nmap_Kd nothere.png\n");
    let p = write(dp, "missingtex.obj", b"mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl body\nf 1/1 2/2 3/3\n");
    let e = err(&p);
    assert!(
        e.contains("nothere.png") && e.contains("missingtex.obj"),
        "{e}"
    );
    // Truncated / garbage GLB.
    let p = write(dp, "trunc.glb", b"glTF\x02\x00\x00\x00\xff\xff");
    assert!(err(&p).contains("trunc.glb"));
    // A texture that is not an image.
    write(dp, "bad.png", b"\x89PNG\r\n\x1a\nnope");
    write(dp, "n.mtl", b"newmtl body\nmap_Kd bad.png\n");
    let p = write(dp, "badpng.obj", b"mtllib n.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl body\nf 1/1 2/2 3/3\n");
    assert!(err(&p).contains("bad.png"));
    // Missing file, unknown extension, empty mesh.
    assert!(err(&dp.join("none.obj")).contains("does not exist"));
    let p = write(dp, "x.stl", b"solid");
    assert!(err(&p).contains("unsupported"));
    let p = write(dp, "empty.obj", b"# nothing\n");
    assert!(err(&p).contains("empty.obj"));
    // Truncated glTF taken from a real file.
    if let Some(truck) = milk_truck() {
        let bytes = std::fs::read(truck).unwrap();
        let p = write(dp, "half.glb", &bytes[..bytes.len() / 2]);
        assert!(err(&p).contains("half.glb"));
    }
}

#[test]
fn generated_obj_round_trips_through_the_loader() {
    let d = tempfile::tempdir().unwrap();
    let mut s = generate::jeep();
    s.normalise(0.0, None);
    cac::scene::obj_write::write_obj(&s, d.path(), "jeep").unwrap();
    let back = Scene::load(&d.path().join("jeep.obj"), &LoadOptions::default()).unwrap();
    assert_eq!(back.triangles.len(), s.triangles.len());
    assert!((back.length() - s.length()).abs() < 1e-3);
    let names: Vec<_> = back
        .materials
        .iter()
        .zip(&back.paintable)
        .filter(|(_, p)| **p)
        .map(|(m, _)| m.name.clone())
        .collect();
    assert_eq!(names, vec!["body_paint".to_string()]);
    assert_eq!(back.paint_texture().unwrap().width, 512);
}

#[test]
fn the_milk_truck_loads_normalised_with_only_its_body_paintable() {
    let Some(truck) = milk_truck() else { return };
    let s = Scene::load(&truck, &LoadOptions::default()).unwrap();
    let (lo, hi) = s.bounds();
    assert!(lo.y.abs() < 1e-4, "ground contact at y=0, got {}", lo.y);
    assert!((hi.x - lo.x) > (hi.z - lo.z), "length must be along X");
    assert!((s.length() - 4.87).abs() < 0.1, "length {}", s.length());
    let paint: Vec<_> = s
        .materials
        .iter()
        .zip(&s.paintable)
        .filter(|(_, p)| **p)
        .map(|(m, _)| m.name.as_str())
        .collect();
    assert_eq!(paint, vec!["truck"]);
    // Two wheel nodes share one mesh: both instances are present.
    let wheels = s
        .triangles
        .iter()
        .filter(|t| s.materials[t.material as usize].name == "wheels")
        .count();
    assert_eq!(wheels, 2 * 2304 / 3);
}

/// Per pixel, the sum of the atlas taps' weights: the light the paint receives there.
fn paint_light(p: &render::RenderPlan) -> Vec<f64> {
    let mut l = vec![0f64; p.width * p.height];
    for (&px, &w) in p.tap_pixel.iter().zip(&p.tap_weight) {
        l[px as usize] += w as f64;
    }
    l
}

/// `environment.sky_occlusion`: with the sun off, the paint's light under an open sky over the
/// ground is the uniform ambient times `(1 + n_y)/2 + albedo (1 − n_y)/2`: unchanged on the
/// roof seen from above, about `(1 + albedo)/2` on the sides seen level, never outside
/// `[albedo, 1]`; and a condition without it is lit exactly as before. Drawing it is the last
/// draw of a condition, so the protocol's views keep every other field.
#[test]
fn sky_occlusion_lights_the_sides_from_sky_and_ground() {
    let mut sc = generate::pickup();
    sc.normalise(0.0, None);
    let r = Renderer::new(sc, small(96, 2, 64)).unwrap();
    let level = environment::LightLevel {
        ambient: 0.5,
        sun: 0.0,
    };
    let env = Environment::new(EnvConfig {
        bright: level,
        dark: level,
        ..Default::default()
    })
    .unwrap();
    let view = |az: f32, el: f32, occluded: bool| {
        let mut c = Condition::plain(Viewpoint::new(az, el, 1.6), Brightness::Bright);
        c.sky_occlusion = occluded;
        c
    };
    let albedo = env
        .lighting(&view(0.0, 0.0, true))
        .sky_occlusion
        .expect("a condition with sky occlusion over a ground carries the ground's albedo")
        as f64;
    assert!(albedo > 0.05 && albedo < 0.95, "ground albedo {albedo}");
    assert_eq!(env.lighting(&view(0.0, 0.0, false)).sky_occlusion, None);
    let ratios = |az: f32, el: f32| {
        let open = environment::plan(&r, &env, &view(az, el, false)).unwrap();
        let occl = environment::plan(&r, &env, &view(az, el, true)).unwrap();
        assert_eq!(open.tap_texel, occl.tap_texel, "the same paint is seen");
        let (lo, lc) = (paint_light(&open), paint_light(&occl));
        let mut q: Vec<f64> = lo
            .iter()
            .zip(&lc)
            .filter(|(o, _)| **o > 0.45) // pixels fully painted (ambient 0.5)
            .map(|(o, c)| c / o)
            .collect();
        assert!(q.len() > 100, "{} painted pixels", q.len());
        for &x in &q {
            assert!(x > albedo - 1e-4 && x < 1.0 + 1e-4, "ratio {x}");
        }
        q.sort_by(f64::total_cmp);
        q[q.len() / 2]
    };
    let top = ratios(30.0, 85.0);
    assert!(top > 0.97, "roof from above: median ratio {top}");
    let side = ratios(90.0, 0.0);
    let want = (1.0 + albedo) / 2.0;
    assert!(
        (side - want).abs() < 0.05,
        "side seen level: median ratio {side}, expected about {want}"
    );
    // The draw comes last: with probability 1 every other field is what probability 0 draws.
    let with = |p: f32| {
        Environment::new(EnvConfig {
            sky_occlusion: p,
            ..Default::default()
        })
        .unwrap()
        .sample_n(16, ViewpointSet::Free, Brightness::Bright, 5)
    };
    let (none, all) = (with(0.0), with(1.0));
    for (a, b) in none.iter().zip(&all) {
        assert!(!a.sky_occlusion && b.sky_occlusion);
        assert_eq!(
            &Condition {
                sky_occlusion: false,
                ..b.clone()
            },
            a
        );
    }
    let e = Environment::new(EnvConfig {
        sky_occlusion: 1.5,
        ..Default::default()
    })
    .err()
    .expect("a probability above 1 is refused");
    assert!(format!("{e:#}").contains("sky_occlusion"), "{e:#}");
}
