//! Printability at the chosen scale: which triangles bound the object's volume and which are
//! single-sided sheets (generalised winding number on both sides of each triangle), the local
//! wall thickness (a ray cast inward from each boundary triangle until it leaves the union of
//! the object's volumes, so overlapping parts count as one), regions thinner than the printer's
//! minimum wall grouped and located in mm, parts smaller than the minimum feature, parts that
//! float above the build plate, and the fit in the printer's build volume.

use crate::mesh::PrintMesh;
use crate::repair::components;
use crate::surface::SurfaceIndex;
use anyhow::{bail, Result};
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;
use std::str::FromStr;

/// What to do with regions thinner than the minimum wall (`--thin`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum ThinPolicy {
    /// Rebuild them at least the minimum wall thick (solidify).
    Thicken,
    /// Leave them out of the solid, with a warning.
    Drop,
    /// Refuse to write geometry, listing them.
    Refuse,
}

impl FromStr for ThinPolicy {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        Ok(match s {
            "thicken" => ThinPolicy::Thicken,
            "drop" => ThinPolicy::Drop,
            "refuse" => ThinPolicy::Refuse,
            o => bail!("unknown --thin '{o}' (expected thicken, drop or refuse)"),
        })
    }
}

/// What each triangle is to the object's volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum TriKind {
    /// Inside on its back, outside on its front: part of the solid's boundary.
    Boundary,
    /// Outside on both sides: a single-sided surface (glass, plates) with no volume.
    Sheet,
    /// Inside on both sides: hidden inside the union of overlapping parts.
    Internal,
}

/// The printer and the checks' limits, in mm at print scale.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PrintLimits {
    /// Thinnest wall the printer makes.
    pub min_wall_mm: f32,
    /// Smallest part (largest extent) worth printing.
    pub min_feature_mm: f32,
    /// Build volume (x, y, z); `None`: unchecked.
    pub build_volume_mm: Option<[f32; 3]>,
    pub thin: ThinPolicy,
}

impl Default for PrintLimits {
    fn default() -> Self {
        PrintLimits {
            min_wall_mm: 0.8,
            min_feature_mm: 1.0,
            build_volume_mm: Some([256.0, 256.0, 256.0]),
            thin: ThinPolicy::Thicken,
        }
    }
}

/// A printer's build volume as a command line writes it: `XxYxZ` in mm (`256x256x256`), or
/// `none` (unchecked).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildVolume(pub Option<[f32; 3]>);

impl std::str::FromStr for BuildVolume {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> anyhow::Result<BuildVolume> {
        if s.trim().eq_ignore_ascii_case("none") {
            return Ok(BuildVolume(None));
        }
        let v: Vec<f32> = s
            .split(['x', 'X'])
            .map(|x| x.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| {
                anyhow::anyhow!(
                    "build volume '{s}': expected XxYxZ in mm, e.g. 256x256x256, or none"
                )
            })?;
        anyhow::ensure!(
            v.len() == 3 && v.iter().all(|x| *x > 0.0 && x.is_finite()),
            "build volume '{s}': expected three positive sizes XxYxZ in mm"
        );
        Ok(BuildVolume(Some([v[0], v[1], v[2]])))
    }
}

/// The triangles' corners, for building an index.
pub fn corners(mesh: &PrintMesh, which: impl Fn(usize) -> bool) -> (Vec<[Vec3; 3]>, Vec<u32>) {
    let mut t = vec![];
    let mut ids = vec![];
    for (i, tr) in mesh.tris.iter().enumerate() {
        if which(i) {
            t.push(tr.v.map(|k| mesh.positions[k as usize]));
            ids.push(i as u32);
        }
    }
    (t, ids)
}

fn normal(t: &[Vec3; 3]) -> (Vec3, Vec3, f32) {
    let cr = (t[1] - t[0]).cross(t[2] - t[0]);
    let c = (t[0] + t[1] + t[2]) / 3.0;
    (c, cr.normalize_or_zero(), 0.5 * cr.length())
}

/// Classifies each triangle by the winding number of the whole mesh `delta` mm behind and in
/// front of its centroid.
pub fn classify(mesh: &PrintMesh, all: &SurfaceIndex, delta: f32) -> Vec<TriKind> {
    mesh.tris
        .par_iter()
        .map(|t| {
            let (c, n, _) = normal(&t.v.map(|k| mesh.positions[k as usize]));
            if n == Vec3::ZERO {
                return TriKind::Internal;
            }
            let back = all.winding(c - n * delta) > 0.5;
            let front = all.winding(c + n * delta) > 0.5;
            match (back, front) {
                (true, true) => TriKind::Internal,
                (false, false) => TriKind::Sheet,
                _ => TriKind::Boundary,
            }
        })
        .collect()
}

/// Wall thickness behind each boundary triangle, measured up to `max` mm (`f32::INFINITY` when
/// thicker): rays go inward from the centroid and continue through internal faces until the
/// point beyond the hit is outside the union (`vol`'s winding number below ½).
pub fn thickness(mesh: &PrintMesh, kinds: &[TriKind], vol: &SurfaceIndex, max: f32) -> Vec<f32> {
    let eps = (max * 1e-3).max(1e-5);
    mesh.tris
        .par_iter()
        .zip(kinds)
        .map(|(t, k)| {
            match k {
                TriKind::Sheet => return 0.0,
                TriKind::Internal => return f32::INFINITY,
                TriKind::Boundary => {}
            }
            let (c, n, _) = normal(&t.v.map(|i| mesh.positions[i as usize]));
            let dir = -n;
            let mut from = eps;
            for _ in 0..6 {
                let Some((t_hit, _)) = vol.ray(c, dir, from, max) else {
                    return f32::INFINITY;
                };
                let beyond = c + dir * (t_hit + eps * 4.0);
                if vol.winding(beyond) < 0.5 {
                    return t_hit;
                }
                from = t_hit + eps * 4.0;
            }
            f32::INFINITY
        })
        .collect()
}

/// A connected region of thin triangles, located at print scale.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ThinRegion {
    pub triangles: usize,
    pub area_mm2: f64,
    /// Thinnest measured wall (0 for a single-sided surface).
    pub min_thickness_mm: f32,
    pub centre_mm: [f32; 3],
    pub min_mm: [f32; 3],
    pub max_mm: [f32; 3],
    /// Names of the parts (materials) it belongs to.
    pub parts: Vec<String>,
}

impl ThinRegion {
    pub fn describe(&self) -> String {
        let what = if self.min_thickness_mm == 0.0 {
            "single-sided surface (no thickness)".to_string()
        } else {
            format!("wall {:.2} mm thick", self.min_thickness_mm)
        };
        format!(
            "{what}, {:.1} mm2 of {} at ({:.1}, {:.1}, {:.1}) mm [box ({:.1}, {:.1}, {:.1})-({:.1}, {:.1}, {:.1}) mm]",
            self.area_mm2,
            self.parts.join("/"),
            self.centre_mm[0],
            self.centre_mm[1],
            self.centre_mm[2],
            self.min_mm[0],
            self.min_mm[1],
            self.min_mm[2],
            self.max_mm[0],
            self.max_mm[1],
            self.max_mm[2]
        )
    }
}

/// Groups triangles flagged `thin` into regions connected through shared edges, largest first.
pub fn regions(mesh: &PrintMesh, thin: &[bool], thick: &[f32]) -> Vec<ThinRegion> {
    let idx: Vec<usize> = (0..mesh.tris.len()).filter(|&i| thin[i]).collect();
    let comp = components(&idx.iter().map(|&i| mesh.tris[i].v).collect::<Vec<_>>());
    let n = comp.iter().max().map_or(0, |&m| m as usize + 1);
    let mut out: Vec<(ThinRegion, Vec3)> = (0..n)
        .map(|_| {
            (
                ThinRegion {
                    triangles: 0,
                    area_mm2: 0.0,
                    min_thickness_mm: f32::INFINITY,
                    centre_mm: [0.0; 3],
                    min_mm: [f32::MAX; 3],
                    max_mm: [f32::MIN; 3],
                    parts: vec![],
                },
                Vec3::ZERO,
            )
        })
        .collect();
    for (j, &i) in idx.iter().enumerate() {
        let t = &mesh.tris[i];
        let p = t.v.map(|k| mesh.positions[k as usize]);
        let (c, _, a) = normal(&p);
        let (r, acc) = &mut out[comp[j] as usize];
        r.triangles += 1;
        r.area_mm2 += a as f64;
        *acc += c * a;
        r.min_thickness_mm = r.min_thickness_mm.min(thick[i]);
        for q in p {
            r.min_mm = Vec3::from(r.min_mm).min(q).to_array();
            r.max_mm = Vec3::from(r.max_mm).max(q).to_array();
        }
        let name = &mesh.parts[t.part as usize];
        if !r.parts.contains(name) {
            r.parts.push(name.clone());
        }
    }
    let mut regs: Vec<ThinRegion> = out
        .into_iter()
        .map(|(mut r, acc)| {
            r.centre_mm = (acc / (r.area_mm2 as f32).max(1e-30)).to_array();
            if r.area_mm2 <= 0.0 {
                r.centre_mm = ((Vec3::from(r.min_mm) + Vec3::from(r.max_mm)) * 0.5).to_array();
            }
            r
        })
        .collect();
    regs.sort_by(|a, b| b.area_mm2.total_cmp(&a.area_mm2));
    regs
}

/// One connected part of the printed mesh.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Part {
    pub triangles: usize,
    pub min_mm: [f32; 3],
    pub max_mm: [f32; 3],
}

impl Part {
    pub fn extent(&self) -> f32 {
        (Vec3::from(self.max_mm) - Vec3::from(self.min_mm)).max_element()
    }
    pub fn describe(&self) -> String {
        format!(
            "{} triangles, ({:.1}, {:.1}, {:.1})-({:.1}, {:.1}, {:.1}) mm",
            self.triangles,
            self.min_mm[0],
            self.min_mm[1],
            self.min_mm[2],
            self.max_mm[0],
            self.max_mm[1],
            self.max_mm[2]
        )
    }
}

/// The printability report of the mesh that is written.
#[derive(Clone, Debug, Serialize, PartialEq, Default)]
pub struct Printability {
    pub min_wall_mm: f32,
    pub sheet_triangles: usize,
    pub internal_triangles: usize,
    /// Regions thinner than the minimum wall (largest first).
    pub thin_regions: Vec<ThinRegion>,
    /// Separate parts (through shared edges).
    pub parts: usize,
    /// Parts whose lowest point is above the build plate (z = lowest point of the object).
    pub floating: Vec<Part>,
    /// Parts smaller than the minimum feature.
    pub tiny: Vec<Part>,
    /// Thin strips discounted as surface relief (see [`analyse`]).
    pub relief_regions: usize,
    pub size_mm: [f32; 3],
    /// `Some(false)` when the object does not fit the build volume (even turned 90° about Z).
    pub fits_build_volume: Option<bool>,
    pub build_volume_mm: Option<[f32; 3]>,
}

impl Printability {
    /// The check in words (one line per finding).
    pub fn lines(&self) -> Vec<String> {
        let mut v = vec![format!(
            "printability: {} parts, size {:.1} x {:.1} x {:.1} mm, {} regions thinner than {:.2} mm ({} thin strips of surface relief printed as they are), {} floating",
            self.parts,
            self.size_mm[0],
            self.size_mm[1],
            self.size_mm[2],
            self.thin_regions.len(),
            self.min_wall_mm,
            self.relief_regions,
            self.floating.len()
        )];
        for r in self.thin_regions.iter().take(8) {
            v.push(format!("  thin: {}", r.describe()));
        }
        if self.thin_regions.len() > 8 {
            v.push(format!("  ... and {} more", self.thin_regions.len() - 8));
        }
        for p in self.floating.iter().take(8) {
            v.push(format!(
                "  floating part (needs supports): {} ({:.1} mm above the plate)",
                p.describe(),
                p.min_mm[2]
            ));
        }
        for p in self.tiny.iter().take(8) {
            v.push(format!(
                "  part smaller than the minimum feature: {}",
                p.describe()
            ));
        }
        if let (Some(false), Some(b)) = (self.fits_build_volume, self.build_volume_mm) {
            v.push(format!(
                "  does not fit the build volume {} x {} x {} mm",
                b[0], b[1], b[2]
            ));
        }
        v
    }
}

/// Parts of a mesh (connected through shared edges) with their boxes.
pub fn parts(mesh: &PrintMesh) -> Vec<Part> {
    let comp = components(&mesh.tris.iter().map(|t| t.v).collect::<Vec<_>>());
    let n = comp.iter().max().map_or(0, |&m| m as usize + 1);
    let mut out = vec![
        Part {
            triangles: 0,
            min_mm: [f32::MAX; 3],
            max_mm: [f32::MIN; 3],
        };
        n
    ];
    for (t, &c) in mesh.tris.iter().zip(&comp) {
        let p = &mut out[c as usize];
        p.triangles += 1;
        for k in t.v {
            let q = mesh.positions[k as usize];
            p.min_mm = Vec3::from(p.min_mm).min(q).to_array();
            p.max_mm = Vec3::from(p.max_mm).max(q).to_array();
        }
    }
    out
}

/// Does `size` fit `vol` as it is or turned 90° about Z?
pub fn fits(size: [f32; 3], vol: [f32; 3]) -> bool {
    let ok = |a: f32, b: f32| a <= b + 1e-3;
    ok(size[2], vol[2])
        && ((ok(size[0], vol[0]) && ok(size[1], vol[1]))
            || (ok(size[0], vol[1]) && ok(size[1], vol[0])))
}

/// Classification, thickness and the per-triangle thin flags of a mesh.
pub struct Analysis {
    pub kinds: Vec<TriKind>,
    pub thickness: Vec<f32>,
    pub thin: Vec<bool>,
    /// Thin regions discounted as surface relief.
    pub relief: usize,
}

/// Classifies and measures every triangle of `mesh` against `min_wall` (mm).
pub fn analyse(mesh: &PrintMesh, min_wall: f32) -> Analysis {
    let (all, _) = corners(mesh, |_| true);
    let all = SurfaceIndex::new(all);
    let diag = Vec3::from(mesh.report.size_mm).length().max(1e-6);
    let delta = (min_wall * 0.05).min(diag * 1e-4).max(1e-5);
    let kinds = classify(mesh, &all, delta);
    let (vt, _) = corners(mesh, |i| kinds[i] != TriKind::Sheet);
    let vol = SurfaceIndex::new(vt);
    let thickness = thickness(mesh, &kinds, &vol, min_wall);
    let mut thin: Vec<bool> = thickness.iter().map(|&t| t < min_wall).collect();
    let relief = drop_relief(mesh, &mut thin, min_wall);
    Analysis {
        kinds,
        thickness,
        thin,
        relief,
    }
}

/// Unflags thin regions that are narrow strips (area over box diagonal below the minimum wall):
/// the flanks of surface relief such as a trim line standing 0.2 mm proud of a body, which a
/// printer renders as well as it can and which are no wall that could break. Returns how many.
fn drop_relief(mesh: &PrintMesh, thin: &mut [bool], min_wall: f32) -> usize {
    let idx: Vec<usize> = (0..mesh.tris.len()).filter(|&i| thin[i]).collect();
    let comp = components(&idx.iter().map(|&i| mesh.tris[i].v).collect::<Vec<_>>());
    let n = comp.iter().max().map_or(0, |&m| m as usize + 1);
    let mut area = vec![0.0f32; n];
    let mut bb = vec![(Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)); n];
    for (j, &i) in idx.iter().enumerate() {
        let p = mesh.tris[i].v.map(|k| mesh.positions[k as usize]);
        let c = comp[j] as usize;
        area[c] += normal(&p).2;
        for q in p {
            bb[c].0 = bb[c].0.min(q);
            bb[c].1 = bb[c].1.max(q);
        }
    }
    let relief: Vec<bool> = (0..n)
        .map(|c| {
            let diag = (bb[c].1 - bb[c].0).length().max(1e-9);
            area[c] / diag < min_wall
        })
        .collect();
    for (j, &i) in idx.iter().enumerate() {
        if relief[comp[j] as usize] {
            thin[i] = false;
        }
    }
    relief.iter().filter(|&&r| r).count()
}

/// The full printability check of the mesh to be written.
pub fn check(mesh: &PrintMesh, a: &Analysis, limits: &PrintLimits) -> Printability {
    let ps = parts(mesh);
    let ground = ps.iter().map(|p| p.min_mm[2]).fold(f32::MAX, f32::min);
    let tol = (limits.min_wall_mm * 0.5).max(0.05);
    // Grounded: on the plate, or (transitively) overlapping a grounded part's box.
    let mut grounded: Vec<bool> = ps.iter().map(|p| p.min_mm[2] <= ground + tol).collect();
    loop {
        let mut changed = false;
        for i in 0..ps.len() {
            if grounded[i] {
                continue;
            }
            let touches = (0..ps.len()).any(|j| {
                grounded[j]
                    && (0..3).all(|k| {
                        ps[i].min_mm[k] <= ps[j].max_mm[k] + tol
                            && ps[j].min_mm[k] <= ps[i].max_mm[k] + tol
                    })
            });
            if touches {
                grounded[i] = true;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let floating = ps
        .iter()
        .zip(&grounded)
        .filter(|(_, &g)| !g)
        .map(|(p, _)| p)
        .cloned()
        .map(|mut p| {
            // Heights relative to the plate.
            p.min_mm[2] -= ground;
            p.max_mm[2] -= ground;
            p
        })
        .collect();
    let tiny = ps
        .iter()
        .filter(|p| p.extent() < limits.min_feature_mm)
        .cloned()
        .collect();
    let size = mesh.report.size_mm;
    Printability {
        min_wall_mm: limits.min_wall_mm,
        sheet_triangles: a.kinds.iter().filter(|&&k| k == TriKind::Sheet).count(),
        internal_triangles: a.kinds.iter().filter(|&&k| k == TriKind::Internal).count(),
        thin_regions: regions(mesh, &a.thin, &a.thickness),
        parts: ps.len(),
        floating,
        tiny,
        relief_regions: a.relief,
        size_mm: size,
        fits_build_volume: limits.build_volume_mm.map(|v| fits(size, v)),
        build_volume_mm: limits.build_volume_mm,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn build_volumes_parse_or_are_refused_with_the_text() {
        let v = |s: &str| s.parse::<BuildVolume>();
        assert_eq!(v("256x256x256").unwrap(), BuildVolume(Some([256.0; 3])));
        assert_eq!(v("180X180x 180").unwrap(), BuildVolume(Some([180.0; 3])));
        assert_eq!(v("none").unwrap(), BuildVolume(None));
        for bad in ["256x256", "0x1x1", "ax1x1", "inf x1x1", "-1x2x3", ""] {
            let e = v(bad).unwrap_err().to_string();
            assert!(e.contains(&format!("'{bad}'")), "{bad}: {e}");
        }
    }

    #[test]
    fn build_volume_fit_allows_a_quarter_turn() {
        assert!(fits([250.0, 100.0, 100.0], [256.0, 256.0, 256.0]));
        assert!(fits([100.0, 250.0, 50.0], [250.0, 210.0, 210.0]));
        assert!(!fits([300.0, 100.0, 100.0], [256.0, 256.0, 256.0]));
        assert!(!fits([100.0, 100.0, 300.0], [256.0, 256.0, 256.0]));
    }
}
