//! The bake's error against run time: for several subdivision limits, the triangle count, the
//! seconds taken and the colour error against the texture (`cac bench export`).

use super::bake::{bake, colour_error, BakeLimits};
use super::PrintMesh;
use crate::scene::generate::value_noise;
use crate::scene::Texture;
use anyhow::Result;
use serde::Serialize;
use std::fmt::Write as _;
use std::time::Instant;

/// A camouflage-like test texture: four-colour blotches with sharp borders (as learned
/// adversarial textures have) plus fine texel-level noise.
pub fn synthetic_camouflage(res: usize, seed: u32) -> Texture {
    let palette = [
        [0.33, 0.36, 0.20],
        [0.55, 0.48, 0.32],
        [0.17, 0.16, 0.12],
        [0.42, 0.50, 0.38],
    ];
    let mut texels = Vec::with_capacity(res * res);
    for y in 0..res {
        for x in 0..res {
            let (u, v) = (x as f32 / res as f32, y as f32 / res as f32);
            let n = 0.6 * value_noise(u * 12.0, v * 12.0, seed)
                + 0.4 * value_noise(u * 37.0, v * 37.0, seed + 1);
            let k = ((n * 4.0) as usize).min(3);
            let f = 0.85 + 0.3 * value_noise(x as f32 * 0.9, y as f32 * 0.9, seed + 2);
            texels.push(palette[k].map(|c| (c * f).clamp(0.0, 1.0)));
        }
    }
    Texture {
        width: res,
        height: res,
        texels,
    }
}

/// One row of the table.
#[derive(Clone, Debug, Serialize)]
pub struct BenchRow {
    pub max_edge_texels: f32,
    pub max_edge_mm: f32,
    pub triangles: usize,
    pub seconds: f64,
    pub rmse_8bit: f64,
    pub mean_delta_e: f64,
    pub p95_delta_e: f64,
}

/// Bakes `mesh` with each limit (best of `repeats` timings) and measures the error at `samples`
/// random surface points.
pub fn run(
    mesh: &PrintMesh,
    limits: &[BakeLimits],
    samples: usize,
    repeats: usize,
) -> Result<Vec<BenchRow>> {
    let mut rows = vec![];
    for l in limits {
        let mut best = f64::INFINITY;
        let mut baked = None;
        for _ in 0..repeats.max(1) {
            let t = Instant::now();
            let b = bake(mesh, l)?;
            best = best.min(t.elapsed().as_secs_f64());
            baked = Some(b);
        }
        let b = baked.unwrap();
        let e = colour_error(mesh, &b, samples, 7);
        rows.push(BenchRow {
            max_edge_texels: l.max_edge_texels,
            max_edge_mm: l.max_edge_mm,
            triangles: b.tris.len(),
            seconds: best,
            rmse_8bit: e.rmse_8bit,
            mean_delta_e: e.mean_delta_e,
            p95_delta_e: e.p95_delta_e,
        });
    }
    Ok(rows)
}

/// The table as Markdown.
pub fn markdown(rows: &[BenchRow]) -> String {
    let mut s = String::from(
        "| max edge (texels) | max edge (mm) | triangles | bake (s) | RMSE (8-bit) | mean ΔE76 | p95 ΔE76 |\n|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        let tx = if r.max_edge_texels.is_finite() {
            format!("{}", r.max_edge_texels)
        } else {
            "-".into()
        };
        let mm = if r.max_edge_mm.is_finite() {
            format!("{}", r.max_edge_mm)
        } else {
            "-".into()
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} | {:.2} | {:.2} | {:.2} |",
            tx, mm, r.triangles, r.seconds, r.rmse_8bit, r.mean_delta_e, r.p95_delta_e
        );
    }
    s
}

/// The table as CSV.
pub fn csv(rows: &[BenchRow]) -> String {
    let mut s = String::from(
        "max_edge_texels,max_edge_mm,triangles,seconds,rmse_8bit,mean_delta_e,p95_delta_e\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{:.6},{:.4},{:.4},{:.4}",
            r.max_edge_texels,
            r.max_edge_mm,
            r.triangles,
            r.seconds,
            r.rmse_8bit,
            r.mean_delta_e,
            r.p95_delta_e
        );
    }
    s
}
