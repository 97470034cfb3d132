//! The bake's error against run time: for several subdivision limits, the triangle count, the
//! seconds taken and the colour error against the texture; optionally the solidifier's error
//! against time at several grid spacings (`cac bench export`, run by [`ExportBench::run`]).

use anyhow::{Context, Result};
use cac_core::memory::MemoryBudget;
use cac_export::bake::{bake, colour_error, BakeLimits};
use cac_export::{PrintMesh, Scale};
use cac_scene::generate::value_noise;
use cac_scene::Texture;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::PathBuf;
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
    /// Peak resident memory while this row was baked and measured (MB; the process's peak is
    /// reset before each row where Linux allows it).
    pub peak_mb: f64,
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
    budget: &MemoryBudget,
) -> Result<Vec<BenchRow>> {
    let mut rows = vec![];
    for l in limits {
        let mut best = f64::INFINITY;
        let mut baked = None;
        cac_core::memory::reset_peak_rss();
        for _ in 0..repeats.max(1) {
            let t = Instant::now();
            drop(baked.take()); // the previous repeat's bake is freed before the next is made
            let b = bake(mesh, l, budget)?;
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
            peak_mb: cac_core::memory::peak_rss_mb(),
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
        "| max edge (texels) | max edge (mm) | triangles | bake (s) | peak MB | RMSE (8-bit) | mean ΔE76 | p95 ΔE76 |\n|---:|---:|---:|---:|---:|---:|---:|---:|\n",
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
            "| {} | {} | {} | {:.3} | {:.0} | {:.2} | {:.2} | {:.2} |",
            tx, mm, r.triangles, r.seconds, r.peak_mb, r.rmse_8bit, r.mean_delta_e, r.p95_delta_e
        );
    }
    s
}

/// The table as CSV.
pub fn csv(rows: &[BenchRow]) -> String {
    let mut s = String::from(
        "max_edge_texels,max_edge_mm,triangles,seconds,peak_mb,rmse_8bit,mean_delta_e,p95_delta_e\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{:.6},{:.1},{:.4},{:.4},{:.4}",
            r.max_edge_texels,
            r.max_edge_mm,
            r.triangles,
            r.seconds,
            r.peak_mb,
            r.rmse_8bit,
            r.mean_delta_e,
            r.p95_delta_e
        );
    }
    s
}

/// One row of the solidify table: grid spacing against triangles, seconds, peak memory and the
/// solid's geometric and colour error against the original surface.
#[derive(Clone, Debug, Serialize)]
pub struct SolidRow {
    pub input_triangles: usize,
    pub voxel_mm: f32,
    pub triangles: usize,
    pub seconds: f64,
    /// Peak resident memory of the process so far (MB; Linux, else 0).
    pub peak_mb: f64,
    pub fidelity: cac_export::Fidelity,
}

/// Subdivides `mesh` (midpoint splits, as the bake does) until it has at least `n` triangles,
/// keeping each piece's paint: a larger input of the same shape for the solidify benchmark.
pub(crate) fn refine(mesh: &PrintMesh, n: usize) -> Result<PrintMesh> {
    let mut mm = mesh.report.size_mm.iter().copied().fold(0.0f32, f32::max);
    loop {
        let b = bake(
            mesh,
            &BakeLimits {
                max_edge_texels: f32::INFINITY,
                max_edge_mm: mm,
                ..Default::default()
            },
            &MemoryBudget::default(),
        )?;
        if b.tris.len() >= n {
            let mut tris: Vec<cac_export::PrintTri> = b
                .tris
                .iter()
                .map(|t| {
                    let src = &mesh.tris[t.parent as usize];
                    let paint = match src.paint {
                        cac_export::Paint::Texture { tex, uv } => cac_export::Paint::Texture {
                            tex,
                            uv: t.bary.map(|w| uv[0] * w.x + uv[1] * w.y + uv[2] * w.z),
                        },
                        p => p,
                    };
                    cac_export::PrintTri {
                        v: t.v,
                        paint,
                        part: src.part,
                    }
                })
                .collect();
            let (positions, report) = cac_export::weld_and_check(&b.positions, &mut tris)?;
            return Ok(PrintMesh {
                positions,
                tris,
                report,
                ..mesh.clone()
            });
        }
        mm *= 0.7;
    }
}

/// Solidifies `mesh` at each grid spacing and measures the result against it.
pub(crate) fn run_solid(
    mesh: &PrintMesh,
    voxels: &[f32],
    min_wall: f32,
    samples: usize,
) -> Result<Vec<SolidRow>> {
    let a = cac_export::printability::analyse(mesh, min_wall);
    let mut rows = vec![];
    for &h in voxels {
        let t = Instant::now();
        let (s, _) = cac_export::solidify(
            mesh,
            &a,
            &cac_export::SolidifyOptions {
                voxel_mm: h,
                min_wall_mm: min_wall,
                thin: cac_export::printability::ThinPolicy::Thicken,
                memory: MemoryBudget::current(),
            },
        )?;
        let seconds = t.elapsed().as_secs_f64();
        let fidelity = cac_export::fidelity(mesh, &a.kinds, &s, None, samples, 5);
        rows.push(SolidRow {
            input_triangles: mesh.tris.len(),
            voxel_mm: h,
            triangles: s.tris.len(),
            seconds,
            peak_mb: cac_core::memory::peak_rss_mb(),
            fidelity,
        });
    }
    Ok(rows)
}

/// The solidify table as Markdown.
pub fn solid_markdown(rows: &[SolidRow]) -> String {
    let mut s = String::from(
        "| input triangles | voxel (mm) | triangles | solidify (s) | peak MB | mean dist (mm) | p99 dist (mm) | max dist (mm) | original to solid mean / max (mm) | RMSE (8-bit) | mean ΔE76 | p95 ΔE76 |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        let f = &r.fidelity;
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.2} | {:.0} | {:.3} | {:.3} | {:.3} | {:.3} / {:.3} | {:.2} | {:.2} | {:.2} |",
            r.input_triangles, r.voxel_mm, r.triangles, r.seconds, r.peak_mb, f.out_mean_mm, f.out_p99_mm,
            f.out_max_mm, f.in_mean_mm, f.in_max_mm, f.rmse_8bit, f.mean_delta_e, f.p95_delta_e
        );
    }
    s
}

/// The solidify table as CSV.
pub fn solid_csv(rows: &[SolidRow]) -> String {
    let mut s = String::from("input_triangles,voxel_mm,triangles,seconds,peak_mb,out_mean_mm,out_p99_mm,out_max_mm,in_mean_mm,in_max_mm,rmse_8bit,mean_delta_e,p95_delta_e\n");
    for r in rows {
        let f = &r.fidelity;
        let _ = writeln!(
            s,
            "{},{},{},{:.4},{:.1},{:.5},{:.5},{:.5},{:.5},{:.5},{:.4},{:.4},{:.4}",
            r.input_triangles,
            r.voxel_mm,
            r.triangles,
            r.seconds,
            r.peak_mb,
            f.out_mean_mm,
            f.out_p99_mm,
            f.out_max_mm,
            f.in_mean_mm,
            f.in_max_mm,
            f.rmse_8bit,
            f.mean_delta_e,
            f.p95_delta_e
        );
    }
    s
}

/// What `cac bench export` measures (also its flags): the bake's colour error against triangle
/// count and seconds for several limits, and optionally solidify's.
#[derive(Clone, Debug)]
pub struct ExportBench {
    /// The object (file or default name).
    pub mesh: PathBuf,
    /// The texture; default: a synthetic camouflage at --res ([`synthetic_camouflage`]).
    pub texture: Option<PathBuf>,
    /// Resolution of the synthetic camouflage.
    pub res: usize,
    pub scale: Scale,
    /// Edge limits in texels to try.
    pub texels: Vec<f32>,
    /// Edge limits in mm to try (texel limit off), e.g. 2,1,0.5.
    pub mm: Vec<f32>,
    /// Random surface samples for the error.
    pub samples: usize,
    /// Also solidify at these grid spacings (mm), e.g. 1.6,0.8,0.4,0.2: error against time.
    pub solid_voxels: Vec<f32>,
    /// Subdivide the mesh to at least this many triangles before solidifying (0: as loaded).
    pub solid_input_triangles: usize,
}

impl Default for ExportBench {
    /// The jeep at 1:24 with a 512² synthetic camouflage; texel limits 16 down to 0.5, 200,000
    /// error samples, no millimetre limits and no solidifying.
    fn default() -> Self {
        ExportBench {
            mesh: PathBuf::from("jeep"),
            texture: None,
            res: 512,
            scale: Scale { denominator: 24.0 },
            texels: vec![16.0, 8.0, 4.0, 2.0, 1.0, 0.5],
            mm: vec![],
            samples: 200_000,
            solid_voxels: vec![],
            solid_input_triangles: 0,
        }
    }
}

/// The solidify table and the mesh it was measured on.
pub struct SolidPart {
    pub input: PrintMesh,
    pub rows: Vec<SolidRow>,
}

/// What [`ExportBench::run`] measured.
pub struct ExportBenchOutcome {
    pub mesh: PrintMesh,
    /// Texture width and height.
    pub texture: (usize, usize),
    pub solid: Option<SolidPart>,
    /// The bake table (none when no edge limit was asked for and the solidifier was).
    pub bake: Option<Vec<BenchRow>>,
}

impl ExportBench {
    pub fn run(&self) -> Result<ExportBenchOutcome> {
        let scene = cac_export::load_mesh(&self.mesh, &Default::default())?;
        let camo = match &self.texture {
            Some(p) => cac_export::load_texture(p, &MemoryBudget::current())?,
            None => synthetic_camouflage(self.res, 11),
        };
        let mesh = cac_export::prepare(&scene, &camo, self.scale)
            .with_context(|| format!("mesh {}", self.mesh.display()))?;
        let limits: Vec<BakeLimits> = self
            .texels
            .iter()
            .map(|&t| BakeLimits {
                max_edge_texels: t,
                ..Default::default()
            })
            .chain(self.mm.iter().map(|&mm| BakeLimits {
                max_edge_texels: f32::INFINITY,
                max_edge_mm: mm,
                ..Default::default()
            }))
            .collect();
        let solid = if self.solid_voxels.is_empty() {
            None
        } else {
            let input = if self.solid_input_triangles > mesh.tris.len() {
                refine(&mesh, self.solid_input_triangles)?
            } else {
                mesh.clone()
            };
            let rows = run_solid(&input, &self.solid_voxels, 0.8, self.samples.min(50_000))?;
            Some(SolidPart { input, rows })
        };
        let bake = if solid.is_some() && limits.is_empty() {
            None
        } else {
            Some(run(
                &mesh,
                &limits,
                self.samples,
                3,
                &MemoryBudget::current(),
            )?)
        };
        Ok(ExportBenchOutcome {
            texture: (camo.width, camo.height),
            mesh,
            solid,
            bake,
        })
    }
}
