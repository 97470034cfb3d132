//! Print-readiness: welds positions, then checks that the mesh is closed, manifold, consistently
//! oriented and free of degenerate triangles, and measures its volume.
//!
//! Repairs (reported): triangles that collapse when welding are removed; inconsistently oriented
//! triangles of an orientable shell are flipped to agree with their neighbours; closed shells with
//! negative volume are turned outward. Refused (reported, the caller decides): open edges,
//! non-manifold edges (more than two triangles), zero-area triangles with distinct corners,
//! non-orientable shells.

use crate::mesh::{Paint, PrintMesh, PrintReport, PrintTri};
use anyhow::{bail, Result};
use glam::Vec3;
use std::collections::{HashMap, VecDeque};

/// Edge statistics of an indexed triangle list: `(open, non-manifold, misoriented)` edges.
#[cfg(test)]
pub(crate) fn edge_stats(tris: impl Iterator<Item = [u32; 3]>) -> (usize, usize, usize) {
    let mut edges: HashMap<(u32, u32), (u32, i32)> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let e = edges.entry((a.min(b), a.max(b))).or_default();
            e.0 += 1;
            e.1 += if a < b { 1 } else { -1 };
        }
    }
    let open = edges.values().filter(|e| e.0 == 1).count();
    let nm = edges.values().filter(|e| e.0 > 2).count();
    let mis = edges.values().filter(|e| e.0 == 2 && e.1 != 0).count();
    (open, nm, mis)
}

/// Merges positions closer than `eps` (grid hashing, 27 neighbour cells). Returns the new
/// positions and the old-to-new index map.
pub(crate) fn weld(positions: &[Vec3], eps: f32) -> (Vec<Vec3>, Vec<u32>) {
    let cell = |p: Vec3| (p / eps).floor().as_ivec3();
    let mut grid: HashMap<glam::IVec3, Vec<u32>> = HashMap::new();
    let mut out: Vec<Vec3> = vec![];
    let mut map = Vec::with_capacity(positions.len());
    for &p in positions {
        let c = cell(p);
        let mut found = None;
        'search: for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = grid.get(&(c + glam::IVec3::new(dx, dy, dz))) {
                        if let Some(&i) = list.iter().find(|&&i| out[i as usize].distance(p) <= eps)
                        {
                            found = Some(i);
                            break 'search;
                        }
                    }
                }
            }
        }
        let i = found.unwrap_or_else(|| {
            out.push(p);
            let i = out.len() as u32 - 1;
            grid.entry(c).or_default().push(i);
            i
        });
        map.push(i);
    }
    (out, map)
}

fn flip(t: &mut PrintTri) {
    t.v.swap(1, 2);
    if let Paint::Texture { uv, .. } = &mut t.paint {
        uv.swap(1, 2);
    }
}

/// Welds, repairs what can safely be repaired, and reports the rest (see the module doc).
pub fn weld_and_check(raw: &[Vec3], tris: &mut Vec<PrintTri>) -> Result<(Vec<Vec3>, PrintReport)> {
    if tris.is_empty() {
        bail!("the mesh has no triangles");
    }
    let mut rep = PrintReport::default();
    let positions = welded_positions(raw, tris, &mut rep)?;
    rep.welded_vertices = positions.len();
    rep.triangles = tris.len();
    measure_area(&positions, tris, &mut rep);
    let edges = edge_triangles(tris);
    count_bad_edges(&positions, &edges, &mut rep);
    let shells = orient_shells(tris, &edges, &mut rep);
    turn_outward(&positions, tris, &shells, &mut rep);
    let (lo, hi) = positions.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(l, h), &p| (l.min(p), h.max(p)),
    );
    rep.size_mm = (hi - lo).to_array();
    Ok((positions, rep))
}

/// Welds `raw` within a millionth of its diagonal, re-indexes `tris`, removes the triangles
/// that collapse, and keeps only the positions still used (in first-use order).
fn welded_positions(
    raw: &[Vec3],
    tris: &mut Vec<PrintTri>,
    rep: &mut PrintReport,
) -> Result<Vec<Vec3>> {
    let (lo, hi) = raw.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(l, h), &p| (l.min(p), h.max(p)),
    );
    let diag = (hi - lo).length();
    if diag.is_nan() || diag <= 0.0 {
        bail!("the mesh has no extent (all vertices coincide)");
    }
    let eps = (diag * 1e-6).max(1e-6);
    let (welded, map) = weld(raw, eps);
    rep.input_vertices = raw.len();
    rep.weld_epsilon_mm = eps;
    for t in tris.iter_mut() {
        t.v = t.v.map(|i| map[i as usize]);
    }
    let before = tris.len();
    tris.retain(|t| t.v[0] != t.v[1] && t.v[1] != t.v[2] && t.v[2] != t.v[0]);
    rep.collapsed_removed = before - tris.len();
    if tris.is_empty() {
        bail!("every triangle collapsed when welding vertices");
    }
    let mut remap = vec![u32::MAX; welded.len()];
    let mut positions = vec![];
    for t in tris.iter_mut() {
        for v in &mut t.v {
            if remap[*v as usize] == u32::MAX {
                remap[*v as usize] = positions.len() as u32;
                positions.push(welded[*v as usize]);
            }
            *v = remap[*v as usize];
        }
    }
    Ok(positions)
}

/// The surface's area, and the triangles of no area (relative to their longest edge).
fn measure_area(positions: &[Vec3], tris: &[PrintTri], rep: &mut PrintReport) {
    for t in tris {
        let [a, b, c] = t.v.map(|i| positions[i as usize]);
        let cr = (b - a).cross(c - a).length();
        let e = (b - a)
            .length_squared()
            .max((c - b).length_squared())
            .max((a - c).length_squared());
        rep.area_mm2 += 0.5 * cr as f64;
        if cr <= 1e-7 * e {
            rep.degenerate += 1;
        }
    }
}

/// Each undirected edge and the triangles that have it.
type EdgeMap = HashMap<(u32, u32), Vec<u32>>;

fn edge_triangles(tris: &[PrintTri]) -> EdgeMap {
    let mut edges = EdgeMap::new();
    for (ti, t) in tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t.v[k], t.v[(k + 1) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push(ti as u32);
        }
    }
    edges
}

/// Open and non-manifold edges, with up to five examples (sorted).
fn count_bad_edges(positions: &[Vec3], edges: &EdgeMap, rep: &mut PrintReport) {
    let pos = |i: u32| positions[i as usize];
    for (&(a, b), ts) in edges {
        if ts.len() != 2 {
            if ts.len() == 1 {
                rep.open_edges += 1;
            } else {
                rep.nonmanifold_edges += 1;
            }
            if rep.example_edges.len() < 5 {
                rep.example_edges
                    .push([pos(a).to_array(), pos(b).to_array()]);
            }
        }
    }
    rep.example_edges
        .sort_by(|p, q| p.partial_cmp(q).unwrap_or(std::cmp::Ordering::Equal));
}

/// The shells (edge-connected triangles): each triangle's shell, and whether each shell is
/// closed and orientable.
struct Shells {
    of: Vec<u32>,
    closed: Vec<bool>,
}

/// Orientation: breadth-first over manifold edges, flipping neighbours to agree.
fn orient_shells(tris: &mut [PrintTri], edges: &EdgeMap, rep: &mut PrintReport) -> Shells {
    let dir = |t: &PrintTri, a: u32, b: u32| (0..3).any(|k| t.v[k] == a && t.v[(k + 1) % 3] == b);
    let mut shell = vec![u32::MAX; tris.len()];
    let mut shell_closed = vec![];
    for seed in 0..tris.len() {
        if shell[seed] != u32::MAX {
            continue;
        }
        let sid = shell_closed.len() as u32;
        let (mut closed, mut orientable) = (true, true);
        shell[seed] = sid;
        let mut queue = VecDeque::from([seed as u32]);
        while let Some(ti) = queue.pop_front() {
            let t = tris[ti as usize];
            for k in 0..3 {
                let (a, b) = (t.v[k], t.v[(k + 1) % 3]);
                let ts = &edges[&(a.min(b), a.max(b))];
                if ts.len() != 2 {
                    closed = false;
                    continue;
                }
                let nb = if ts[0] == ti { ts[1] } else { ts[0] };
                let agrees = dir(&tris[nb as usize], b, a);
                if shell[nb as usize] == u32::MAX {
                    shell[nb as usize] = sid;
                    if !agrees {
                        flip(&mut tris[nb as usize]);
                        rep.reoriented_triangles += 1;
                    }
                    queue.push_back(nb);
                } else if !agrees {
                    orientable = false;
                }
            }
        }
        if !orientable {
            rep.non_orientable_shells += 1;
        }
        shell_closed.push(closed && orientable);
    }
    rep.shells = shell_closed.len();
    Shells {
        of: shell,
        closed: shell_closed,
    }
}

/// Each shell's volume; closed shells of negative volume turned outward; the total volume.
fn turn_outward(positions: &[Vec3], tris: &mut [PrintTri], shells: &Shells, rep: &mut PrintReport) {
    let mut vol = vec![0.0f64; rep.shells];
    for (ti, t) in tris.iter().enumerate() {
        let [a, b, c] = t.v.map(|i| positions[i as usize].as_dvec3());
        vol[shells.of[ti] as usize] += a.dot(b.cross(c)) / 6.0;
    }
    for (s, v) in vol.iter_mut().enumerate() {
        if shells.closed[s] && *v < 0.0 {
            rep.flipped_shells += 1;
            for (ti, t) in tris.iter_mut().enumerate() {
                if shells.of[ti] as usize == s {
                    flip(t);
                }
            }
            *v = -*v;
        }
    }
    rep.volume_mm3 = vol.iter().sum();
}

/// `mesh` with new geometry: `tris` over `positions` welded and checked ([`weld_and_check`]),
/// the name, textures and parts kept. The ending of every repair that rebuilds the triangles.
pub(crate) fn rewelded(
    mesh: &PrintMesh,
    positions: &[Vec3],
    mut tris: Vec<PrintTri>,
) -> Result<PrintMesh> {
    let (positions, report) = weld_and_check(positions, &mut tris)?;
    Ok(PrintMesh {
        positions,
        tris,
        report,
        ..mesh.clone()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(v: [u32; 3]) -> PrintTri {
        PrintTri {
            v,
            paint: Paint::Solid([1.0; 3]),
            part: 0,
        }
    }

    /// A unit cube (10 mm) with split vertices per face, one face flipped.
    fn cube(flip_one: bool, drop_one: bool) -> (Vec<Vec3>, Vec<PrintTri>) {
        use crate::fixtures::{corner, CUBE_QUADS as quads};
        let c = |i: u32| corner(i) * 10.0;
        let (mut p, mut t) = (vec![], vec![]);
        for q in quads {
            let b = p.len() as u32;
            p.extend(q.iter().map(|&i| c(i)));
            t.push(tri([b, b + 1, b + 2]));
            t.push(tri([b, b + 2, b + 3]));
        }
        if flip_one {
            t[3].v.swap(1, 2);
        }
        if drop_one {
            t.pop();
        }
        (p, t)
    }

    #[test]
    fn split_cube_welds_closed_with_volume() {
        let (p, mut t) = cube(true, false);
        let (pos, r) = weld_and_check(&p, &mut t).unwrap();
        assert_eq!(pos.len(), 8);
        assert!(r.is_closed(), "{r:?}");
        assert_eq!(r.reoriented_triangles, 1);
        assert!((r.volume_mm3 - 1000.0).abs() < 1e-3, "{}", r.volume_mm3);
        assert_eq!(edge_stats(t.iter().map(|t| t.v)), (0, 0, 0));
    }

    #[test]
    fn inside_out_cube_is_turned_outward() {
        let (p, mut t) = cube(false, false);
        for x in &mut t {
            x.v.swap(1, 2);
        }
        let (_, r) = weld_and_check(&p, &mut t).unwrap();
        assert_eq!(r.flipped_shells, 1);
        assert!(r.volume_mm3 > 999.0);
    }

    #[test]
    fn open_cube_is_reported() {
        let (p, mut t) = cube(false, true);
        let (_, r) = weld_and_check(&p, &mut t).unwrap();
        assert_eq!(r.open_edges, 3);
        assert!(!r.is_closed());
        assert!(r.problems().contains("3 open edges"), "{}", r.problems());
    }
}
