//! Multi-material painting for slicers: every triangle of the print mesh carries a subdivision
//! tree whose leaves name a filament, in the encoding PrusaSlicer's painting tool saves to 3MF
//! (`slic3rpe:mmu_segmentation`) and Bambu Studio / OrcaSlicer save as `paint_color`. The slicer
//! splits the object along the painted borders, so the printed colours follow the texture below
//! the mesh's own resolution (down to the nozzle width).
//!
//! # The encoding (learned from the slicers' source, reimplemented here)
//!
//! Read in prusa3d/PrusaSlicer `src/libslic3r/TriangleSelector.cpp` (`serialize`,
//! `deserialize`, `perform_split`, `split_triangle`), `src/libslic3r/Model.cpp`
//! (`FacetsAnnotation::get_triangle_as_string` / `set_triangle_from_string`),
//! `src/libslic3r/Model.hpp` at tag `version_2.5.0` (`EnforcerBlockerType`) and
//! `src/libslic3r/Format/3mf.cpp` (the attribute, `slic3rpe:MmPaintingVersion`, and
//! `Metadata/Slic3r_PE.config` read by `load_from_gcode_string_legacy`); and in
//! SoftFever/OrcaSlicer / bambulab/BambuStudio `src/libslic3r/Format/bbs_3mf.cpp` (the same
//! string under `paint_color`, `Metadata/project_settings.config`) and OrcaSlicer's
//! `src/libslic3r/Format/3mf.cpp` (`PrusaFileParser`). No code was copied.
//!
//! - A triangle is a tree written depth first as 4-bit codes (nibbles). A node's first nibble has
//!   the number of split sides in its low two bits. `0` is a leaf: its high two bits are the
//!   state when it is 0, 1 or 2; when they are `0b11` a second nibble follows holding
//!   `state − 3` (so states 3..=18 fit; the readers accept up to 16). A split node (1, 2 or 3
//!   sides) has the "special side" in its high two bits (for 3 sides it is 0) and is followed
//!   by its `sides + 1` children **in reverse order** (last child first).
//! - State 0 is "not painted" (the object's own extruder); state `k` is extruder `k` (PrusaSlicer's
//!   `Extruder1 = 1`); filament `i` of a printer profile (0-based) is written as state `i + 1`.
//! - The 3MF string is one uppercase hex digit per nibble, the nibble's bit `i` being the
//!   stream's `i`-th bit, and the digits in **reverse** stream order: the root's nibble is the
//!   last character. A leaf of extruder 1 is `"4"`, of extruder 3 `"0C"`; a triangle split in
//!   four with leaves 1, 2, 3, 4 is `"480C1C3"`.
//! - Splitting (side `s` is the side opposite corner `s`; corners are taken from `s` on,
//!   `r = (c[s], c[s+1], c[s+2])`, and `m(a, b)` is a midpoint): one side: `(r0, r1, m(r1,r2))`,
//!   `(m(r1,r2), r2, r0)`; two sides (the special side is kept): `(r0, m01, m20)`,
//!   `(m01, r1, m20)`, `(r1, r2, m20)`; three sides: `(c0, m01, m20)`, `(m01, c1, m12)`,
//!   `(m12, c2, m20)`, `(m01, m12, m20)`. [`paint`] only splits in four; [`decode`] reads all
//!   three kinds.
//!
//! [`paint`] splits each textured triangle in four until its sub-triangles are about the nozzle
//! wide or a texel across (capped depth), gives each leaf the filament nearest (ΔE2000,
//! [`Printer::nearest`]) the texture at its centre, and joins children that agree into one leaf.

use crate::mesh::{Paint, PrintMesh, PrintTri};
use anyhow::{bail, ensure, Context, Result};
use cac_core::printer::{Fdm, Printer};
use cac_core::report::timer::{format_duration, parse_duration};
use cac_scene::Texture;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::HashMap;
use std::ops::{Add, Mul};
use std::path::Path;

/// The highest state the slicers read (PrusaSlicer names extruders up to 15, Bambu Studio and
/// OrcaSlicer 16).
pub const MAX_STATE: u8 = 16;

/// A painted triangle: a leaf, or a triangle split into `sides + 1` children.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Node {
    /// 0: not painted (the object's extruder); `k`: extruder `k` (filament `k − 1`).
    Leaf(u8),
    /// Split along 1, 2 or 3 sides; `special` is the side split (1), kept (2) or 0 (3); the
    /// children in the order of [`child_corners`].
    Split {
        sides: u8,
        special: u8,
        children: Vec<Node>,
    },
}

impl Node {
    /// A triangle split in four (all sides), children in [`child_corners`] order.
    pub fn quad(children: [Node; 4]) -> Node {
        Node::Split {
            sides: 3,
            special: 0,
            children: children.to_vec(),
        }
    }

    /// Number of leaves.
    pub fn leaves(&self) -> usize {
        match self {
            Node::Leaf(_) => 1,
            Node::Split { children, .. } => children.iter().map(Node::leaves).sum(),
        }
    }

    /// Depth of the deepest leaf (0 for a leaf).
    pub fn depth(&self) -> u32 {
        match self {
            Node::Leaf(_) => 0,
            Node::Split { children, .. } => 1 + children.iter().map(Node::depth).max().unwrap_or(0),
        }
    }

    /// Is the node well formed (states ≤ [`MAX_STATE`], split kinds and child counts right)?
    pub fn check(&self) -> Result<()> {
        match self {
            Node::Leaf(s) => ensure!(*s <= MAX_STATE, "state {s} is above {MAX_STATE}"),
            Node::Split {
                sides,
                special,
                children,
            } => {
                ensure!((1..=3).contains(sides), "a split of {sides} sides");
                ensure!(*special < 3, "special side {special}");
                ensure!(
                    *sides != 3 || *special == 0,
                    "a 3-side split names side {special}"
                );
                ensure!(
                    children.len() == *sides as usize + 1,
                    "a {sides}-side split with {} children",
                    children.len()
                );
                children.iter().try_for_each(Node::check)?;
            }
        }
        Ok(())
    }
}

/// The 3MF string of a painted triangle (see the module's notes). Panics on a malformed node
/// (the painter makes none; [`Node::check`] says what is wrong).
pub fn encode(node: &Node) -> String {
    let mut nibbles = Vec::new();
    push_nibbles(node, &mut nibbles);
    nibbles
        .iter()
        .rev()
        .map(|&n| char::from_digit(n as u32, 16).unwrap().to_ascii_uppercase())
        .collect()
}

fn push_nibbles(node: &Node, out: &mut Vec<u8>) {
    match node {
        Node::Leaf(s) => {
            assert!(*s <= MAX_STATE, "state {s} above {MAX_STATE}");
            if *s < 3 {
                out.push(s << 2);
            } else {
                out.push(0b1100);
                out.push(s - 3);
            }
        }
        Node::Split {
            sides,
            special,
            children,
        } => {
            assert!(
                (1..=3).contains(sides) && *special < 3 && children.len() == *sides as usize + 1
            );
            out.push(sides | special << 2);
            for c in children.iter().rev() {
                push_nibbles(c, out);
            }
        }
    }
}

/// Deepest tree [`decode`] accepts (PrusaSlicer's painting stops far earlier).
const MAX_DECODE_DEPTH: u32 = 40;

/// Reads a painting string (as [`encode`] writes and the slicers save); errors say what is wrong.
pub fn decode(s: &str) -> Result<Node> {
    ensure!(!s.is_empty(), "an empty painting string");
    let nibbles: Vec<u8> = s
        .chars()
        .rev()
        .map(|ch| match ch {
            '0'..='9' | 'A'..='F' => Ok(ch.to_digit(16).unwrap() as u8),
            _ => bail!("'{ch}' in painting string {s:?} is not an uppercase hex digit"),
        })
        .collect::<Result<_>>()?;
    let mut pos = 0;
    let node = read_node(&nibbles, &mut pos, 0).with_context(|| format!("painting {s:?}"))?;
    ensure!(
        pos == nibbles.len(),
        "painting {s:?}: {} digits left after its tree",
        nibbles.len() - pos
    );
    Ok(node)
}

fn read_node(n: &[u8], pos: &mut usize, depth: u32) -> Result<Node> {
    ensure!(
        depth <= MAX_DECODE_DEPTH,
        "deeper than {MAX_DECODE_DEPTH} levels"
    );
    let mut next = || -> Result<u8> {
        let v = *n.get(*pos).context("the string ends inside its tree")?;
        *pos += 1;
        Ok(v)
    };
    let code = next()?;
    let sides = code & 0b11;
    if sides == 0 {
        let state = if code >> 2 == 0b11 {
            next()? + 3
        } else {
            code >> 2
        };
        ensure!(state <= MAX_STATE, "state {state} is above {MAX_STATE}");
        return Ok(Node::Leaf(state));
    }
    let special = code >> 2;
    ensure!(
        special < 3,
        "special side {special} of a {sides}-side split"
    );
    ensure!(
        sides != 3 || special == 0,
        "a 3-side split names side {special}"
    );
    let mut children = (0..=sides)
        .map(|_| read_node(n, pos, depth + 1))
        .collect::<Result<Vec<_>>>()?;
    children.reverse();
    Ok(Node::Split {
        sides,
        special,
        children,
    })
}

/// The children of a triangle with corners `c` split along `sides` sides with special side
/// `special` (as the slicers split it; see the module's notes). Works on positions, UVs or
/// barycentric coordinates alike.
pub fn child_corners<T>(sides: u8, special: u8, c: [T; 3]) -> Vec<[T; 3]>
where
    T: Copy + Add<Output = T> + Mul<f32, Output = T>,
{
    let s = special as usize % 3;
    let [r0, r1, r2] = [c[s], c[(s + 1) % 3], c[(s + 2) % 3]];
    let m = |a: T, b: T| (a + b) * 0.5;
    match sides {
        1 => {
            let m12 = m(r1, r2);
            vec![[r0, r1, m12], [m12, r2, r0]]
        }
        2 => {
            let (m01, m20) = (m(r0, r1), m(r2, r0));
            vec![[r0, m01, m20], [m01, r1, m20], [r1, r2, m20]]
        }
        _ => {
            let (m01, m12, m20) = (m(r0, r1), m(r1, r2), m(r2, r0));
            vec![
                [r0, m01, m20],
                [m01, r1, m12],
                [m12, r2, m20],
                [m01, m12, m20],
            ]
        }
    }
}

fn area(p: &[Vec3; 3]) -> f64 {
    0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length() as f64
}

/// Adds the area (mm² for positions in mm) of each state's leaves of a triangle with corners
/// `p` to `out[state]` (grown as needed).
pub fn state_areas(node: &Node, p: [Vec3; 3], out: &mut Vec<f64>) {
    match node {
        Node::Leaf(s) => {
            if out.len() <= *s as usize {
                out.resize(*s as usize + 1, 0.0);
            }
            out[*s as usize] += area(&p);
        }
        Node::Split {
            sides,
            special,
            children,
        } => {
            for (c, q) in children.iter().zip(child_corners(*sides, *special, p)) {
                state_areas(c, q, out);
            }
        }
    }
}

/// How finely [`paint`] splits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PaintLimits {
    /// A sub-triangle whose longest edge is at most this (mm) is a leaf: the nozzle width.
    pub leaf_mm: f32,
    /// ... or whose longest edge spans at most this many texels.
    pub leaf_texels: f32,
    /// Most times a triangle is split in four (4^depth leaves at most).
    pub max_depth: u32,
}

impl PaintLimits {
    /// Leaves of the nozzle's width or one texel, at most 8 levels (65 536 leaves a triangle).
    pub fn for_fdm(fdm: &Fdm) -> Self {
        PaintLimits {
            leaf_mm: fdm.nozzle_mm,
            leaf_texels: 1.0,
            max_depth: 8,
        }
    }
}

/// Most leaves [`paint`] evaluates before refusing (about a minute on two cores).
pub const MAX_EVALUATIONS: f64 = 4e8;

/// What the painting covers: per filament, the painted area.
#[derive(Clone, Debug, Serialize)]
pub struct PaintSummary {
    /// Printer profile's name.
    pub printer: String,
    /// Filament names and `#RRGGBB` colours, in extruder order.
    pub filaments: Vec<(String, String)>,
    /// Painted area per filament, mm².
    pub area_mm2: Vec<f64>,
    pub triangles: usize,
    /// Triangles whose painting is split (more than one leaf).
    pub split_triangles: usize,
    pub leaves: usize,
    pub max_depth: u32,
    pub limits: PaintLimits,
}

impl PaintSummary {
    /// Each filament's share of the painted area (0..1).
    pub fn shares(&self) -> Vec<f64> {
        let total: f64 = self.area_mm2.iter().sum::<f64>().max(1e-12);
        self.area_mm2.iter().map(|a| a / total).collect()
    }

    /// The summary's line: triangles, leaves and each filament's share of the surface.
    pub fn line(&self) -> String {
        let shares: Vec<String> = self
            .filaments
            .iter()
            .zip(self.shares())
            .map(|((name, hex), s)| format!("{name} ({hex}) {:.1} %", s * 100.0))
            .collect();
        format!(
            "painted for {} ({} filaments): {} triangles, {} split into {} leaves (depth ≤ {}, leaves ≤ {} mm or {} texel); area: {}",
            self.printer,
            self.filaments.len(),
            self.triangles,
            self.split_triangles,
            self.leaves,
            self.max_depth,
            self.limits.leaf_mm,
            self.limits.leaf_texels,
            shares.join(", ")
        )
    }
}

/// Every triangle's painting, and its summary.
#[derive(Clone, Debug)]
pub struct Painting {
    /// One tree per triangle of the mesh, in order.
    pub trees: Vec<Node>,
    pub summary: PaintSummary,
}

/// Paints every triangle of `mesh` with the filaments of an FDM `printer`: textured triangles
/// (the camouflage, and other parts' own textures) are split and painted leaf by leaf, solid
/// ones take the filament nearest their colour.
pub fn paint(
    mesh: &PrintMesh,
    printer: &Printer,
    name: &str,
    limits: &PaintLimits,
) -> Result<Painting> {
    let Printer::Fdm { palette, fdm, .. } = printer else {
        bail!("printer profile {name} is not a multi-material FDM profile: nothing to paint with")
    };
    ensure!(
        !palette.is_empty() && palette.len() <= MAX_STATE as usize,
        "printer profile {name} has {} filaments; the slicers' painting holds 1 to {MAX_STATE}",
        palette.len()
    );
    ensure!(
        limits.leaf_mm > 0.0 && limits.leaf_texels > 0.0,
        "painting leaves must have a positive size"
    );
    let evaluations: f64 = mesh
        .tris
        .iter()
        .map(|t| 4f64.powi(needed_depth(mesh, t, limits) as i32))
        .sum();
    if evaluations > MAX_EVALUATIONS {
        bail!(
            "painting for {name} would evaluate {evaluations:.2e} sub-triangles (over {MAX_EVALUATIONS:.0e}): the object is large against the nozzle ({} mm) and texels; print at a smaller scale or use a coarser texture",
            limits.leaf_mm
        );
    }
    let trees: Vec<Node> = mesh
        .tris
        .par_iter()
        .map_init(HashMap::new, |cache, t| {
            let mut painter = Painter {
                printer,
                limits,
                cache,
            };
            painter.triangle(mesh, t)
        })
        .collect();
    let mut area = vec![0.0; palette.len() + 1];
    for (t, node) in mesh.tris.iter().zip(&trees) {
        state_areas(node, t.v.map(|i| mesh.positions[i as usize]), &mut area);
    }
    let summary = PaintSummary {
        printer: name.to_string(),
        filaments: fdm
            .filaments
            .iter()
            .zip(palette)
            .map(|(f, &c)| (f.name.clone(), cac_core::colour::to_hex(c)))
            .collect(),
        area_mm2: area[1..=palette.len()].to_vec(),
        triangles: trees.len(),
        split_triangles: trees
            .iter()
            .filter(|n| matches!(n, Node::Split { .. }))
            .count(),
        leaves: trees.iter().map(Node::leaves).sum(),
        max_depth: trees.iter().map(Node::depth).max().unwrap_or(0),
        limits: *limits,
    };
    Ok(Painting { trees, summary })
}

/// How many four-way splits triangle `t` needs before its leaves reach the limits.
fn needed_depth(mesh: &PrintMesh, t: &PrintTri, limits: &PaintLimits) -> u32 {
    let Paint::Texture { tex, uv } = t.paint else {
        return 0;
    };
    let p = t.v.map(|i| mesh.positions[i as usize]);
    let tx = &mesh.textures[tex as usize];
    let ratio = (longest(&p) / limits.leaf_mm).min(texel_edge(tx, &uv) / limits.leaf_texels);
    if ratio <= 1.0 || !ratio.is_finite() {
        return 0;
    }
    (ratio.log2().ceil() as u32).min(limits.max_depth)
}

fn longest(p: &[Vec3; 3]) -> f32 {
    (0..3)
        .map(|i| p[i].distance(p[(i + 1) % 3]))
        .fold(0.0, f32::max)
}

fn texel_edge(tx: &Texture, uv: &[Vec2; 3]) -> f32 {
    let size = Vec2::new(tx.width as f32, tx.height as f32);
    (0..3)
        .map(|i| ((uv[i] - uv[(i + 1) % 3]) * size).length())
        .fold(0.0, f32::max)
}

struct Painter<'a> {
    printer: &'a Printer,
    limits: &'a PaintLimits,
    /// 8-bit colour → state.
    cache: &'a mut HashMap<[u8; 3], u8>,
}

impl Painter<'_> {
    fn triangle(&mut self, mesh: &PrintMesh, t: &PrintTri) -> Node {
        match t.paint {
            Paint::Solid(c) => Node::Leaf(self.state(c)),
            Paint::Texture { tex, uv } => {
                let p = t.v.map(|i| mesh.positions[i as usize]);
                self.split(&mesh.textures[tex as usize], p, uv, 0)
            }
        }
    }

    /// The state (extruder) of the filament nearest an sRGB colour.
    fn state(&mut self, c: [f32; 3]) -> u8 {
        let q = cac_core::colour::to_rgb8(c);
        let printer = self.printer;
        *self
            .cache
            .entry(q)
            .or_insert_with(|| printer.nearest(q.map(|v| v as f32 / 255.0)) as u8 + 1)
    }

    fn split(&mut self, tx: &Texture, p: [Vec3; 3], uv: [Vec2; 3], depth: u32) -> Node {
        let edge_tx = texel_edge(tx, &uv);
        if depth >= self.limits.max_depth
            || longest(&p) <= self.limits.leaf_mm
            || edge_tx <= self.limits.leaf_texels
        {
            return Node::Leaf(self.leaf(tx, &uv, edge_tx));
        }
        let ps = child_corners(3, 0, p);
        let uvs = child_corners(3, 0, uv);
        let children: Vec<Node> = ps
            .into_iter()
            .zip(uvs)
            .map(|(q, w)| self.split(tx, q, w, depth + 1))
            .collect();
        match children[0] {
            Node::Leaf(s) if children.iter().all(|c| *c == Node::Leaf(s)) => Node::Leaf(s),
            _ => Node::Split {
                sides: 3,
                special: 0,
                children,
            },
        }
    }

    /// A leaf's filament: the one nearest the texture at its centre; a leaf wider than two
    /// texels takes the most common of its centre and its four children's centres (ties: the
    /// centre), so a nozzle-wide leaf does not follow one texel of noise.
    fn leaf(&mut self, tx: &Texture, uv: &[Vec2; 3], edge_tx: f32) -> u8 {
        let centre = |w: &[Vec2; 3]| (w[0] + w[1] + w[2]) / 3.0;
        let c = self.state(tx.sample(centre(uv)));
        if edge_tx <= 2.0 {
            return c;
        }
        let mut votes = vec![(c, 1u32)];
        for w in child_corners(3, 0, *uv) {
            let s = self.state(tx.sample(centre(&w)));
            match votes.iter_mut().find(|(k, _)| *k == s) {
                Some(v) => v.1 += 1,
                None => votes.push((s, 1)),
            }
        }
        // max_by_key keeps the last maximum: scan in reverse so the centre's state wins ties.
        votes
            .iter()
            .rev()
            .max_by_key(|(_, n)| *n)
            .map_or(c, |(s, _)| *s)
    }
}

/// `Metadata/Slic3r_PE.config`: the extruder count (`nozzle_diameter`), the filament colours,
/// the layer height and a wipe tower, as PrusaSlicer reads a project's settings (one
/// `; key = value` line each after a header line; the slicer's defaults stand for the rest).
/// Separate extruders (`single_extruder_multi_material = 0`): PrusaSlicer 2.5's defaults for
/// a single-nozzle MMU give no print-time estimate. Purge volumes are PrusaSlicer's defaults
/// (140 mm³ between filaments, 70 mm³ loaded and unloaded), for `K` filaments. With a build
/// volume (`--build-volume`), the bed and height are it and the wipe tower (60 mm wide) stands
/// in the bed's front right corner, 5 mm in.
pub fn prusa_config(
    fdm: &Fdm,
    palette: &[[f32; 3]],
    name: &str,
    build_volume_mm: Option<[f32; 3]>,
) -> String {
    let k = palette.len();
    let hex: Vec<String> = palette
        .iter()
        .map(|&c| cac_core::colour::to_hex(c))
        .collect();
    let repeat = |v: String, n: usize| vec![v; n].join(",");
    let matrix: Vec<&str> = (0..k * k)
        .map(|i| if i / k == i % k { "0" } else { "140" })
        .collect();
    let mut lines = vec![
        ("printer_technology", "FFF".to_string()),
        ("nozzle_diameter", repeat(fmt_mm(fdm.nozzle_mm), k)),
        ("extruder_colour", hex.join(";")),
        ("filament_colour", hex.join(";")),
        ("layer_height", fmt_mm(fdm.layer_mm)),
        ("single_extruder_multi_material", "0".into()),
        ("wipe_tower", "1".into()),
        ("use_relative_e_distances", "1".into()),
        ("wiping_volumes_matrix", matrix.join(",")),
        ("wiping_volumes_extruders", repeat("70".into(), 2 * k)),
    ];
    if let Some([w, d, h]) = build_volume_mm {
        let (w, d) = (fmt_mm(w), fmt_mm(d));
        lines.push(("bed_shape", format!("0x0,{w}x0,{w}x{d},0x{d}")));
        lines.push(("max_print_height", fmt_mm(h)));
        let x = fmt_mm((build_volume_mm.unwrap()[0] - 65.0).max(0.0));
        lines.push(("wipe_tower_x", x));
        lines.push(("wipe_tower_y", "5".into()));
    }
    let mut s = format!(
        "; generated by cac export for printer profile {:?}: the filaments of a multi-material painting\n",
        name.replace(['\n', '\r'], " ")
    );
    for (key, v) in lines {
        s += &format!("; {key} = {v}\n");
    }
    s
}

/// `Metadata/project_settings.config` (JSON) for Bambu Studio / OrcaSlicer: the filament
/// colours and the layer height.
pub fn bambu_config(fdm: &Fdm, palette: &[[f32; 3]]) -> String {
    let hex: Vec<String> = palette
        .iter()
        .map(|&c| cac_core::colour::to_hex(c))
        .collect();
    let v = serde_json::json!({
        "filament_colour": hex,
        "layer_height": fmt_mm(fdm.layer_mm),
    });
    serde_json::to_string_pretty(&v).unwrap() + "\n"
}

fn fmt_mm(v: f32) -> String {
    let s = format!("{v:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// What a sliced print costs, read from the G-code.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SliceCost {
    /// The slicer, from the G-code's header (`PrusaSlicer 2.5.0+...`).
    pub slicer: String,
    /// Tool changes: switches from one extruder to another, counted in the G-code outside the
    /// wipe tower's initial priming of every extruder (as the slicer's `; total toolchanges`).
    pub tool_changes: usize,
    /// Tools selected at least once outside the priming (0-based).
    pub tools_used: Vec<usize>,
    /// The slicer's `; filament used [mm]` per extruder.
    pub filament_mm: Vec<f64>,
    /// The slicer's `; filament used [cm3]` per extruder.
    pub filament_cm3: Vec<f64>,
    /// Filament fed in extrusion moves, per extruder (mm), parsed from the moves, outside the
    /// initial priming (so, like the slicer's `filament used`).
    pub extruded_mm: Vec<f64>,
    /// Of which in the wipe tower (`;TYPE:Wipe tower`): the purge after tool changes.
    pub wipe_tower_mm: Vec<f64>,
    /// Filament extruded while priming every extruder on the wipe tower at the start (mm; not in
    /// the slicer's `filament used`).
    pub priming_mm: Vec<f64>,
    /// `; estimated printing time (normal mode)`, seconds (`None` when absent or not valid).
    pub print_time_s: Option<f64>,
}

impl SliceCost {
    /// Filament wasted: the wipe tower's purge and the priming, mm.
    pub fn waste_mm(&self) -> f64 {
        self.wipe_tower_mm.iter().sum::<f64>() + self.priming_mm.iter().sum::<f64>()
    }

    /// The waste's share of all the filament extruded (priming included).
    pub fn waste_share(&self) -> f64 {
        let all = self.extruded_mm.iter().sum::<f64>() + self.priming_mm.iter().sum::<f64>();
        self.waste_mm() / all.max(1e-12)
    }

    /// The summary's line.
    pub fn line(&self) -> String {
        let mm: Vec<String> = self.filament_mm.iter().map(|v| format!("{v:.0}")).collect();
        let time = self
            .print_time_s
            .map_or("not estimated".into(), format_duration);
        format!(
            "sliced with {}: {} tool changes; filament {} mm (extruders 1..{}), {:.1} cm3; purge {:.0} mm (wipe tower {:.0} mm, priming {:.0} mm) = {:.1} % of the filament; estimated print time {time}",
            if self.slicer.is_empty() { "the slicer" } else { &self.slicer },
            self.tool_changes,
            mm.join(" / "),
            self.filament_mm.len(),
            self.filament_cm3.iter().sum::<f64>(),
            self.waste_mm(),
            self.wipe_tower_mm.iter().sum::<f64>(),
            self.priming_mm.iter().sum::<f64>(),
            self.waste_share() * 100.0
        )
    }
}

fn numbers(s: &str) -> Vec<f64> {
    s.split(',').filter_map(|v| v.trim().parse().ok()).collect()
}

/// Reads what a print costs from PrusaSlicer G-code: tool changes, filament per extruder (the
/// slicer's totals and the extrusion moves, relative or absolute E), the wipe tower's share
/// and the estimated print time.
pub fn gcode_cost(gcode: &str) -> Result<SliceCost> {
    let mut r = GcodeReader::default();
    for line in gcode.lines() {
        let line = line.trim();
        if let Some(comment) = line.strip_prefix(';') {
            r.comment(comment.trim_start());
            continue;
        }
        let code = line.split(';').next().unwrap_or("").trim();
        let mut words = code.split_whitespace();
        let Some(cmd) = words.next() else { continue };
        match cmd {
            "M82" => r.relative = false,
            "M83" => r.relative = true,
            "G92" => {
                for w in words {
                    if let Some(v) = w.strip_prefix('E') {
                        r.e_abs = v.parse().unwrap_or(0.0);
                    }
                }
            }
            "G0" | "G1" | "G2" | "G3" => r.extrusion_move(words),
            t if t.len() > 1
                && t.starts_with('T')
                && t[1..].bytes().all(|b| b.is_ascii_digit()) =>
            {
                r.select_tool(t)?
            }
            _ => {}
        }
    }
    r.finish()
}

/// Adds `x` to `v[i]`, growing `v` with zeros to reach `i`.
fn add_per_extruder(v: &mut Vec<f64>, i: usize, x: f64) {
    if v.len() <= i {
        v.resize(i + 1, 0.0);
    }
    v[i] += x;
}

/// The state of [`gcode_cost`]'s pass over the G-code, and what it has counted so far.
#[derive(Default)]
struct GcodeReader {
    c: SliceCost,
    /// The tool selected last.
    tool: Option<usize>,
    /// Whether E is relative (`M83`) rather than absolute (`M82`).
    relative: bool,
    /// The absolute E position (set by `G92`, advanced by absolute moves).
    e_abs: f64,
    /// Whether the current feature (`;TYPE:`) is the wipe tower.
    wipe_tower: bool,
    /// Between `CP PRIMING START` and `CP PRIMING END`.
    priming: bool,
}

impl GcodeReader {
    /// Reads a comment (after `;`): priming markers, features and the slicer's totals.
    fn comment(&mut self, comment: &str) {
        let c = &mut self.c;
        if comment.starts_with("CP PRIMING START") {
            self.priming = true;
        } else if comment.starts_with("CP PRIMING END") {
            self.priming = false;
        } else if let Some(f) = comment.strip_prefix("TYPE:") {
            self.wipe_tower = f.trim() == "Wipe tower";
        } else if let Some(v) = comment.strip_prefix("filament used [mm] =") {
            c.filament_mm = numbers(v);
        } else if let Some(v) = comment.strip_prefix("filament used [cm3] =") {
            c.filament_cm3 = numbers(v);
        } else if let Some(v) = comment.strip_prefix("estimated printing time (normal mode) =") {
            c.print_time_s = parse_duration(v.trim());
        } else if let Some(v) = comment.strip_prefix("generated by ") {
            if c.slicer.is_empty() {
                c.slicer = v.split(" on ").next().unwrap_or(v).trim().to_string();
            }
        }
    }

    /// Counts the filament a `G0`..`G3` move (its `words`) feeds while moving in X or Y.
    fn extrusion_move<'a>(&mut self, words: impl Iterator<Item = &'a str>) {
        let (mut e, mut xy) = (None, false);
        for w in words {
            match w.as_bytes().first() {
                Some(b'E') => e = w[1..].parse::<f64>().ok(),
                Some(b'X' | b'Y') => xy = true,
                _ => {}
            }
        }
        let Some(e) = e else { return };
        let de = if self.relative {
            e
        } else {
            let d = e - self.e_abs;
            self.e_abs = e;
            d
        };
        if xy && de > 0.0 {
            let t = self.tool.unwrap_or(0);
            let c = &mut self.c;
            if self.priming {
                add_per_extruder(&mut c.priming_mm, t, de);
            } else {
                add_per_extruder(&mut c.extruded_mm, t, de);
                let wipe = if self.wipe_tower { de } else { 0.0 };
                add_per_extruder(&mut c.wipe_tower_mm, t, wipe);
            }
        }
    }

    /// Selects tool `t` (`T<n>`), counting the change and the tool outside the priming.
    fn select_tool(&mut self, t: &str) -> Result<()> {
        let n: usize = t[1..].parse().context("tool number")?;
        if !self.priming {
            if self.tool.is_some_and(|cur| cur != n) {
                self.c.tool_changes += 1;
            }
            if !self.c.tools_used.contains(&n) {
                self.c.tools_used.push(n);
            }
        }
        self.tool = Some(n);
        Ok(())
    }

    /// The cost counted: per-extruder lists padded to the same length; refuses G-code that
    /// extrudes nothing.
    fn finish(self) -> Result<SliceCost> {
        let mut c = self.c;
        c.tools_used.sort_unstable();
        let k = c.filament_mm.len().max(c.extruded_mm.len());
        c.extruded_mm.resize(k, 0.0);
        c.wipe_tower_mm.resize(k, 0.0);
        c.priming_mm.resize(k, 0.0);
        ensure!(
            !c.extruded_mm.iter().all(|&v| v == 0.0),
            "the G-code extrudes nothing"
        );
        Ok(c)
    }
}

/// The PrusaSlicer command line `--slice` runs.
pub const PRUSA_SLICER: &str = "prusa-slicer";

/// Slices a painted 3MF with PrusaSlicer's command line (the 3MF carries the extruder count,
/// colours and wipe tower, so no other settings are passed), writes the G-code to `gcode`
/// (atomically) and reads what the print costs.
pub fn slice(threemf: &Path, gcode: &Path) -> Result<SliceCost> {
    let dir = gcode.parent().unwrap_or(Path::new("."));
    let tmp = tempfile::Builder::new()
        .prefix(".cac-slice-")
        .suffix(".gcode")
        .tempfile_in(dir)
        .with_context(|| format!("cannot write in {}", dir.display()))?;
    let out = std::process::Command::new(PRUSA_SLICER)
        .arg("--export-gcode")
        .arg("-o")
        .arg(tmp.path())
        .arg(threemf)
        .output();
    let out = match out {
        Ok(o) => o,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "--slice runs PrusaSlicer's command line ({PRUSA_SLICER}), which is not on PATH; install it (Debian/Ubuntu: apt-get install prusa-slicer) or leave out --slice"
        ),
        Err(e) => return Err(e).context(format!("cannot run {PRUSA_SLICER}")),
    };
    let text = std::fs::read_to_string(tmp.path()).unwrap_or_default();
    if !out.status.success() || text.is_empty() {
        let (err, so) = (
            String::from_utf8_lossy(&out.stderr),
            String::from_utf8_lossy(&out.stdout),
        );
        let log: Vec<&str> = err
            .lines()
            .chain(so.lines())
            .filter(|l| !l.contains("[trace]") && !l.contains("[debug]") && !l.trim().is_empty())
            .collect();
        let tail = &log[log.len().saturating_sub(6)..];
        bail!(
            "{PRUSA_SLICER} could not slice {} ({}): {}",
            threemf.display(),
            out.status,
            tail.join(" | ")
        );
    }
    let cost = gcode_cost(&text).with_context(|| format!("G-code of {}", threemf.display()))?;
    tmp.persist(gcode)
        .with_context(|| format!("cannot write {}", gcode.display()))?;
    Ok(cost)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gcode_cost_counts_switches_and_wipe_tower() {
        let g = "; generated by PrusaSlicer 2.5.0+UNKNOWN on 2026-01-01\nM83\n; CP PRIMING START\nT1\nG1 X9 E5\nT0\n; CP PRIMING END\nT0\nG1 X1 Y1 E2\nG1 E-0.8\nG1 E0.8\n;TYPE:Wipe tower\nT1\nG1 X2 E3\n;TYPE:External perimeter\nG1 X3 E4\nT1\nT0\nG1 Y5 E1\n; filament used [mm] = 3.00, 7.00\n; estimated printing time (normal mode) = 1m 2s\n";
        let c = gcode_cost(g).unwrap();
        assert_eq!(c.slicer, "PrusaSlicer 2.5.0+UNKNOWN");
        assert_eq!(c.tool_changes, 2);
        assert_eq!(c.tools_used, vec![0, 1]);
        assert_eq!(c.extruded_mm, vec![3.0, 7.0]);
        assert_eq!(c.wipe_tower_mm, vec![0.0, 3.0]);
        assert_eq!(c.filament_mm, vec![3.0, 7.0]);
        assert_eq!(c.priming_mm, vec![0.0, 5.0]);
        assert_eq!(c.print_time_s, Some(62.0));
    }
}
