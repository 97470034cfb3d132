//! Light repair of a print mesh, keeping its triangles, UVs and paint: what a user's mesh usually
//! needs before [`super::printcheck`] accepts it, short of rebuilding it ([`super::solidify`]).
//! In order: vertices closer than a touch tolerance (0.01 mm at print scale) are welded and the
//! triangles that collapse are removed; duplicate triangles (same three vertices, either winding)
//! and zero-area triangles are removed; T-junctions are zipped (an open edge with another open
//! edge's vertex lying on it is split there, so cracks between parts that touch are closed);
//! small holes (boundary loops whose perimeter is at most `max_hole_mm`) are filled by ear
//! clipping in the loop's best-fit plane, the new triangles painted with the mean colour around
//! the hole; open shells that face inward (negative volume about their centroid) are flipped.
//! Orientation within shells and of closed shells is then done by the print check, which is run
//! again on the result.

use crate::mesh::{Paint, PrintMesh, PrintTri};
use crate::printcheck::{rewelded, weld};
use anyhow::Result;
use cac_scene::polygon::{ear_clip, OnEdge};
use glam::{Vec2, Vec3};
use serde::Serialize;
use std::collections::{HashMap, HashSet};

/// What the light repair did.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub(crate) struct RepairLog {
    pub touch_welded: usize,
    pub duplicates_removed: usize,
    pub degenerate_removed: usize,
    pub tjunctions_split: usize,
    pub holes_filled: usize,
    pub hole_triangles: usize,
    /// Holes larger than the limit, left open (their perimeters, mm).
    pub holes_left_mm: Vec<f32>,
    pub open_shells_flipped: usize,
}

impl RepairLog {
    /// What was done, in words.
    pub fn notes(&self) -> Vec<String> {
        let mut n = vec![];
        let mut say = |k: usize, what: &str| {
            if k > 0 {
                n.push(format!("repaired: {what}: {k}"));
            }
        };
        say(self.touch_welded, "vertices welded to a touching vertex");
        say(self.duplicates_removed, "duplicate triangles removed");
        say(self.degenerate_removed, "zero-area triangles removed");
        say(
            self.tjunctions_split,
            "T-junction edges split to close cracks",
        );
        say(self.holes_filled, "small holes filled");
        say(
            self.open_shells_flipped,
            "inward-facing open shells flipped",
        );
        if !self.holes_left_mm.is_empty() {
            let mut h = self.holes_left_mm.clone();
            h.sort_by(|a, b| b.total_cmp(a));
            h.truncate(5);
            let s: Vec<String> = h.iter().map(|p| format!("{p:.1}")).collect();
            n.push(format!(
                "{} holes too large to fill (perimeters {} mm)",
                self.holes_left_mm.len(),
                s.join(", ")
            ));
        }
        n
    }
}

/// Twice the area vector of a triangle.
fn cross(p: &[Vec3], t: [u32; 3]) -> Vec3 {
    let [a, b, c] = t.map(|i| p[i as usize]);
    (b - a).cross(c - a)
}

fn is_degenerate(p: &[Vec3], t: [u32; 3]) -> bool {
    let [a, b, c] = t.map(|i| p[i as usize]);
    let e = (b - a)
        .length_squared()
        .max((c - b).length_squared())
        .max((a - c).length_squared());
    cross(p, t).length() <= 1e-7 * e
}

/// Undirected edge → number of triangles using it.
fn edge_counts(tris: &[PrintTri]) -> HashMap<(u32, u32), u32> {
    let mut m = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t.v[k], t.v[(k + 1) % 3]);
            *m.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    m
}

/// The corner colour of triangle `t` at corner `k` (for painting hole fills).
fn corner_colour(mesh: &PrintMesh, t: &PrintTri, k: usize) -> [f32; 3] {
    match t.paint {
        Paint::Texture { tex, uv } => mesh.textures[tex as usize].sample(uv[k]),
        Paint::Solid(c) => c,
    }
}

/// Light repair of `mesh` (see the module doc). Returns the repaired mesh (checked again) and
/// what was done.
pub(crate) fn light_repair(mesh: &PrintMesh, max_hole_mm: f32) -> Result<(PrintMesh, RepairLog)> {
    let mut log = RepairLog::default();
    let mut tris = mesh.tris.clone();
    // 1. Weld what touches (0.01 mm at print scale).
    let (mut pos, map) = weld(&mesh.positions, 0.01);
    log.touch_welded = mesh.positions.len() - pos.len();
    for t in &mut tris {
        t.v = t.v.map(|i| map[i as usize]);
    }
    tris.retain(|t| t.v[0] != t.v[1] && t.v[1] != t.v[2] && t.v[0] != t.v[2]);
    // 2. Duplicates and zero-area triangles.
    let mut seen = HashSet::new();
    let before = tris.len();
    tris.retain(|t| {
        let mut k = t.v;
        k.sort();
        seen.insert(k)
    });
    log.duplicates_removed = before - tris.len();
    let before = tris.len();
    tris.retain(|t| !is_degenerate(&pos, t.v));
    log.degenerate_removed = before - tris.len();
    // 3. T-junctions: split open edges at open vertices lying on them.
    log.tjunctions_split = zip_tjunctions(&pos, &mut tris);
    // 4. Holes.
    fill_holes(mesh, &mut pos, &mut tris, max_hole_mm, &mut log);
    // 5. Open shells facing inward.
    log.open_shells_flipped = orient_open_shells(&pos, &mut tris);
    anyhow::ensure!(!tris.is_empty(), "no triangle is left after repair");
    Ok((rewelded(mesh, &pos, tris)?, log))
}

/// Splits open edges at the open vertices that lie on them (within 0.01 mm), repeatedly.
fn zip_tjunctions(pos: &[Vec3], tris: &mut Vec<PrintTri>) -> usize {
    let mut split = 0;
    for _pass in 0..8 {
        let counts = edge_counts(tris);
        let open: HashSet<u32> = counts
            .iter()
            .filter(|(_, &c)| c == 1)
            .flat_map(|(&(a, b), _)| [a, b])
            .collect();
        if open.is_empty() {
            break;
        }
        // Hash grid of open vertices.
        let lens: Vec<f32> = counts
            .iter()
            .filter(|(_, &c)| c == 1)
            .map(|(&(a, b), _)| pos[a as usize].distance(pos[b as usize]))
            .collect();
        let cell = (lens.iter().sum::<f32>() / lens.len() as f32).max(1e-3);
        let key = |p: Vec3| (p / cell).floor().as_ivec3();
        let mut grid: HashMap<glam::IVec3, Vec<u32>> = HashMap::new();
        for &v in &open {
            grid.entry(key(pos[v as usize])).or_default().push(v);
        }
        let mut changed = false;
        let mut out = Vec::with_capacity(tris.len());
        for t in tris.iter() {
            let mut done = false;
            for k in 0..3 {
                let (a, b, c) = (t.v[k], t.v[(k + 1) % 3], t.v[(k + 2) % 3]);
                if counts[&(a.min(b), a.max(b))] != 1 {
                    continue;
                }
                let (pa, pb) = (pos[a as usize], pos[b as usize]);
                let (lo, hi) = (key(pa.min(pb)), key(pa.max(pb)));
                if (hi - lo).abs().max_element() > 64 {
                    continue;
                }
                let d = pb - pa;
                let mut found: Option<(f32, u32)> = None;
                for x in lo.x..=hi.x {
                    for y in lo.y..=hi.y {
                        for z in lo.z..=hi.z {
                            for &v in grid.get(&glam::IVec3::new(x, y, z)).into_iter().flatten() {
                                if v == a || v == b || v == c {
                                    continue;
                                }
                                let q = pos[v as usize];
                                let s = (q - pa).dot(d) / d.length_squared();
                                if s <= 1e-3 || s >= 1.0 - 1e-3 {
                                    continue;
                                }
                                if (pa + d * s).distance(q) <= 0.01
                                    && found.is_none_or(|(fs, _)| s < fs)
                                {
                                    found = Some((s, v));
                                }
                            }
                        }
                    }
                }
                if let Some((s, v)) = found {
                    // Split t = (a, b, c) into (a, v, c) and (v, b, c), keeping its winding.
                    let (ka, kb, kc) = (k, (k + 1) % 3, (k + 2) % 3);
                    let mut t1 = *t;
                    let mut t2 = *t;
                    t1.v[kb] = v;
                    t2.v[ka] = v;
                    if let (Paint::Texture { uv, .. }, Paint::Texture { uv: u1, .. }) =
                        (t.paint, &mut t1.paint)
                    {
                        u1[kb] = uv[ka].lerp(uv[kb], s);
                    }
                    if let (Paint::Texture { uv, .. }, Paint::Texture { uv: u2, .. }) =
                        (t.paint, &mut t2.paint)
                    {
                        u2[ka] = uv[ka].lerp(uv[kb], s);
                    }
                    let _ = kc;
                    out.push(t1);
                    out.push(t2);
                    split += 1;
                    done = true;
                    changed = true;
                    break;
                }
            }
            if !done {
                out.push(*t);
            }
        }
        *tris = out;
        if !changed {
            break;
        }
    }
    split
}

/// Boundary loops, each in the winding of its triangles (the fill goes the other way).
fn boundary_loops(tris: &[PrintTri]) -> Vec<Vec<(u32, usize)>> {
    let counts = edge_counts(tris);
    // Directed open edge a -> b, with the triangle it belongs to.
    let mut next: HashMap<u32, Vec<(u32, usize)>> = HashMap::new();
    for (ti, t) in tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t.v[k], t.v[(k + 1) % 3]);
            if counts[&(a.min(b), a.max(b))] == 1 {
                next.entry(a).or_default().push((b, ti));
            }
        }
    }
    let mut loops = vec![];
    let starts: Vec<u32> = next.keys().copied().collect();
    for s in starts {
        while let Some((b, ti)) = next.get_mut(&s).and_then(|v| v.pop()) {
            let mut lp = vec![(s, ti)];
            let mut cur = b;
            let mut ok = false;
            for _ in 0..1_000_000 {
                if cur == s {
                    ok = true;
                    break;
                }
                let Some((n, tj)) = next.get_mut(&cur).and_then(|v| v.pop()) else {
                    break;
                };
                lp.push((cur, tj));
                cur = n;
            }
            if ok && lp.len() >= 3 {
                loops.push(lp);
            }
        }
    }
    loops
}

fn fill_holes(
    mesh: &PrintMesh,
    pos: &mut Vec<Vec3>,
    tris: &mut Vec<PrintTri>,
    max_hole_mm: f32,
    log: &mut RepairLog,
) {
    for lp in boundary_loops(tris) {
        let pts: Vec<Vec3> = lp.iter().map(|&(v, _)| pos[v as usize]).collect();
        let perim: f32 = (0..pts.len())
            .map(|i| pts[i].distance(pts[(i + 1) % pts.len()]))
            .sum();
        if perim > max_hole_mm {
            log.holes_left_mm.push(perim);
            continue;
        }
        // Mean colour of the corners around the hole, and a part to assign.
        let mut col = [0.0f32; 3];
        for &(v, ti) in &lp {
            let t = &tris[ti];
            let k = t.v.iter().position(|&x| x == v).unwrap_or(0);
            let c = corner_colour(mesh, t, k);
            for j in 0..3 {
                col[j] += c[j] / lp.len() as f32;
            }
        }
        let part = tris[lp[0].1].part;
        // The fill runs against the loop's direction.
        let ring: Vec<u32> = lp.iter().rev().map(|&(v, _)| v).collect();
        let new = triangulate(pos, &ring);
        log.holes_filled += 1;
        log.hole_triangles += new.len();
        for v in new {
            tris.push(PrintTri {
                v,
                paint: Paint::Solid(col),
                part,
            });
        }
    }
}

/// Ear clipping of a ring in its best-fit (Newell) plane; a fan around an added centroid when
/// no ear can be found (non-simple projection).
fn triangulate(pos: &mut Vec<Vec3>, ring: &[u32]) -> Vec<[u32; 3]> {
    let n = ring.len();
    let p: Vec<Vec3> = ring.iter().map(|&v| pos[v as usize]).collect();
    if n == 3 {
        return vec![[ring[0], ring[1], ring[2]]];
    }
    let mut normal = Vec3::ZERO;
    for i in 0..n {
        let (a, b) = (p[i], p[(i + 1) % n]);
        normal += Vec3::new(
            (a.y - b.y) * (a.z + b.z),
            (a.z - b.z) * (a.x + b.x),
            (a.x - b.x) * (a.y + b.y),
        );
    }
    let normal = normal.normalize_or_zero();
    let u = normal.any_orthonormal_vector();
    let w = normal.cross(u);
    let q: Vec<Vec2> = p.iter().map(|x| Vec2::new(x.dot(u), x.dot(w))).collect();
    let ears = ear_clip(&q, OnEdge::Blocks);
    if ears.len() == n - 2 {
        return ears.iter().map(|t| t.map(|i| ring[i])).collect();
    }
    // Fallback: fan around the centroid of the whole ring.
    let c = p.iter().copied().sum::<Vec3>() / n as f32;
    pos.push(c);
    let ci = pos.len() as u32 - 1;
    (0..n).map(|i| [ring[i], ring[(i + 1) % n], ci]).collect()
}

/// Connected components of triangles through shared edges (union-find).
pub fn components(tris: &[[u32; 3]]) -> Vec<u32> {
    let mut parent: Vec<u32> = (0..tris.len() as u32).collect();
    fn find(p: &mut [u32], mut i: u32) -> u32 {
        while p[i as usize] != i {
            p[i as usize] = p[p[i as usize] as usize];
            i = p[i as usize];
        }
        i
    }
    let mut first: HashMap<(u32, u32), u32> = HashMap::new();
    for (ti, t) in tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let e = (a.min(b), a.max(b));
            match first.get(&e) {
                Some(&o) => {
                    let (x, y) = (find(&mut parent, o), find(&mut parent, ti as u32));
                    parent[x as usize] = y;
                }
                None => {
                    first.insert(e, ti as u32);
                }
            }
        }
    }
    let mut ids: HashMap<u32, u32> = HashMap::new();
    (0..tris.len() as u32)
        .map(|i| {
            let r = find(&mut parent, i);
            let n = ids.len() as u32;
            *ids.entry(r).or_insert(n)
        })
        .collect()
}

/// Flips open components whose volume about their own centroid is clearly negative.
pub(crate) fn orient_open_shells(pos: &[Vec3], tris: &mut [PrintTri]) -> usize {
    let counts = edge_counts(tris);
    let comp = components(&tris.iter().map(|t| t.v).collect::<Vec<_>>());
    let nc = comp.iter().max().map_or(0, |&m| m as usize + 1);
    let mut open = vec![false; nc];
    let mut centroid = vec![(Vec3::ZERO, 0.0f32); nc];
    for (ti, t) in tris.iter().enumerate() {
        let c = comp[ti] as usize;
        for k in 0..3 {
            let (a, b) = (t.v[k], t.v[(k + 1) % 3]);
            if counts[&(a.min(b), a.max(b))] == 1 {
                open[c] = true;
            }
        }
        let area = cross(pos, t.v).length();
        let [a, b, cc] = t.v.map(|i| pos[i as usize]);
        centroid[c].0 += (a + b + cc) / 3.0 * area;
        centroid[c].1 += area;
    }
    let mut vol = vec![(0.0f64, 0.0f64); nc];
    for (ti, t) in tris.iter().enumerate() {
        let c = comp[ti] as usize;
        let o = centroid[c].0 / centroid[c].1.max(1e-30);
        let [a, b, cc] = t.v.map(|i| (pos[i as usize] - o).as_dvec3());
        let v = a.dot(b.cross(cc)) / 6.0;
        vol[c].0 += v;
        vol[c].1 += v.abs();
    }
    let flip: Vec<bool> = (0..nc)
        .map(|c| open[c] && vol[c].0 < -0.2 * vol[c].1)
        .collect();
    let mut n = 0;
    for (ti, t) in tris.iter_mut().enumerate() {
        if flip[comp[ti] as usize] {
            t.v.swap(1, 2);
            if let Paint::Texture { uv, .. } = &mut t.paint {
                uv.swap(1, 2);
            }
        }
    }
    for f in flip {
        n += f as usize;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::PrintReport;

    /// A 10 mm cube of split faces, with face `drop` missing (or none).
    fn cube_mesh(drop: Option<usize>) -> PrintMesh {
        use crate::fixtures::{corner, CUBE_QUADS as quads};
        let c = |i: u32| corner(i) * 10.0;
        let (mut p, mut t) = (vec![], vec![]);
        for (qi, q) in quads.iter().enumerate() {
            if Some(qi) == drop {
                continue;
            }
            let b = p.len() as u32;
            p.extend(q.iter().map(|&i| c(i)));
            for v in [[b, b + 1, b + 2], [b, b + 2, b + 3]] {
                t.push(PrintTri {
                    v,
                    paint: Paint::Solid([0.5, 0.2, 0.1]),
                    part: 0,
                });
            }
        }
        crate::fixtures::print_mesh("cube", &p, t)
    }

    #[test]
    fn missing_face_is_filled_and_closed() {
        let m = cube_mesh(Some(3));
        assert_eq!(m.report.open_edges, 4);
        let (r, log) = light_repair(&m, 100.0).unwrap();
        assert!(r.report.is_closed(), "{:?}", r.report);
        assert_eq!(log.holes_filled, 1);
        assert!((r.report.volume_mm3 - 1000.0).abs() < 1e-2);
        // Too small a limit leaves it open.
        let (r, log) = light_repair(&m, 10.0).unwrap();
        assert!(!r.report.is_closed());
        assert_eq!(log.holes_left_mm, vec![40.0]);
    }

    #[test]
    fn duplicates_and_tjunctions_are_repaired() {
        let mut m = cube_mesh(None);
        let _ = PrintReport::default();
        m.tris.push(m.tris[0]);
        // Split one face's triangle at an edge midpoint on one side only: a T-junction.
        let (p0, p1) = (m.tris[2].v[0], m.tris[2].v[1]);
        let mid = (m.positions[p0 as usize] + m.positions[p1 as usize]) * 0.5;
        m.positions.push(mid);
        let v = m.positions.len() as u32 - 1;
        let mut a = m.tris[2];
        let mut b = m.tris[2];
        a.v[1] = v;
        b.v[0] = v;
        m.tris[2] = a;
        m.tris.push(b);
        let (r, log) = light_repair(&m, 1.0).unwrap();
        assert_eq!(log.duplicates_removed, 1);
        assert_eq!(log.tjunctions_split, 1);
        assert!(r.report.is_closed(), "{:?} {log:?}", r.report);
    }
}
