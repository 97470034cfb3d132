//! The print mesh and its parts: the scale it is made at, the welded triangles with their paint,
//! the parts, and the print check's report ([`crate::printcheck`] fills it in).

use anyhow::{ensure, Context, Result};
use cac_scene::Texture;
use glam::{Vec2, Vec3};
use serde::Serialize;
use std::str::FromStr;

/// The object scale `1:N` (the printed object is `N` times smaller than the real one).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Scale {
    pub denominator: f64,
}

impl Scale {
    /// Millimetres on the print per metre of the real object.
    pub(crate) fn mm_per_m(&self) -> f64 {
        1000.0 / self.denominator
    }
}

impl FromStr for Scale {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Scale> {
        let (num, den) = match s.split_once(':') {
            Some((a, b)) => (a.trim(), b.trim()),
            None => ("1", s.trim()),
        };
        let num: f64 = num
            .parse()
            .with_context(|| format!("scale '{s}': '{num}' is not a number (expected 1:N)"))?;
        let den: f64 = den
            .parse()
            .with_context(|| format!("scale '{s}': '{den}' is not a number (expected 1:N)"))?;
        ensure!(
            num.is_finite() && den.is_finite() && num > 0.0 && den > 0.0,
            "scale '{s}' must be 1:N with N > 0 (a zero or negative scale has no size)"
        );
        Ok(Scale {
            denominator: den / num,
        })
    }
}

/// How one triangle corner set is coloured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Paint {
    /// Texture `tex` of [`PrintMesh::textures`] at per-corner UVs (origin lower-left, v up).
    Texture { tex: u32, uv: [Vec2; 3] },
    /// One sRGB colour.
    Solid([f32; 3]),
}

/// One printable triangle: welded vertex indices (counter-clockwise seen from outside).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrintTri {
    pub v: [u32; 3],
    pub paint: Paint,
    /// Index into [`PrintMesh::parts`].
    pub part: u32,
}

/// A mesh ready for the writers: millimetres, +Z up, welded, checked.
#[derive(Clone, Debug)]
pub struct PrintMesh {
    pub name: String,
    pub positions: Vec<Vec3>,
    pub tris: Vec<PrintTri>,
    /// Final colours (display sRGB); texture 0 is the camouflage. Other parts' textures already
    /// include their material's base colour.
    pub textures: Vec<Texture>,
    /// Part (material) names.
    pub parts: Vec<String>,
    /// Per part: painted with the camouflage?
    pub painted: Vec<bool>,
    pub report: PrintReport,
}

impl PrintMesh {
    /// The corner UVs of triangle `t` if it is textured with texture 0 (the camouflage).
    pub fn camo_uv(&self, t: &PrintTri) -> Option<[Vec2; 3]> {
        match t.paint {
            Paint::Texture { tex: 0, uv } => Some(uv),
            _ => None,
        }
    }
}

/// What the check found and what it repaired.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct PrintReport {
    pub input_vertices: usize,
    pub welded_vertices: usize,
    pub weld_epsilon_mm: f32,
    pub triangles: usize,
    /// Triangles removed because two corners welded together (repair).
    pub collapsed_removed: usize,
    /// Zero-area triangles with three distinct corners (refused).
    pub degenerate: usize,
    /// Edges used by one triangle only.
    pub open_edges: usize,
    /// Edges used by more than two triangles.
    pub nonmanifold_edges: usize,
    /// Connected shells (through manifold edges).
    pub shells: usize,
    /// Triangles flipped to agree with their shell (repair).
    pub reoriented_triangles: usize,
    /// Closed shells turned outward (repair).
    pub flipped_shells: usize,
    pub non_orientable_shells: usize,
    /// Enclosed volume (sum over shells of the signed volume), mm³.
    pub volume_mm3: f64,
    pub area_mm2: f64,
    /// Bounding box size (x, y, z) in mm.
    pub size_mm: [f32; 3],
    /// Up to 5 open or non-manifold edges, as their end points in mm (for the error message).
    pub example_edges: Vec<[[f32; 3]; 2]>,
}

impl PrintReport {
    /// Closed, manifold, oriented, no degenerate triangles.
    pub fn is_closed(&self) -> bool {
        self.open_edges == 0
            && self.nonmanifold_edges == 0
            && self.degenerate == 0
            && self.non_orientable_shells == 0
    }

    /// The refusal reasons, in words.
    pub fn problems(&self) -> String {
        let mut p = vec![];
        if self.open_edges > 0 {
            p.push(format!("{} open edges (holes)", self.open_edges));
        }
        if self.nonmanifold_edges > 0 {
            p.push(format!(
                "{} non-manifold edges (shared by more than two triangles)",
                self.nonmanifold_edges
            ));
        }
        if self.degenerate > 0 {
            p.push(format!("{} zero-area triangles", self.degenerate));
        }
        if self.non_orientable_shells > 0 {
            p.push(format!(
                "{} non-orientable shells",
                self.non_orientable_shells
            ));
        }
        let mut s = p.join(", ");
        if !self.example_edges.is_empty() {
            let ex: Vec<String> = self
                .example_edges
                .iter()
                .map(|[a, b]| {
                    format!(
                        "({:.2}, {:.2}, {:.2})-({:.2}, {:.2}, {:.2}) mm",
                        a[0], a[1], a[2], b[0], b[1], b[2]
                    )
                })
                .collect();
            s += &format!("; e.g. edges {}", ex.join(", "));
        }
        s
    }

    /// What was repaired, in words.
    pub(crate) fn repairs(&self) -> Vec<String> {
        let mut r = vec![];
        if self.input_vertices != self.welded_vertices {
            r.push(format!(
                "welded {} vertices into {} (tolerance {:.1e} mm)",
                self.input_vertices, self.welded_vertices, self.weld_epsilon_mm
            ));
        }
        if self.collapsed_removed > 0 {
            r.push(format!(
                "repaired: removed {} triangles that collapsed when welding",
                self.collapsed_removed
            ));
        }
        if self.reoriented_triangles > 0 {
            r.push(format!(
                "repaired: flipped {} triangles to agree with their neighbours",
                self.reoriented_triangles
            ));
        }
        if self.flipped_shells > 0 {
            r.push(format!(
                "repaired: turned {} inside-out shells outward",
                self.flipped_shells
            ));
        }
        r
    }
}

/// A file-name-safe stem.
pub(crate) fn sanitize(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "object".into()
    } else {
        s
    }
}
