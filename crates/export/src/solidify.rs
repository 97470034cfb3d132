//! Solidification: rebuilds a mesh that light repair cannot fix (intersecting shells, open parts,
//! single-sided panels, non-manifold edges, walls thinner than the printer's minimum) as one
//! watertight, outward-facing, manifold solid, keeping the colours. A point is inside when the
//! generalised winding number of the volume-bounding triangles is above ½ (so intersecting
//! shells are united and holes are spanned by the winding number's minimal "soap film") or, for
//! `--thin thicken`, when it is closer than half the minimum wall to a thin or single-sided
//! triangle (see [`super::printability`]). That inside test is sampled on a grid of `voxel_mm`
//! spacing at print scale, sparsely: the grid is cut into blocks of 4³ cells, and a block is
//! evaluated only when a surface is within its radius, its corners disagree, or the face it
//! shares with an evaluated block has points on both sides (so every face the surface crosses
//! is evaluated from both sides, and the sparse surface stays closed); the surface is
//! extracted with marching cubes (the `marching-cubes` crate's Bourke case tables, driven here
//! with one shared vertex per grid edge, so the result is welded and closed), each vertex placed
//! where the edge meets an original triangle (a ray cast) when it does, otherwise by
//! interpolating the winding number or the distance. Each new triangle takes its paint from the
//! original triangle closest to its centroid, with per-corner UVs at the closest points of that
//! triangle, so the textured and baked writers work on it unchanged.

use crate::mesh::{Paint, PrintMesh, PrintTri};
use crate::printability::{corners, Analysis, ThinPolicy, TriKind};
use crate::printcheck::rewelded;
use crate::surface::{closest_on_triangle, SurfaceIndex};
use anyhow::{bail, Result};
use cac_core::memory::MemoryBudget;
use glam::{IVec3, Vec3};
use marching_cubes::tables::{EDGE_TABLE, TRI_TABLE};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::HashMap;
use std::time::Instant;

/// Cells per block side.
const B: i32 = 4;

/// How to solidify.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SolidifyOptions {
    /// Grid spacing at print scale (mm).
    pub voxel_mm: f32,
    pub min_wall_mm: f32,
    pub thin: ThinPolicy,
    /// The solid's estimate ([`estimate_bytes`]) must fit this.
    pub memory: MemoryBudget,
}

/// Memory per output triangle through solidify and the weld that follows: measured on the jeep
/// at 1:24 (`cac bench export --solid-voxels 0.8,0.4,0.2`: 144, 538 and 1970 MB peak for 0.24,
/// 0.98 and 3.94 M triangles, about 500 bytes each).
pub(crate) const BYTES_PER_SOLID_TRIANGLE: u64 = 500;

/// An upper estimate of the solid's memory before its grid is evaluated: marching cubes makes
/// at most two triangles per crossed cell and a surface of area `A` crosses at most `√3 A / h²`
/// cells (an axis-aligned one `A / h²`); thickened triangles count for both sides of their slab.
/// Plus a byte per coarse grid point and 12 per block.
pub(crate) fn estimate_bytes(
    volume: &[[Vec3; 3]],
    thin: &[[Vec3; 3]],
    h: f32,
    coarse_points: u64,
) -> u64 {
    let area = |t: &[[Vec3; 3]]| -> f64 {
        t.iter()
            .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length() as f64)
            .sum()
    };
    let a = area(volume) + 2.0 * area(thin);
    let triangles = 2.0 * 3f64.sqrt() * a / (h as f64 * h as f64);
    let bytes = triangles * BYTES_PER_SOLID_TRIANGLE as f64 + 13.0 * coarse_points as f64;
    bytes.min(u64::MAX as f64 / 2.0) as u64
}

/// What solidification did and measured.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct SolidifyReport {
    pub voxel_mm: f32,
    /// Grid points per axis.
    pub grid: [usize; 3],
    pub blocks: usize,
    pub blocks_evaluated: usize,
    /// Of those, blocks evaluated only because an evaluated neighbour's shared face has
    /// crossings (a surface far from every input triangle, such as a hole's film).
    pub blocks_added: usize,
    /// Grid points where the winding number was computed.
    pub points_evaluated: usize,
    /// The volume triangles were closed (winding numbers only near the surface).
    pub closed_input: bool,
    pub sheet_triangles: usize,
    pub thickened_triangles: usize,
    pub dropped_triangles: usize,
    pub triangles: usize,
    pub seconds: f64,
}

impl SolidifyReport {
    pub fn note(&self) -> String {
        let added = if self.blocks_added > 0 {
            format!(
                ", {} of them across faces the surface crosses",
                self.blocks_added
            )
        } else {
            String::new()
        };
        format!(
            "solidified: voxel {:.3} mm, grid {}x{}x{} ({} of {} blocks evaluated{}), {} triangles, {} single-sided and thin triangles thickened, {} dropped, {:.1} s",
            self.voxel_mm,
            self.grid[0],
            self.grid[1],
            self.grid[2],
            self.blocks_evaluated,
            self.blocks,
            added,
            self.triangles,
            self.thickened_triangles,
            self.dropped_triangles,
            self.seconds
        )
    }
}

/// Corner offsets of a cell in the case tables' numbering.
const CORNER: [[i32; 3]; 8] = [
    [0, 0, 0],
    [1, 0, 0],
    [1, 1, 0],
    [0, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [1, 1, 1],
    [0, 1, 1],
];
/// Edges as corner pairs, in the case tables' numbering.
const EDGE: [[usize; 2]; 12] = [
    [0, 1],
    [1, 2],
    [2, 3],
    [3, 0],
    [4, 5],
    [5, 6],
    [6, 7],
    [7, 4],
    [0, 4],
    [1, 5],
    [2, 6],
    [3, 7],
];

/// The inside test sampled at one grid point.
#[derive(Clone, Copy)]
struct Sample {
    /// Winding number of the volume triangles.
    w: f32,
    /// Distance to the thin set minus half the minimum wall (positive when none).
    g: f32,
}

impl Sample {
    fn inside(&self) -> bool {
        self.w > 0.5 || self.g < 0.0
    }
}

struct Field<'a> {
    /// The volume triangles are closed (every edge used an even number of times): the winding
    /// number is then constant away from them, and known from a neighbour's.
    closed: bool,
    vol: &'a SurfaceIndex,
    thin: &'a SurfaceIndex,
    r: f32,
    h: f32,
    origin: Vec3,
}

impl Field<'_> {
    fn pos(&self, p: IVec3) -> Vec3 {
        self.origin + p.as_vec3() * self.h
    }
    fn sample(&self, p: Vec3) -> Sample {
        let w = if self.vol.is_empty() {
            0.0
        } else {
            self.vol.winding(p)
        };
        Sample {
            w,
            g: self.thin_g(p),
        }
    }
    fn thin_g(&self, p: Vec3) -> f32 {
        let cap = self.r + 2.0 * self.h;
        self.thin
            .closest_within(p, cap)
            .map_or(2.0 * self.h, |c| c.dist - self.r)
    }
    /// The surface point on the grid edge from inside point `a` to outside point `b`, as a
    /// fraction of the way from `a`.
    fn crossing(&self, a: Vec3, sa: Sample, b: Vec3, sb: Sample) -> f32 {
        let mut t: f32 = 0.0;
        if sa.w > 0.5 {
            let dir = (a - b) / self.h;
            t = match self.vol.ray(b, dir, 0.0, self.h) {
                Some((th, _)) => 1.0 - th / self.h,
                None => (sa.w - 0.5) / (sa.w - sb.w),
            };
        }
        if sa.g < 0.0 {
            t = t.max(sa.g / (sa.g - sb.g));
        }
        t.clamp(0.02, 0.98)
    }
}

/// The position of grid point (0, 0, 0) for a grid of spacing `h` padded by `pad` around the box
/// from `lo`. An odd offset keeps grid points off the round coordinates of axis-aligned input
/// faces (a point on a face has a winding number of exactly ½).
fn grid_origin(lo: Vec3, pad: f32, h: f32) -> Vec3 {
    lo - Vec3::splat(pad) - Vec3::new(0.2113, 0.3179, 0.4271) * h
}

/// Rebuilds `mesh` as one closed solid (see the module doc).
pub fn solidify(
    mesh: &PrintMesh,
    a: &Analysis,
    opts: &SolidifyOptions,
) -> Result<(PrintMesh, SolidifyReport)> {
    let start = Instant::now();
    let h = opts.voxel_mm;
    if !(h > 0.0 && h.is_finite()) {
        bail!("voxel size {h} mm must be positive");
    }
    let thicken = opts.thin == ThinPolicy::Thicken;
    let keep_vol =
        |i: usize| a.kinds[i] != TriKind::Sheet && !(opts.thin == ThinPolicy::Drop && a.thin[i]);
    let (vt, _) = corners(mesh, keep_vol);
    let (tt, _) = corners(mesh, |i| thicken && a.thin[i]);
    let mut rep = SolidifyReport {
        voxel_mm: h,
        sheet_triangles: a.kinds.iter().filter(|&&k| k == TriKind::Sheet).count(),
        thickened_triangles: tt.len(),
        dropped_triangles: mesh.tris.len() - vt.len() - tt.len().min(mesh.tris.len() - vt.len()),
        ..Default::default()
    };
    if !thicken {
        rep.dropped_triangles = (0..mesh.tris.len()).filter(|&i| !keep_vol(i)).count();
    }
    if vt.is_empty() && tt.is_empty() {
        bail!("nothing is left to print: every triangle is single-sided or thinner than the minimum wall and was dropped");
    }
    let r = if tt.is_empty() {
        0.0
    } else {
        opts.min_wall_mm * 0.5
    };
    let g = Grid::around(&vt, &tt, r, h)?;
    opts.memory
        .check(
            &format!("the solid at a {h} mm grid"),
            estimate_bytes(&vt, &tt, h, g.ncoarse),
            "use a larger --voxel-mm",
        )
        .map_err(anyhow::Error::from)?;
    rep.grid = (g.cells + IVec3::ONE).to_array().map(|x| x as usize);
    rep.blocks = (g.blocks.x * g.blocks.y * g.blocks.z) as usize;
    let closed = closed_as_chain(mesh, keep_vol);
    let vol = SurfaceIndex::new(vt);
    let thin = SurfaceIndex::new(tt);
    let field = Field {
        closed,
        vol: &vol,
        thin: &thin,
        r,
        h,
        origin: g.origin,
    };
    let seeds = g.seeds(&field);
    let per_block = g.march(&field, seeds, &mut rep);
    rep.blocks_evaluated = per_block.len();
    rep.closed_input = closed;
    rep.points_evaluated = per_block.iter().map(|b| b.1.evaluated).sum();
    let (positions, tris_k) = merge(&per_block);
    if tris_k.is_empty() {
        bail!("the solid is empty at a voxel size of {h} mm (the object is smaller than the grid)");
    }
    let tris = paint_from(mesh, &positions, &tris_k);
    let solid = rewelded(mesh, &positions, tris)?;
    rep.triangles = solid.tris.len();
    rep.seconds = start.elapsed().as_secs_f64();
    Ok((solid, rep))
}

/// The solid's grid: cells of `h` mm around the triangles (padded by the thickening radius and
/// two cells), in blocks of `B`³ cells whose corners are the coarse points.
struct Grid {
    origin: Vec3,
    cells: IVec3,
    blocks: IVec3,
    coarse: IVec3,
    ncoarse: u64,
}

impl Grid {
    fn around(vt: &[[Vec3; 3]], tt: &[[Vec3; 3]], r: f32, h: f32) -> Result<Grid> {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for t in vt.iter().chain(tt) {
            for p in t {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
        }
        let pad = r + 2.0 * h;
        let origin = grid_origin(lo, pad, h);
        let cells = ((hi + Vec3::splat(pad) - origin) / h).ceil().as_ivec3();
        let blocks = (cells + IVec3::splat(B - 1)) / B;
        let cells = blocks * B;
        let coarse = blocks + IVec3::ONE;
        let ncoarse = coarse.x as u64 * coarse.y as u64 * coarse.z as u64;
        if ncoarse > 40_000_000 || cells.max_element() > 1 << 20 {
            bail!(
                "the solid's grid would be {}x{}x{} cells of {h} mm: too fine for an object of {:.0} x {:.0} x {:.0} mm; use a larger --voxel-mm",
                cells.x, cells.y, cells.z, hi.x - lo.x, hi.y - lo.y, hi.z - lo.z
            );
        }
        Ok(Grid {
            origin,
            cells,
            blocks,
            coarse,
            ncoarse,
        })
    }

    fn block_index(&self, b: IVec3) -> usize {
        ((b.x * self.blocks.y + b.y) * self.blocks.z + b.z) as usize
    }

    /// The blocks a surface may pass through: corners on both sides, or a triangle near.
    fn seeds(&self, field: &Field) -> Vec<IVec3> {
        let coarse = self.coarse;
        let cidx = |p: IVec3| ((p.x * coarse.y + p.y) * coarse.z + p.z) as usize;
        // The inside test at every block corner.
        let corner_in: Vec<bool> = (0..self.ncoarse as usize)
            .into_par_iter()
            .map(|i| {
                let i = i as i32;
                let p = IVec3::new(
                    i / (coarse.y * coarse.z),
                    (i / coarse.z) % coarse.y,
                    i % coarse.z,
                );
                field.sample(field.pos(p * B)).inside()
            })
            .collect();
        let blocks = self.blocks;
        let block_ids: Vec<IVec3> = (0..blocks.x)
            .flat_map(|x| {
                (0..blocks.y).flat_map(move |y| (0..blocks.z).map(move |z| IVec3::new(x, y, z)))
            })
            .collect();
        let h = field.h;
        let rho = (B as f32) * h * 3f32.sqrt() * 0.5 + h;
        block_ids
            .par_iter()
            .filter(|&&bi| {
                let ins: Vec<bool> = CORNER
                    .iter()
                    .map(|c| corner_in[cidx(bi + IVec3::from(*c))])
                    .collect();
                let mixed = ins.iter().any(|&x| x != ins[0]);
                let c = field.pos(bi * B) + Vec3::splat(B as f32 * h * 0.5);
                mixed
                    || field.vol.closest_within(c, rho).is_some()
                    || field.thin.closest_within(c, rho + field.r).is_some()
            })
            .copied()
            .collect()
    }

    /// Marching cubes over the seed blocks and, wave by wave, the blocks across every face with
    /// crossings. The seeds miss a surface that enters a block through a face without separating
    /// its corners or coming near an input triangle: the winding number's film across a large
    /// hole, far from every triangle, lying within the winding number's approximation error of a
    /// grid plane that is a block face (its points then fall on both sides of ½ while the
    /// corners agree). Every triangle edge on a block face must be matched by the block on the
    /// other side, so whenever an evaluated block's face has points on both sides, the block
    /// across it is evaluated too, until no face with crossings borders an unevaluated block.
    /// Returned in grid order, so that the first block to place a shared vertex does not depend
    /// on the order of evaluation.
    fn march(
        &self,
        field: &Field,
        mut wave: Vec<IVec3>,
        rep: &mut SolidifyReport,
    ) -> Vec<(usize, BlockMesh)> {
        let mut queued = vec![false; rep.blocks];
        for &bi in &wave {
            queued[self.block_index(bi)] = true;
        }
        let mut per_block: Vec<(usize, BlockMesh)> = vec![];
        while !wave.is_empty() {
            let done: Vec<BlockMesh> = wave
                .par_iter()
                .map(|&bi| march_block(field, bi, self.cells))
                .collect();
            let mut next = vec![];
            for (&bi, m) in wave.iter().zip(done) {
                for f in 0..6 {
                    if m.crossed_faces & (1 << f) == 0 {
                        continue;
                    }
                    let mut nb = bi;
                    nb[f / 2] += if f % 2 == 0 { -1 } else { 1 };
                    if nb.min_element() >= 0
                        && nb.cmplt(self.blocks).all()
                        && !queued[self.block_index(nb)]
                    {
                        queued[self.block_index(nb)] = true;
                        rep.blocks_added += 1;
                        next.push(nb);
                    }
                }
                per_block.push((self.block_index(bi), m));
            }
            wave = next;
        }
        per_block.sort_unstable_by_key(|b| b.0);
        per_block
    }
}

/// Closed as a chain: every edge is used as often in one direction as in the other, so the
/// winding number is an integer away from the surface (an even use count alone is not enough:
/// two triangles on the same side of an edge leave it a boundary of the winding number, which
/// then varies off the surface and cannot be carried between points).
fn closed_as_chain(mesh: &PrintMesh, keep: impl Fn(usize) -> bool) -> bool {
    let mut e: HashMap<(u32, u32), i32> = HashMap::new();
    for (i, t) in mesh.tris.iter().enumerate() {
        if keep(i) {
            for k in 0..3 {
                let (a, b) = (t.v[k], t.v[(k + 1) % 3]);
                *e.entry((a.min(b), a.max(b))).or_insert(0) += if a < b { 1 } else { -1 };
            }
        }
    }
    e.values().all(|&c| c == 0)
}

/// The blocks' triangles on one vertex per grid edge.
fn merge(per_block: &[(usize, BlockMesh)]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut index: HashMap<u64, u32> = HashMap::new();
    let mut positions: Vec<Vec3> = vec![];
    let mut tris_k: Vec<[u32; 3]> = vec![];
    for (_, BlockMesh { verts, tris, .. }) in per_block {
        for &(k, p) in verts {
            index.entry(k).or_insert_with(|| {
                positions.push(p);
                positions.len() as u32 - 1
            });
        }
        for t in tris {
            tris_k.push(t.map(|k| index[&k]));
        }
    }
    (positions, tris_k)
}

/// Each new triangle painted from the closest original triangle (texture coordinates
/// interpolated at its corners' closest points).
fn paint_from(mesh: &PrintMesh, positions: &[Vec3], tris_k: &[[u32; 3]]) -> Vec<PrintTri> {
    let (all, _) = corners(mesh, |_| true);
    let all = SurfaceIndex::new(all);
    tris_k
        .par_iter()
        .map(|&v| {
            let p = v.map(|k| positions[k as usize]);
            let c = (p[0] + p[1] + p[2]) / 3.0;
            let s = all.closest(c).expect("non-empty mesh");
            let src = &mesh.tris[s.tri as usize];
            let st = all.tri(s.tri);
            let paint = match src.paint {
                Paint::Texture { tex, uv } => Paint::Texture {
                    tex,
                    uv: p.map(|q| {
                        let (_, b) = closest_on_triangle(q, &st);
                        uv[0] * b.x + uv[1] * b.y + uv[2] * b.z
                    }),
                },
                Paint::Solid(col) => Paint::Solid(col),
            };
            PrintTri {
                v,
                paint,
                part: src.part,
            }
        })
        .collect()
}

/// One block's share of the surface.
struct BlockMesh {
    /// Vertices by global grid-edge key.
    verts: Vec<(u64, Vec3)>,
    /// Triangles as grid-edge keys.
    tris: Vec<[u64; 3]>,
    /// Points where the winding number was computed.
    evaluated: usize,
    /// Bit `2 axis + side` (side 0 at the low end): that face has points inside and outside,
    /// so the surface crosses it into the neighbouring block.
    crossed_faces: u8,
}

/// Evaluates one block's (B+1)³ points and runs marching cubes on its B³ cells.
fn march_block(f: &Field, bi: IVec3, cells: IVec3) -> BlockMesh {
    let base = bi * B;
    let (s, evaluated) = if f.closed {
        winding_samples(f, base)
    } else {
        field_samples(f, base)
    };
    let crossed_faces = crossed_faces(&s);
    let (verts, tris) = march_cells(f, base, cells, &s);
    BlockMesh {
        verts,
        tris,
        evaluated,
        crossed_faces,
    }
}

/// Points per block side.
const N: usize = (B + 1) as usize;

/// Index of the block's point `(x, y, z)`.
fn at(x: i32, y: i32, z: i32) -> usize {
    ((x as usize * N) + y as usize) * N + z as usize
}

/// The block's points sampled on a closed volume, and how many winding numbers that took.
fn winding_samples(f: &Field, base: IVec3) -> (Vec<Sample>, usize) {
    let n = N;
    let mut s = vec![Sample { w: 0.0, g: 0.0 }; n * n * n];
    let mut evaluated = 0;
    // Winding numbers only within a voxel of a surface; elsewhere the side of a neighbour
    // (no surface can pass between a point and a neighbour more than a voxel from it).
    let mut known = vec![false; n * n * n];
    let mut queue = std::collections::VecDeque::new();
    for x in 0..=B {
        for y in 0..=B {
            for z in 0..=B {
                let p = f.pos(base + IVec3::new(x, y, z));
                let i = at(x, y, z);
                s[i].g = f.thin_g(p);
                if f.vol.closest_within(p, f.h).is_some() {
                    s[i].w = f.vol.winding(p);
                    known[i] = true;
                    evaluated += 1;
                    queue.push_back(IVec3::new(x, y, z));
                }
            }
        }
    }
    let mut next_seed = 0;
    loop {
        while let Some(q) = queue.pop_front() {
            let wq = if s[at(q.x, q.y, q.z)].w > 0.5 {
                1.0
            } else {
                0.0
            };
            for d in [
                IVec3::X,
                IVec3::Y,
                IVec3::Z,
                -IVec3::X,
                -IVec3::Y,
                -IVec3::Z,
            ] {
                let r = q + d;
                if r.min_element() < 0 || r.max_element() > B {
                    continue;
                }
                let i = at(r.x, r.y, r.z);
                if !known[i] {
                    known[i] = true;
                    s[i].w = wq;
                    queue.push_back(r);
                }
            }
        }
        // A region with no surface near: one winding number for all of it.
        while next_seed < known.len() && known[next_seed] {
            next_seed += 1;
        }
        if next_seed == known.len() {
            break;
        }
        let (x, y, z) = (next_seed / (n * n), (next_seed / n) % n, next_seed % n);
        let q = IVec3::new(x as i32, y as i32, z as i32);
        let w = if f.vol.is_empty() {
            0.0
        } else {
            f.vol.winding(f.pos(base + q))
        };
        s[next_seed].w = if w > 0.5 { 1.0 } else { 0.0 };
        known[next_seed] = true;
        evaluated += 1;
        queue.push_back(q);
    }
    (s, evaluated)
}

/// The block's points sampled on an open surface's field (every point evaluated).
fn field_samples(f: &Field, base: IVec3) -> (Vec<Sample>, usize) {
    let n = N;
    let mut s = vec![Sample { w: 0.0, g: 0.0 }; n * n * n];
    for x in 0..=B {
        for y in 0..=B {
            for z in 0..=B {
                s[at(x, y, z)] = f.sample(f.pos(base + IVec3::new(x, y, z)));
            }
        }
    }
    (s, n * n * n)
}

/// The block's faces the surface crosses (see [`BlockMesh::crossed_faces`]).
fn crossed_faces(s: &[Sample]) -> u8 {
    let mut crossed_faces = 0u8;
    for axis in 0..3 {
        for (side, c) in [(0, 0), (1, B)] {
            let mut seen = [false; 2];
            for u in 0..=B {
                for v in 0..=B {
                    let mut q = IVec3::ZERO;
                    q[axis] = c;
                    q[(axis + 1) % 3] = u;
                    q[(axis + 2) % 3] = v;
                    seen[s[at(q.x, q.y, q.z)].inside() as usize] = true;
                }
            }
            if seen[0] && seen[1] {
                crossed_faces |= 1 << (2 * axis + side);
            }
        }
    }
    crossed_faces
}

/// Marching cubes over the block's cells: vertices keyed by their global grid edge, and the
/// triangles as those keys.
fn march_cells(
    f: &Field,
    base: IVec3,
    cells: IVec3,
    s: &[Sample],
) -> (Vec<(u64, Vec3)>, Vec<[u64; 3]>) {
    let gp = cells + IVec3::ONE;
    let key = |p: IVec3, axis: u64| {
        (((p.x as u64 * gp.y as u64 + p.y as u64) * gp.z as u64 + p.z as u64) << 2) | axis
    };
    let mut verts = vec![];
    let mut tris = vec![];
    for x in 0..B {
        for y in 0..B {
            for z in 0..B {
                let cell = IVec3::new(x, y, z);
                let cs: [Sample; 8] = std::array::from_fn(|k| {
                    let c = cell + IVec3::from(CORNER[k]);
                    s[at(c.x, c.y, c.z)]
                });
                let mut case = 0usize;
                for (k, smp) in cs.iter().enumerate() {
                    if smp.inside() {
                        case |= 1 << k;
                    }
                }
                let edges = EDGE_TABLE[case] as u16;
                if edges == 0 {
                    continue;
                }
                let mut ek = [0u64; 12];
                for (e, [c0, c1]) in EDGE.iter().enumerate() {
                    if edges & (1 << e) == 0 {
                        continue;
                    }
                    let (p0, p1) = (
                        base + cell + IVec3::from(CORNER[*c0]),
                        base + cell + IVec3::from(CORNER[*c1]),
                    );
                    let axis = (p1 - p0)
                        .abs()
                        .to_array()
                        .iter()
                        .position(|&d| d == 1)
                        .unwrap();
                    let lo = p0.min(p1);
                    ek[e] = key(lo, axis as u64);
                    let (s0, s1) = (cs[*c0], cs[*c1]);
                    let (a, sa, b, sb) = if s0.inside() {
                        (f.pos(p0), s0, f.pos(p1), s1)
                    } else {
                        (f.pos(p1), s1, f.pos(p0), s0)
                    };
                    let t = f.crossing(a, sa, b, sb);
                    verts.push((ek[e], a + (b - a) * t));
                }
                let row = &TRI_TABLE[case];
                let mut i = 0;
                while i + 2 < 16 && row[i] >= 0 {
                    let e = [row[i], row[i + 1], row[i + 2]].map(|x| ek[x as usize]);
                    // With "inside" as the tables' below-isolevel corners, their winding faces
                    // inward: reverse it.
                    tris.push([e[0], e[2], e[1]]);
                    i += 3;
                }
            }
        }
    }
    (verts, tris)
}

/// Recolours a bake of a rebuilt solid from the original surface: every baked vertex takes the
/// colour of the closest original point (texture or solid colour), so colours follow the
/// original across part borders instead of the per-triangle source of the textured transfer.
pub(crate) fn recolour_from(original: &PrintMesh, baked: &mut crate::bake::Baked) {
    let (ot, _) = corners(original, |_| true);
    let orig = SurfaceIndex::new(ot);
    let cols: Vec<[f32; 3]> = baked
        .positions
        .par_iter()
        .map(|&p| {
            let c = orig.closest(p).expect("non-empty");
            crate::bake::reference_colour(original, c.tri as usize, c.bary)
        })
        .collect();
    for t in &mut baked.tris {
        t.colour = t.v.map(|v| cols[v as usize]);
    }
}

/// How faithful a rebuilt solid is to the original surface, at print scale.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Fidelity {
    pub samples: usize,
    /// Distance from the new surface to the original one (mm): mean, 99th percentile, maximum
    /// (one-sided Hausdorff distance, estimated at the samples).
    pub out_mean_mm: f64,
    pub out_p99_mm: f64,
    pub out_max_mm: f64,
    /// Distance from the original's visible surface (boundary and single-sided triangles, not
    /// those hidden inside overlapping parts) to the new one (mm).
    pub in_mean_mm: f64,
    pub in_max_mm: f64,
    /// Colour of the new surface (the bake's 8-bit corner colours, interpolated; or the
    /// transferred texture when there is no bake) against the original texture at the closest
    /// original point, on textured parts: RMSE in 8-bit steps, mean and p95 CIE76 ΔE.
    pub colour_samples: usize,
    pub rmse_8bit: f64,
    pub mean_delta_e: f64,
    pub p95_delta_e: f64,
}

/// `n` area-uniform random points on triangles `tris` of `pos`: (triangle, barycentric).
fn sample_points(
    pos: &[Vec3],
    tris: &[[u32; 3]],
    n: usize,
    rng: &mut impl rand::Rng,
) -> Vec<(usize, Vec3)> {
    let mut cdf = Vec::with_capacity(tris.len());
    let mut acc = 0.0f64;
    for t in tris {
        let [a, b, c] = t.map(|i| pos[i as usize]);
        acc += 0.5 * (b - a).cross(c - a).length() as f64;
        cdf.push(acc);
    }
    if acc <= 0.0 {
        return vec![];
    }
    (0..n)
        .map(|_| {
            let x = rng.random::<f64>() * acc;
            let i = cdf.partition_point(|&c| c < x).min(tris.len() - 1);
            let (mut u, mut v) = (rng.random::<f32>(), rng.random::<f32>());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            (i, Vec3::new(1.0 - u - v, u, v))
        })
        .collect()
}

/// Measures `solid` (and its bake, when given) against `original` (see [`Fidelity`]).
pub fn fidelity(
    original: &PrintMesh,
    kinds: &[TriKind],
    solid: &PrintMesh,
    baked: Option<&crate::bake::Baked>,
    n: usize,
    seed: u64,
) -> Fidelity {
    use cac_core::colour::{delta_e76_srgb as delta_e, to_rgb8};
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (ot, _) = corners(original, |_| true);
    let orig = SurfaceIndex::new(ot);
    let (st, _) = corners(solid, |_| true);
    let new = SurfaceIndex::new(st);
    let mut f = Fidelity::default();
    // Out: points of the new surface (of the bake when there is one, which is the same surface).
    let (pos, tv): (&[Vec3], Vec<[u32; 3]>) = match baked {
        Some(b) => (&b.positions, b.tris.iter().map(|t| t.v).collect()),
        None => (&solid.positions, solid.tris.iter().map(|t| t.v).collect()),
    };
    let pts = sample_points(pos, &tv, n, &mut rng);
    #[allow(clippy::type_complexity)]
    let res: Vec<(f32, Option<([f32; 3], [f32; 3])>)> = pts
        .par_iter()
        .map(|&(i, b)| {
            let [p0, p1, p2] = tv[i].map(|k| pos[k as usize]);
            let p = p0 * b.x + p1 * b.y + p2 * b.z;
            let c = orig.closest(p).expect("non-empty");
            let textured = matches!(original.tris[c.tri as usize].paint, Paint::Texture { .. });
            let col = textured.then(|| {
                let want = crate::bake::reference_colour(original, c.tri as usize, c.bary);
                let got = match baked {
                    Some(bk) => {
                        let q = bk.tris[i]
                            .colour
                            .map(|c| to_rgb8(c).map(|x| x as f32 / 255.0));
                        std::array::from_fn(|k| q[0][k] * b.x + q[1][k] * b.y + q[2][k] * b.z)
                    }
                    None => crate::bake::reference_colour(solid, i, b),
                };
                (got, want)
            });
            (c.dist, col)
        })
        .collect();
    let mut d: Vec<f64> = res.iter().map(|r| r.0 as f64).collect();
    d.sort_by(|a, b| a.total_cmp(b));
    f.samples = d.len();
    if !d.is_empty() {
        f.out_mean_mm = d.iter().sum::<f64>() / d.len() as f64;
        f.out_p99_mm = d[(d.len() * 99 / 100).min(d.len() - 1)];
        f.out_max_mm = *d.last().unwrap();
    }
    let mut se = 0.0f64;
    let mut des = vec![];
    for (got, want) in res.iter().filter_map(|r| r.1) {
        for k in 0..3 {
            se += ((got[k] - want[k]) as f64 * 255.0).powi(2);
        }
        des.push(delta_e(got, want) as f64);
    }
    des.sort_by(|a, b| a.total_cmp(b));
    f.colour_samples = des.len();
    if !des.is_empty() {
        f.rmse_8bit = (se / (3 * des.len()) as f64).sqrt();
        f.mean_delta_e = des.iter().sum::<f64>() / des.len() as f64;
        f.p95_delta_e = des[(des.len() * 95 / 100).min(des.len() - 1)];
    }
    // In: visible original points to the new surface.
    let vis: Vec<[u32; 3]> = original
        .tris
        .iter()
        .zip(kinds)
        .filter(|(_, k)| **k != TriKind::Internal)
        .map(|(t, _)| t.v)
        .collect();
    let pts = sample_points(&original.positions, &vis, n, &mut rng);
    let d: Vec<f64> = pts
        .par_iter()
        .map(|&(i, b)| {
            let [p0, p1, p2] = vis[i].map(|k| original.positions[k as usize]);
            new.closest(p0 * b.x + p1 * b.y + p2 * b.z)
                .map_or(0.0, |c| c.dist as f64)
        })
        .collect();
    if !d.is_empty() {
        f.in_mean_mm = d.iter().sum::<f64>() / d.len() as f64;
        f.in_max_mm = d.iter().copied().fold(0.0, f64::max);
    }
    f
}

impl Fidelity {
    pub fn note(&self) -> String {
        format!(
            "solid vs original: surface distance mean {:.3} mm, p99 {:.3} mm, max {:.3} mm (original to solid: mean {:.3}, max {:.3} mm); colour RMSE {:.2} (8-bit), mean dE76 {:.2}, p95 {:.2} ({} samples)",
            self.out_mean_mm, self.out_p99_mm, self.out_max_mm, self.in_mean_mm, self.in_max_mm,
            self.rmse_8bit, self.mean_delta_e, self.p95_delta_e, self.colour_samples
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::PrintReport;
    use crate::printability::analyse;
    use crate::printcheck::edge_stats;

    fn mesh_of(tris: Vec<[Vec3; 3]>) -> PrintMesh {
        let mut positions = vec![];
        let mut pt = vec![];
        for t in tris {
            let b = positions.len() as u32;
            positions.extend(t);
            pt.push(PrintTri {
                v: [b, b + 1, b + 2],
                paint: Paint::Solid([0.2, 0.4, 0.6]),
                part: 0,
            });
        }
        crate::fixtures::print_mesh("t", &positions, pt)
    }

    use crate::fixtures::{cube, cuboid};

    fn opts(h: f32) -> SolidifyOptions {
        SolidifyOptions {
            voxel_mm: h,
            min_wall_mm: 0.8,
            thin: ThinPolicy::Thicken,
            memory: MemoryBudget::default(),
        }
    }

    #[test]
    fn a_solid_over_the_budget_is_refused_before_its_grid_is_evaluated() {
        let t = cube(40.0, Vec3::ZERO);
        let m = mesh_of(t.clone());
        let a = crate::printability::analyse(&m, 0.8);
        // 9600 mm² at 0.05 mm: about 13 M triangles, 6.7 GB by the estimate.
        let err = solidify(&m, &a, &opts(0.05)).unwrap_err().to_string();
        assert!(
            err.contains("the solid at a 0.05 mm grid would need about"),
            "{err}"
        );
        assert!(
            err.contains("--voxel-mm") && err.contains("--max-memory"),
            "{err}"
        );
        // The estimate bounds the triangles a solid really has.
        let (s, _) = solidify(&m, &a, &opts(1.0)).unwrap();
        let bound = estimate_bytes(&t, &[], 1.0, 0) / BYTES_PER_SOLID_TRIANGLE;
        assert!(s.tris.len() as u64 <= bound, "{} > {bound}", s.tris.len());
    }

    #[test]
    fn intersecting_cubes_become_one_closed_outward_solid() {
        let mut t = cube(10.0, Vec3::ZERO);
        t.extend(cube(10.0, Vec3::splat(5.0)));
        let m = mesh_of(t);
        let a = analyse(&m, 0.8);
        let (s, rep) = solidify(&m, &a, &opts(0.5)).unwrap();
        assert!(s.report.is_closed(), "{:?}", s.report);
        assert_eq!(edge_stats(s.tris.iter().map(|t| t.v)), (0, 0, 0));
        assert_eq!(s.report.flipped_shells, 0, "already outward");
        let parts = crate::printability::parts(&s);
        assert_eq!(s.report.shells, 1, "{parts:?}");
        // Union volume 2000 - 125 mm³; edges and corners are cut by less than a voxel.
        let v = s.report.volume_mm3;
        assert!((v - 1875.0).abs() < 40.0, "{v} {rep:?}");
        assert!(rep.blocks_evaluated < rep.blocks);
        let _ = PrintReport::default();
    }

    #[test]
    fn single_sided_quad_is_thickened_to_the_minimum_wall() {
        let q = [
            [
                Vec3::ZERO,
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(10.0, 10.0, 0.0),
            ],
            [
                Vec3::ZERO,
                Vec3::new(10.0, 10.0, 0.0),
                Vec3::new(0.0, 10.0, 0.0),
            ],
        ];
        let m = mesh_of(q.to_vec());
        let a = analyse(&m, 0.8);
        assert!(a.kinds.iter().all(|&k| k == TriKind::Sheet));
        let (s, _) = solidify(&m, &a, &opts(0.2)).unwrap();
        assert!(s.report.is_closed(), "{:?}", s.report);
        // A 10 x 10 mm slab about 0.8 mm thick (rounded edges).
        let v = s.report.volume_mm3;
        assert!(v > 60.0 && v < 100.0, "{v}");
        assert!(
            (s.report.size_mm[2] - 0.8).abs() < 0.1,
            "{:?}",
            s.report.size_mm
        );
    }

    /// The failure of a box vehicle (messy.obj): a body without a floor, a cabin, four wheel
    /// boxes through the body's sides and a single-sided window just off the cabin. The winding
    /// number's film across the 40 x 16 mm floor hole is the plane of the hole (exactly ½ there),
    /// far from every triangle; put on a grid plane that is a block face, its points fall on both
    /// sides of ½ by the winding number's approximation error while the corners of the block
    /// above agree, so that block was skipped and the faces shared with its evaluated
    /// neighbours were left open (8 open edges at each `eps` before the fix).
    #[test]
    fn hole_film_on_a_block_face_is_closed() {
        let h = 0.4;
        let (len, wid) = (40.0, 16.0);
        let mut added = 0;
        for eps in [-0.002f32, 0.0, 0.002] {
            // The wheels start at z = 0 and the window is thickened (r = 0.4 mm), so the grid's
            // z origin is that of `grid_origin`: grid plane 16 is a block face.
            let pad = 0.4 + 2.0 * h;
            let z = grid_origin(Vec3::ZERO, pad, h).z + 16.0 * h + eps;
            // The body without its floor (face 0: −z).
            let mut t = cuboid(Vec3::new(0.0, 0.0, z), Vec3::new(len, wid, z + 8.0), &[0]);
            t.extend(cuboid(
                Vec3::new(12.0, 0.5, z + 8.0),
                Vec3::new(26.0, wid - 0.5, z + 14.0),
                &[],
            ));
            for x in [6.0, 30.0] {
                for y in [-1.0, wid - 1.0] {
                    t.extend(cuboid(
                        Vec3::new(x, y, 0.0),
                        Vec3::new(x + 6.0, y + 2.0, z + 1.6),
                        &[],
                    ));
                }
            }
            let [a, b, c, d] = [(1.5, 9.0), (wid - 1.5, 9.0), (wid - 1.5, 13.0), (1.5, 13.0)]
                .map(|(y, dz)| Vec3::new(26.42, y, z + dz));
            t.extend([[a, b, c], [a, c, d]]);
            let m = mesh_of(t);
            let an = analyse(&m, 0.8);
            assert!(!m.report.is_closed());
            let (s, rep) = solidify(&m, &an, &opts(h)).unwrap();
            assert!(s.report.is_closed(), "eps {eps}: {:?} {rep:?}", s.report);
            assert_eq!(edge_stats(s.tris.iter().map(|t| t.v)), (0, 0, 0));
            assert_eq!(s.report.flipped_shells, 0, "already outward");
            assert!(!rep.closed_input && rep.sheet_triangles == 2, "{rep:?}");
            added += rep.blocks_added;
        }
        // Otherwise the film no longer crosses a block face unseen (a more exact winding number?)
        // and this test no longer covers the case.
        assert!(added > 0, "no block was added for a crossed face");
    }
}
