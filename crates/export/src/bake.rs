//! The colour bake: adaptive, crack-free subdivision of the print mesh until every edge of a
//! textured triangle spans at most `max_edge_texels` texels and every edge is at most
//! `max_edge_mm` long, then one sRGB colour per corner sampled bilinearly from the texture.
//!
//! Subdivision splits marked edges at their midpoint (shared edges are split once, for both
//! neighbours, so no T-junctions appear): a triangle with one, two or three marked edges becomes
//! two, three or four triangles; this repeats until no edge is marked. [`colour_error`] measures
//! how far the per-corner colours (interpolated across each triangle) are from the texture.

use crate::mesh::{Paint, PrintMesh};
use anyhow::{bail, Result};
use cac_core::colour::delta_e76_srgb as delta_e;
use cac_core::memory::MemoryBudget;
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::collections::HashMap;

/// Subdivision limits. The defaults come from the table in `docs/export.md`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BakeLimits {
    /// Longest edge of a textured triangle, in texels of its texture.
    pub max_edge_texels: f32,
    /// Longest edge of any triangle, in mm (`f32::INFINITY`: no limit).
    pub max_edge_mm: f32,
    /// Refuse to bake beyond this many triangles.
    pub max_triangles: usize,
}

impl Default for BakeLimits {
    fn default() -> Self {
        BakeLimits {
            max_edge_texels: 2.0,
            max_edge_mm: f32::INFINITY,
            max_triangles: 20_000_000,
        }
    }
}

/// One baked triangle: vertex indices into [`Baked::positions`], a colour per corner, and where
/// it lies in its original triangle (barycentric coordinates of its corners there).
#[derive(Clone, Copy, Debug)]
pub struct BakedTri {
    pub v: [u32; 3],
    pub colour: [[f32; 3]; 3],
    pub parent: u32,
    pub bary: [Vec3; 3],
}

/// The subdivided, coloured mesh (mm, +Z up, like [`PrintMesh`]).
#[derive(Clone, Debug)]
pub struct Baked {
    pub positions: Vec<Vec3>,
    pub tris: Vec<BakedTri>,
}

/// The UV of a point given by barycentric coordinates in a textured triangle.
fn uv_at(uv: &[Vec2; 3], b: Vec3) -> Vec2 {
    uv[0] * b.x + uv[1] * b.y + uv[2] * b.z
}

/// The texture colour of the print mesh at barycentric `b` of triangle `parent`.
pub fn reference_colour(mesh: &PrintMesh, parent: usize, b: Vec3) -> [f32; 3] {
    match mesh.tris[parent].paint {
        Paint::Texture { tex, uv } => mesh.textures[tex as usize].sample(uv_at(&uv, b)),
        Paint::Solid(c) => c,
    }
}

/// Memory held per baked triangle through the export that follows the bake (the bake's own
/// vectors and edge map, the colour-error sample, the 3MF's property list, the OBJ's vertices):
/// the jeep's whole `cac export` at 2.55 M and 10.2 M baked triangles peaked at 489 and 1889 MB,
/// 192 bytes per added triangle (docs/memory.md).
pub(crate) const BYTES_PER_BAKED_TRIANGLE: u64 = 200;

/// Memory an export holds before the bake's triangles (binary, mesh, textures, buffers).
const BAKE_FIXED_BYTES: u64 = 128 << 20;

/// A lower bound on the bake's triangle count: a triangle whose edges are at most `L` long has
/// at most the area `√3/4 L²`, so a triangle of area `A` (in texels² or mm²) ends as at least
/// `A / (√3/4 L²)` pieces. Known without subdividing, so a bake that cannot fit is refused at
/// once.
pub(crate) fn min_triangles(mesh: &PrintMesh, limits: &BakeLimits) -> u64 {
    let piece = |l: f32| 3f64.sqrt() / 4.0 * (l as f64).powi(2);
    let (mm_piece, tx_piece) = (piece(limits.max_edge_mm), piece(limits.max_edge_texels));
    mesh.tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.v.map(|i| mesh.positions[i as usize]);
            let mut n = 0.5 * (b - a).cross(c - a).length() as f64 / mm_piece;
            if let Paint::Texture { tex, uv } = t.paint {
                let tx = &mesh.textures[tex as usize];
                let d = (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs() as f64;
                let texels2 = 0.5 * d * tx.width as f64 * tx.height as f64;
                n = n.max(texels2 / tx_piece);
            }
            if n.is_finite() {
                n.max(1.0) as u64
            } else {
                u64::MAX / 4
            }
        })
        .fold(0u64, u64::saturating_add)
}

/// The most triangles the bake may make: `limits.max_triangles`, and what fits the budget.
fn triangle_cap(limits: &BakeLimits, budget: &MemoryBudget) -> u64 {
    (limits.max_triangles as u64).min(budget.items(BAKE_FIXED_BYTES, BYTES_PER_BAKED_TRIANGLE))
}

/// The refusal of a bake of `n` triangles (estimated or counted) over the cap.
fn too_many(n: u64, limits: &BakeLimits, budget: &MemoryBudget) -> anyhow::Error {
    let knob = format!(
        "raise --max-edge-texels (now {}){}, or use a smaller texture",
        limits.max_edge_texels,
        if limits.max_edge_mm.is_finite() {
            format!(" or --max-edge-mm (now {})", limits.max_edge_mm)
        } else {
            String::new()
        }
    );
    if n > limits.max_triangles as u64 {
        anyhow::anyhow!(
            "the bake would make at least {n} triangles, over its limit of {}: {knob}",
            limits.max_triangles
        )
    } else {
        let need = BAKE_FIXED_BYTES + n.saturating_mul(BYTES_PER_BAKED_TRIANGLE);
        budget
            .check(&format!("the bake ({n} triangles)"), need, &knob)
            .unwrap_err()
            .into()
    }
}

/// Refuses, without subdividing, a bake whose [`min_triangles`] is already over the limit or the
/// budget (the exporter calls it before repairing, so a hopeless bake costs no solidify).
pub(crate) fn check_lower_bound(
    mesh: &PrintMesh,
    limits: &BakeLimits,
    budget: &MemoryBudget,
) -> Result<()> {
    let lower = min_triangles(mesh, limits);
    if lower > triangle_cap(limits, budget) {
        return Err(too_many(lower, limits, budget));
    }
    Ok(())
}

/// Subdivides and colours the mesh, refusing (before it allocates) a bake whose triangles would
/// not fit `limits.max_triangles` or the memory budget.
pub fn bake(mesh: &PrintMesh, limits: &BakeLimits, budget: &MemoryBudget) -> Result<Baked> {
    let positive = |x: f32| x > 0.0; // false for NaN too
    if !positive(limits.max_edge_texels) || !positive(limits.max_edge_mm) {
        bail!(
            "bake limits must be positive (max edge {} texels, {} mm)",
            limits.max_edge_texels,
            limits.max_edge_mm
        );
    }
    check_lower_bound(mesh, limits, budget)?;
    let cap = triangle_cap(limits, budget);
    let mut positions = mesh.positions.clone();
    let corners = [Vec3::X, Vec3::Y, Vec3::Z];
    let mut tris: Vec<BakedTri> = mesh
        .tris
        .iter()
        .enumerate()
        .map(|(i, t)| BakedTri {
            v: t.v,
            colour: [[0.0; 3]; 3],
            parent: i as u32,
            bary: corners,
        })
        .collect();
    let texel_scale: Vec<Option<Vec2>> = mesh
        .tris
        .iter()
        .map(|t| match t.paint {
            Paint::Texture { tex, .. } => {
                let tx = &mesh.textures[tex as usize];
                Some(Vec2::new(tx.width as f32, tx.height as f32))
            }
            Paint::Solid(_) => None,
        })
        .collect();
    let key = |a: u32, b: u32| (a.min(b), a.max(b));
    loop {
        let mut marked: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &tris {
            let parent = &mesh.tris[t.parent as usize];
            for k in 0..3 {
                let (a, b) = (t.v[k], t.v[(k + 1) % 3]);
                let mut long =
                    positions[a as usize].distance(positions[b as usize]) > limits.max_edge_mm;
                if let (Some(s), Paint::Texture { uv, .. }) =
                    (texel_scale[t.parent as usize], parent.paint)
                {
                    let d = (uv_at(&uv, t.bary[k]) - uv_at(&uv, t.bary[(k + 1) % 3])) * s;
                    long |= d.length() > limits.max_edge_texels;
                }
                if long {
                    marked.insert(key(a, b), u32::MAX);
                }
            }
        }
        if marked.is_empty() {
            break;
        }
        // Count this round's triangles (a triangle with k marked edges becomes k + 1) before
        // anything is allocated for them.
        let count: u64 = tris
            .iter()
            .map(|t| {
                1 + (0..3)
                    .filter(|&k| marked.contains_key(&key(t.v[k], t.v[(k + 1) % 3])))
                    .count() as u64
            })
            .sum();
        if count > cap {
            return Err(too_many(count, limits, budget));
        }
        // Create midpoints once per edge, in edge order (so the vertices written do not depend
        // on the hash map's iteration order: the same input bakes to the same file).
        positions.reserve(marked.len());
        let mut edges: Vec<(u32, u32)> = marked.keys().copied().collect();
        edges.sort_unstable();
        for (a, b) in edges {
            positions.push((positions[a as usize] + positions[b as usize]) * 0.5);
            marked.insert((a, b), positions.len() as u32 - 1);
        }
        let mut next = Vec::with_capacity(count as usize);
        for t in &tris {
            let mid: [Option<u32>; 3] =
                std::array::from_fn(|k| marked.get(&key(t.v[k], t.v[(k + 1) % 3])).copied());
            split(t, mid, &mut next);
        }
        tris = next;
    }
    for t in &mut tris {
        for k in 0..3 {
            t.colour[k] = reference_colour(mesh, t.parent as usize, t.bary[k]);
        }
    }
    Ok(Baked { positions, tris })
}

/// Splits `t` at the midpoints `mid[k]` of its marked edges `k` (corner k to k+1).
fn split(t: &BakedTri, mid: [Option<u32>; 3], out: &mut Vec<BakedTri>) {
    let n = mid.iter().filter(|m| m.is_some()).count();
    // Rotate so that the pattern is canonical: one edge → edge 0; two edges → 0 and 1.
    let r = match n {
        1 => mid.iter().position(|m| m.is_some()).unwrap(),
        2 => (mid.iter().position(|m| m.is_none()).unwrap() + 1) % 3,
        _ => 0,
    };
    let c = |k: usize| (t.v[(k + r) % 3], t.bary[(k + r) % 3]);
    let m = |k: usize| {
        let (a, b) = (t.bary[(k + r) % 3], t.bary[(k + r + 1) % 3]);
        (mid[(k + r) % 3].unwrap(), (a + b) * 0.5)
    };
    let mut push = |p: [(u32, Vec3); 3]| {
        out.push(BakedTri {
            v: p.map(|x| x.0),
            colour: t.colour,
            parent: t.parent,
            bary: p.map(|x| x.1),
        })
    };
    match n {
        0 => out.push(*t),
        1 => {
            push([c(0), m(0), c(2)]);
            push([m(0), c(1), c(2)]);
        }
        2 => {
            // Marked edges 0 (c0-c1) and 1 (c1-c2).
            push([m(0), c(1), m(1)]);
            push([c(0), m(0), m(1)]);
            push([c(0), m(1), c(2)]);
        }
        _ => {
            push([c(0), m(0), m(2)]);
            push([m(0), c(1), m(1)]);
            push([m(2), m(1), c(2)]);
            push([m(0), m(1), m(2)]);
        }
    }
}

/// Colour error of a bake against the texture.
#[derive(Clone, Debug, Serialize)]
pub struct ColourError {
    pub samples: usize,
    /// Root mean square error per channel, in 8-bit sRGB steps.
    pub rmse_8bit: f64,
    /// Mean and 95th percentile CIE76 ΔE.
    pub mean_delta_e: f64,
    pub p95_delta_e: f64,
}

/// Samples `n` area-uniform random points on the textured triangles and compares the baked
/// colour (corner colours quantised to 8 bits, interpolated barycentrically in sRGB, as the
/// 3MF stores them) with the texture's bilinear colour there.
pub fn colour_error(mesh: &PrintMesh, baked: &Baked, n: usize, seed: u64) -> ColourError {
    let area = |t: &BakedTri| {
        let [a, b, c] = t.v.map(|i| baked.positions[i as usize]);
        0.5 * (b - a).cross(c - a).length() as f64
    };
    let textured: Vec<&BakedTri> = baked
        .tris
        .iter()
        .filter(|t| matches!(mesh.tris[t.parent as usize].paint, Paint::Texture { .. }))
        .collect();
    let mut cdf = Vec::with_capacity(textured.len());
    let mut acc = 0.0;
    for t in &textured {
        acc += area(t);
        cdf.push(acc);
    }
    if textured.is_empty() || acc <= 0.0 {
        return ColourError {
            samples: 0,
            rmse_8bit: 0.0,
            mean_delta_e: 0.0,
            p95_delta_e: 0.0,
        };
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (mut se, mut des) = (0.0f64, Vec::with_capacity(n));
    for _ in 0..n {
        let x = rng.random::<f64>() * acc;
        let i = cdf.partition_point(|&c| c < x).min(textured.len() - 1);
        let t = textured[i];
        let (mut u, mut v) = (rng.random::<f32>(), rng.random::<f32>());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let w = [1.0 - u - v, u, v];
        let q = t
            .colour
            .map(|c| cac_core::colour::to_rgb8(c).map(|x| x as f32 / 255.0));
        let baked_c: [f32; 3] = std::array::from_fn(|k| (0..3).map(|j| q[j][k] * w[j]).sum());
        let b = t.bary[0] * w[0] + t.bary[1] * w[1] + t.bary[2] * w[2];
        let r = reference_colour(mesh, t.parent as usize, b);
        for k in 0..3 {
            se += ((baked_c[k] - r[k]) as f64 * 255.0).powi(2);
        }
        des.push(delta_e(baked_c, r) as f64);
    }
    des.sort_by(|a, b| a.total_cmp(b));
    ColourError {
        samples: n,
        rmse_8bit: (se / (3 * n) as f64).sqrt(),
        mean_delta_e: des.iter().sum::<f64>() / n as f64,
        p95_delta_e: des[(n * 95 / 100).min(n - 1)],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{PrintReport, PrintTri};
    use crate::printcheck;
    use cac_scene::Texture;

    /// A 40 x 40 mm square of two triangles textured with a 16 x 16 checker.
    fn square() -> PrintMesh {
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(40.0, 0.0, 0.0),
            Vec3::new(40.0, 40.0, 0.0),
            Vec3::new(0.0, 40.0, 0.0),
        ];
        let uv = [Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y];
        let tri = |v: [u32; 3]| PrintTri {
            v,
            paint: Paint::Texture {
                tex: 0,
                uv: v.map(|i| uv[i as usize]),
            },
            part: 0,
        };
        let texels = (0..256)
            .map(|i| {
                if (i % 16 + i / 16) % 2 == 0 {
                    [1.0; 3]
                } else {
                    [0.0, 0.2, 0.9]
                }
            })
            .collect();
        PrintMesh {
            name: "square".into(),
            positions,
            tris: vec![tri([0, 1, 2]), tri([0, 2, 3])],
            textures: vec![Texture {
                width: 16,
                height: 16,
                texels,
            }],
            parts: vec!["body".into()],
            painted: vec![true],
            report: PrintReport::default(),
        }
    }

    #[test]
    fn subdivision_meets_the_limits_without_cracks() {
        let m = square();
        let b = bake(
            &m,
            &BakeLimits {
                max_edge_texels: 1.0,
                max_edge_mm: 3.0,
                ..Default::default()
            },
            &MemoryBudget::default(),
        )
        .unwrap();
        for t in &b.tris {
            for k in 0..3 {
                let (p, q) = (
                    b.positions[t.v[k] as usize],
                    b.positions[t.v[(k + 1) % 3] as usize],
                );
                assert!(p.distance(q) <= 3.0 + 1e-4);
            }
        }
        // No T-junctions: the only open edges are the square's boundary, each split alike.
        let (open, nm, mis) = printcheck::edge_stats(b.tris.iter().map(|t| t.v));
        assert_eq!((nm, mis), (0, 0));
        let boundary = 4 * (b.positions.iter().filter(|p| p.y == 0.0).count() - 1);
        assert_eq!(open, boundary);
        // Area is preserved.
        let area: f32 = b
            .tris
            .iter()
            .map(|t| {
                let [p, q, r] = t.v.map(|i| b.positions[i as usize]);
                0.5 * (q - p).cross(r - p).z
            })
            .sum();
        assert!((area - 1600.0).abs() < 1e-2, "{area}");
    }

    #[test]
    fn finer_limits_reduce_the_error() {
        let m = square();
        let err = |texels: f32| {
            let b = bake(
                &m,
                &BakeLimits {
                    max_edge_texels: texels,
                    ..Default::default()
                },
                &MemoryBudget::default(),
            )
            .unwrap();
            colour_error(&m, &b, 20_000, 3).rmse_8bit
        };
        let (coarse, fine) = (err(16.0), err(0.5));
        assert!(fine < coarse * 0.6, "coarse {coarse}, fine {fine}");
    }

    #[test]
    fn the_lower_bound_never_exceeds_the_count_and_is_within_its_factor() {
        let m = square();
        for (texels, mm) in [
            (16.0, f32::INFINITY),
            (1.0, 3.0),
            (0.5, f32::INFINITY),
            (64.0, 2.0),
        ] {
            let l = BakeLimits {
                max_edge_texels: texels,
                max_edge_mm: mm,
                ..Default::default()
            };
            let n = bake(&m, &l, &MemoryBudget::default()).unwrap().tris.len() as u64;
            let lower = min_triangles(&m, &l);
            assert!(
                lower <= n && n <= 8 * lower.max(1),
                "{texels} {mm}: {lower} vs {n}"
            );
        }
    }

    #[test]
    fn a_bake_over_the_budget_is_refused_before_it_allocates_naming_the_knobs() {
        // An 8192² texture over the square: at least 38 M triangles at 2 texels per edge.
        let mut m = square();
        m.textures[0] = Texture {
            width: 8192,
            height: 8192,
            texels: vec![[0.5; 3]; 1],
        };
        let err = bake(&m, &BakeLimits::default(), &MemoryBudget::default())
            .unwrap_err()
            .to_string();
        assert!(err.contains("over its limit of 20000000"), "{err}");
        assert!(err.contains("--max-edge-texels (now 2)"), "{err}");
        // Under the triangle limit but over a small budget: the budget names --max-memory.
        // (512²: at least 151 k triangles, 158 MB with the fixed share.)
        m.textures[0] = Texture {
            width: 512,
            height: 512,
            texels: vec![[0.5; 3]; 512 * 512],
        };
        let small = MemoryBudget::new(150 << 20);
        let err = bake(&m, &BakeLimits::default(), &small)
            .unwrap_err()
            .to_string();
        assert!(err.contains("over the memory budget of 150 MB"), "{err}");
        assert!(err.contains("--max-memory"), "{err}");
        // The same bake fits the default budget.
        assert!(bake(&m, &BakeLimits::default(), &MemoryBudget::default()).is_ok());
    }

    #[test]
    fn the_count_refuses_what_the_lower_bound_lets_through() {
        // Long thin slivers: tiny area (the lower bound says 2 triangles) but each edge spans
        // the whole 4096-texel atlas, so subdivision makes thousands.
        let mut m = square();
        m.positions[2] = Vec3::new(40.0, 0.001, 0.0);
        m.positions[3] = Vec3::new(0.0, 0.001, 0.0);
        m.textures[0] = Texture {
            width: 4096,
            height: 4096,
            texels: vec![[0.5; 3]; 4096 * 4096],
        };
        for t in &mut m.tris {
            t.paint = Paint::Texture {
                tex: 0,
                uv: [Vec2::ZERO, Vec2::new(1.0, 0.0001), Vec2::new(1.0, 0.0)],
            };
        }
        let l = BakeLimits {
            max_triangles: 1000,
            ..Default::default()
        };
        assert!(min_triangles(&m, &l) <= 1000);
        let err = bake(&m, &l, &MemoryBudget::default())
            .unwrap_err()
            .to_string();
        assert!(err.contains("over its limit of 1000"), "{err}");
    }
}
