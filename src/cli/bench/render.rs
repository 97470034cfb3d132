//! `cac bench render`: BVH build time and primary-ray throughput for a 512x512 G-buffer of the
//! default vehicle and (when `../shared` is present) the Cesium milk truck, with 1 and 2 threads,
//! side by side with Embree (Python `embreex`) casting the same rays when it is installed; and
//! the anti-aliasing error-against-time table (PSNR of 1/4/16 samples against 64). Prints tables
//! and writes CSV.

use super::timer::fastest_ms;
use anyhow::{Context, Result};
use cac::environment::{Brightness, Condition, EnvConfig, Environment};
use cac::render::{accel::Accel, gbuffer::GBuffer, RenderSettings, Renderer, Viewpoint};
use cac::report::Table;
use cac::scene::{LoadOptions, Scene};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder for the CSV files.
    #[arg(long, default_value = "bench-out")]
    pub out: PathBuf,
    /// Image side for the ray-throughput runs.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Timed repetitions (the best is reported).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Python interpreter for the Embree comparison.
    #[arg(long, default_value = "python3")]
    pub python: String,
}

fn scenes() -> Vec<(String, Scene)> {
    let mut v = vec![];
    let mut jeep = cac::scene::generate::jeep();
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
fn best_of<T>(n: usize, mut f: impl FnMut() -> T) -> (f64, T) {
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
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/embree_bench.py");
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

pub fn run(a: Args) -> Result<()> {
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    rays(&a)?;
    anti_aliasing(&a)?;
    println!(
        "\nwrote {} and {}",
        a.out.join("render_rays.csv").display(),
        a.out.join("render_aa.csv").display()
    );
    Ok(())
}

/// BVH build and ray throughput per scene, 1 and 2 threads, beside Embree: render_rays.csv.
fn rays(a: &Args) -> Result<()> {
    let mut csv = rays_header();
    let settings = RenderSettings {
        width: a.size,
        height: a.size,
        samples: 1,
        ..Default::default()
    };
    for (name, scene) in scenes() {
        let (build_s, accel) = best_of(a.repeats, || Accel::build(&scene));
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
            .filter(|s| s.surface == cac::render::gbuffer::Surface::Object)
            .count();
        let emb = embree(&a.python, &scene, &g0, a.repeats);
        for threads in [1usize, 2] {
            let (secs, gsecs) = cast_times(a.repeats, threads, &scene, &accel, &cam, &g0)?;
            let rays = g0.data.len();
            let mrays = rays as f64 / secs / 1e6;
            let (eb, er, eh) = emb
                .map(|(b, r, h)| (format!("{b:.2}"), format!("{:.2}", r / 1e6), h.to_string()))
                .unwrap_or_default();
            let ratio = emb
                .map(|(_, r, _)| format!("{:.2}", mrays * 1e6 / r))
                .unwrap_or_else(|| "n/a".into());
            println!(
                "{:<11} {:>9} {:>9.2} {:>7} {:>10.2} {:>11} {:>13} {:>12.1}",
                name,
                scene.triangles.len(),
                build_s * 1e3,
                threads,
                mrays,
                if er.is_empty() { "n/a" } else { &er },
                ratio,
                gsecs * 1e3
            );
            csv.row([
                name.clone(),
                scene.triangles.len().to_string(),
                format!("{:.3}", build_s * 1e3),
                threads.to_string(),
                rays.to_string(),
                format!("{secs:.5}"),
                format!("{mrays:.3}"),
                format!("{:.2}", gsecs * 1e3),
                hits.to_string(),
                eb,
                er,
                eh,
            ]);
        }
        match emb {
            None => println!(
                "  (Embree comparison skipped: `pip install trimesh embreex numpy` to enable it)"
            ),
            Some((_, _, eh)) if eh != hits => {
                println!("  note: Embree hit {eh} rays, cac {hits} (edge rays may differ)")
            }
            Some(_) => {}
        }
    }
    cac::io::write_atomic(&a.out.join("render_rays.csv"), csv.csv().as_bytes())
}

/// Prints the ray table's heading; returns the CSV table.
fn rays_header() -> Table {
    let t = Table::new([
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
    ]);
    println!(
        "{:<11} {:>9} {:>9} {:>7} {:>10} {:>11} {:>13} {:>12}",
        "scene",
        "triangles",
        "build ms",
        "threads",
        "Mrays/s",
        "embree Mr/s",
        "cac / embree",
        "G-buffer ms"
    );
    t
}

/// Seconds of the fastest closest-hit pass over `g0`'s rays (the same work as Embree's: the
/// closest hit of each ray) and of the fastest whole G-buffer, on `threads` threads.
fn cast_times(
    repeats: usize,
    threads: usize,
    scene: &Scene,
    accel: &Accel,
    cam: &cac::render::Camera,
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

/// Anti-aliasing error against time (PSNR of 1/4/16 samples against 64): render_aa.csv.
fn anti_aliasing(a: &Args) -> Result<()> {
    let mut jeep = cac::scene::generate::jeep();
    jeep.normalise(0.0, None);
    let env = Environment::new(EnvConfig::default())?;
    let cond = Condition::plain(Viewpoint::new(35.0, 12.0, 1.6), Brightness::Bright);
    let render_at = |spp: usize| -> Result<(f64, Vec<[f32; 3]>)> {
        let r = Renderer::new(
            jeep.clone(),
            RenderSettings {
                width: 256,
                height: 256,
                samples: spp,
                ..Default::default()
            },
        )?;
        let atlas = r.scene.initial_atlas(r.settings.atlas_res);
        let (secs, img) = best_of(a.repeats.min(3), || {
            let plan = cac::environment::plan(&r, &env, &cond).expect("plan");
            plan.render_cpu(&atlas)
        });
        Ok((secs, img))
    };
    let (_, reference) = render_at(64)?;
    let mut aa = Table::new(["samples", "ms_per_frame", "psnr_db_vs_64"]);
    println!(
        "\nanti-aliasing, 256x256 jeep, against 64 samples per pixel:\n{:>8} {:>12} {:>10}",
        "samples", "ms/frame", "PSNR dB"
    );
    for spp in [1usize, 4, 16, 64] {
        let (secs, img) = render_at(spp)?;
        let psnr = psnr(&img, &reference);
        println!("{:>8} {:>12.1} {:>10.2}", spp, secs * 1e3, psnr);
        aa.row([
            spp.to_string(),
            format!("{:.2}", secs * 1e3),
            format!("{psnr:.3}"),
        ]);
    }
    cac::io::write_atomic(&a.out.join("render_aa.csv"), aa.csv().as_bytes())
}

/// Peak signal-to-noise ratio (dB) of `img` against `reference`, values in [0, 1].
fn psnr(img: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let mse: f64 = img
        .iter()
        .zip(reference)
        .flat_map(|(a, b)| (0..3).map(move |c| ((a[c] - b[c]) as f64).powi(2)))
        .sum::<f64>()
        / (img.len() * 3) as f64;
    if mse > 0.0 {
        10.0 * (1.0 / mse).log10()
    } else {
        f64::INFINITY
    }
}
