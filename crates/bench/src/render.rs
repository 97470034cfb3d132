//! The render benchmark's measurements (`cac bench render`): BVH build time and primary-ray
//! throughput for a G-buffer of the default vehicle and (when `../shared` is present) the Cesium
//! milk truck, with 1 and 2 threads, beside Embree (Python `embreex`) casting the same rays when
//! it is installed ([`rays`]). Timed with the one timer (`report::timer`); the table is a
//! [`Table`] for the CSV file. (The anti-aliasing half of the benchmark forms images under an
//! environment condition: [`crate::anti_aliasing`].)

use anyhow::Result;
use cac_core::report::timer::fastest_ms;
use cac_core::report::Table;
use cac_render::camera::Viewpoint;
use cac_render::RenderSettings;
use cac_render::{accel::Accel, gbuffer::GBuffer};
use cac_scene::{LoadOptions, Scene};
use std::path::Path;

/// One thread count's figures of a [`RayScene`].
#[derive(Clone, Debug)]
pub struct ThreadRun {
    pub threads: usize,
    pub rays: usize,
    /// Seconds of the fastest closest-hit pass, and of the fastest whole G-buffer.
    pub secs: f64,
    pub gbuffer_secs: f64,
}

impl ThreadRun {
    pub(crate) fn mrays_per_s(&self) -> f64 {
        self.rays as f64 / self.secs / 1e6
    }
}

/// Embree's figures on the same rays: build ms, rays/s, hits.
pub(crate) type EmbreeRun = (f64, f64, usize);

/// One scene's ray-throughput figures.
#[derive(Clone, Debug)]
pub struct RayScene {
    pub name: String,
    pub triangles: usize,
    pub build_secs: f64,
    /// Rays that hit the object.
    pub hits: usize,
    pub embree: Option<EmbreeRun>,
    pub runs: Vec<ThreadRun>,
}

/// BVH build and ray throughput per scene on a `size`² image, 1 and 2 threads, fastest of
/// `repeats`, beside Embree run by `python` when it is installed.
pub fn rays(size: usize, repeats: usize, python: &str) -> Result<Vec<RayScene>> {
    let settings = RenderSettings {
        width: size,
        height: size,
        samples: 1,
        ..Default::default()
    };
    let mut out = vec![];
    for (name, scene) in scenes() {
        let (build_secs, accel) = best_of(repeats, || Accel::build(&scene));
        let (lo, hi) = scene.bounds();
        let cam = Viewpoint::new(35.0, 15.0, 1.5).camera(
            settings.intrinsics(),
            lo,
            hi,
            scene.length(),
        )?;
        let g0 = GBuffer::cast(&scene, &accel, &cam, 1, false);
        let hits = g0
            .data
            .iter()
            .filter(|s| s.surface == cac_render::gbuffer::Surface::Object)
            .count();
        let embree = embree(python, &scene, &g0, repeats);
        let mut runs = vec![];
        for threads in [1usize, 2] {
            let (secs, gbuffer_secs) = cast_times(repeats, threads, &scene, &accel, &cam, &g0)?;
            runs.push(ThreadRun {
                threads,
                rays: g0.data.len(),
                secs,
                gbuffer_secs,
            });
        }
        out.push(RayScene {
            name,
            triangles: scene.triangles.len(),
            build_secs,
            hits,
            embree,
            runs,
        });
    }
    Ok(out)
}

/// The rows of `render_rays.csv`.
pub fn rays_table(scenes: &[RayScene]) -> Table {
    let mut t = Table::new([
        "scene",
        "triangles",
        "bvh_build_ms",
        "threads",
        "rays",
        "seconds",
        "mrays_per_s",
        "gbuffer_ms",
        "hits",
        "embree_build_ms",
        "embree_mrays_per_s",
        "embree_hits",
        "cac_over_embree",
    ]);
    for s in scenes {
        let (eb, er, eh) = s
            .embree
            .map(|(b, r, h)| (format!("{b:.2}"), format!("{:.2}", r / 1e6), h.to_string()))
            .unwrap_or_default();
        for r in &s.runs {
            t.row([
                s.name.clone(),
                s.triangles.to_string(),
                format!("{:.3}", s.build_secs * 1e3),
                r.threads.to_string(),
                r.rays.to_string(),
                format!("{:.5}", r.secs),
                format!("{:.3}", r.mrays_per_s()),
                format!("{:.2}", r.gbuffer_secs * 1e3),
                s.hits.to_string(),
                eb.clone(),
                er.clone(),
                eh.clone(),
                s.embree.map_or(String::new(), |(_, er, _)| {
                    format!("{:.2}", r.mrays_per_s() * 1e6 / er)
                }),
            ]);
        }
    }
    t
}

fn scenes() -> Vec<(String, Scene)> {
    let mut v = vec![];
    let mut jeep = cac_scene::generate::jeep();
    jeep.normalise(0.0, None);
    v.push(("jeep".to_string(), jeep));
    let truck = Path::new("../shared/meshes/CesiumMilkTruck/CesiumMilkTruck.glb");
    if truck.is_file() {
        if let Ok(s) = Scene::load(truck, &LoadOptions::default()) {
            v.push(("milk-truck".to_string(), s));
        }
    }
    v
}

/// Seconds of the fastest of `n` (at least one) runs of `f`, no warm-up, and its last output.
pub(crate) fn best_of<T>(n: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let (ms, out) = fastest_ms(0, n.max(1), || Ok(f())).expect("infallible");
    (ms / 1e3, out)
}

fn embree(python: &str, scene: &Scene, g: &GBuffer, repeats: usize) -> Option<(f64, f64, usize)> {
    let dir = tempfile::tempdir().ok()?;
    // Mesh as .npz is awkward without numpy here: write .npy files and a tiny npz via python.
    let mut verts = Vec::with_capacity(scene.positions.len() * 12);
    for p in &scene.positions {
        for c in [p.x, p.y, p.z] {
            verts.extend(c.to_le_bytes());
        }
    }
    let mut faces = Vec::with_capacity(scene.triangles.len() * 12);
    for t in &scene.triangles {
        for i in t.p {
            faces.extend((i as i32).to_le_bytes());
        }
    }
    let mut rays = Vec::with_capacity(g.data.len() * 24);
    for s in &g.data {
        for c in [
            g.camera.eye.x,
            g.camera.eye.y,
            g.camera.eye.z,
            s.dir.x,
            s.dir.y,
            s.dir.z,
        ] {
            rays.extend(c.to_le_bytes());
        }
    }
    std::fs::write(dir.path().join("v.bin"), verts).ok()?;
    std::fs::write(dir.path().join("f.bin"), faces).ok()?;
    std::fs::write(dir.path().join("rays.bin"), rays).ok()?;
    let d = dir.path().display().to_string();
    let pack = format!("import numpy as np; np.savez('{d}/m.npz', vertices=np.fromfile('{d}/v.bin', dtype=np.float32).reshape(-1,3), faces=np.fromfile('{d}/f.bin', dtype=np.int32).reshape(-1,3))");
    let ok = std::process::Command::new(python)
        .args(["-c", &pack])
        .status()
        .ok()?
        .success();
    if !ok {
        return None;
    }
    let script =
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tools/embree_bench.py");
    let out = std::process::Command::new(python)
        .arg(script)
        .arg(format!("{d}/m.npz"))
        .arg(format!("{d}/rays.bin"))
        .arg(repeats.to_string())
        .output()
        .ok()?;
    if !out.status.success() {
        eprintln!(
            "embree comparison failed: {}",
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
    Some((
        v["build_ms"].as_f64()?,
        v["rays_per_s"].as_f64()?,
        v["hits"].as_u64()? as usize,
    ))
}

/// Seconds of the fastest closest-hit pass over `g0`'s rays (the same work as Embree's: the
/// closest hit of each ray) and of the fastest whole G-buffer, on `threads` threads.
fn cast_times(
    repeats: usize,
    threads: usize,
    scene: &Scene,
    accel: &Accel,
    cam: &cac_render::camera::Camera,
    g0: &GBuffer,
) -> Result<(f64, f64)> {
    let dirs: Vec<glam::Vec3> = g0.data.iter().map(|s| s.dir).collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let (secs, _) = best_of(repeats, || {
        pool.install(|| {
            use rayon::prelude::*;
            dirs.par_chunks(4096)
                .map(|c| {
                    c.iter()
                        .filter(|d| accel.closest(cam.eye, **d, 0.0, f32::INFINITY).is_some())
                        .count()
                })
                .sum::<usize>()
        })
    });
    let (gsecs, _) = best_of(repeats, || {
        pool.install(|| GBuffer::cast(scene, accel, cam, 1, false))
    });
    Ok((secs, gsecs))
}
