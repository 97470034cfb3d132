//! Meshes the export modules' unit tests share.

use crate::mesh::{PrintMesh, PrintTri};
use crate::printcheck;
use glam::Vec3;

/// The unit cube's six faces, outward, as corner indices (see [`corner`]).
pub use cac_scene::BOX_QUADS as CUBE_QUADS;

/// Corner `i` of the unit cube: `(i & 1, i >> 1 & 1, i >> 2 & 1)`.
pub fn corner(i: u32) -> Vec3 {
    Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32)
}

/// A one-part mesh of `tris` over `positions`, welded and checked as the exporter does.
pub fn print_mesh(name: &str, positions: &[Vec3], mut tris: Vec<PrintTri>) -> PrintMesh {
    let (positions, report) = printcheck::weld_and_check(positions, &mut tris).unwrap();
    PrintMesh {
        name: name.into(),
        positions,
        tris,
        textures: vec![],
        parts: vec!["body".into()],
        painted: vec![false],
        report,
    }
}

/// A closed, outward cube (12 triangles) of side `s` at `o`.
pub fn cube(s: f32, o: Vec3) -> Vec<[Vec3; 3]> {
    cuboid(o, o + Vec3::splat(s), &[])
}

/// The box from `lo` to `hi` as outward triangles, without the faces whose indices into
/// [`CUBE_QUADS`] are in `skip`.
pub fn cuboid(lo: Vec3, hi: Vec3, skip: &[usize]) -> Vec<[Vec3; 3]> {
    let c = |i: u32| lo + corner(i) * (hi - lo);
    CUBE_QUADS
        .iter()
        .enumerate()
        .filter(|(k, _)| !skip.contains(k))
        .flat_map(|(_, q)| [[c(q[0]), c(q[1]), c(q[2])], [c(q[0]), c(q[2]), c(q[3])]])
        .collect()
}
