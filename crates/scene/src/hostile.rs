//! A seeded generator of hostile meshes: the files users really bring (tiled and far-out UVs,
//! a floorless box vehicle with intersecting wheels, objects from 1 mm to 1 km, degenerate and
//! non-finite vertices, a million triangles, ten thousand tiny parts, non-manifold fans,
//! inverted normals, missing material and texture files, glTF node trees with transforms, and
//! the quad vehicle of issue 49: five objects of quads in three materials, wheels pushed through
//! an open body, the atlas tiled once per face, a single-sided window).
//!
//! Each [`HostileCase`] is written as files into a folder and says what a stage must do with it:
//! work, or refuse with an error naming the file. `cac meshes hostile --out DIR` writes them for
//! a user's own pipeline; `tests/hostile_meshes.rs` runs every case through load, render, eval,
//! training and export in child processes and bounds their peak memory. It is not a loader and
//! checks nothing itself.

use anyhow::Result;
use rand::{Rng, SeedableRng};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What loading a case must give.
#[derive(Clone, Debug, PartialEq)]
pub enum Expect {
    /// Loads (and renders, trains, evaluates); export works or refuses with a clear error.
    Loads,
    /// Every stage refuses at load with an error containing this text and the file's name.
    Refused(&'static str),
}

/// One written case.
#[derive(Clone, Debug)]
pub struct HostileCase {
    pub name: &'static str,
    /// The mesh file to hand to `--mesh`.
    pub mesh: PathBuf,
    pub expect: Expect,
    /// Triangles written.
    pub triangles: usize,
}

/// The cases, in order (names are file stems).
pub const CASES: [&str; 15] = [
    "tiled_uv_vehicle",
    "quad_vehicle",
    "uv_far_outside",
    "tiny_1mm",
    "huge_1km",
    "degenerate",
    "non_finite",
    "million_triangles",
    "tiny_parts",
    "nonmanifold_fan",
    "inverted",
    "missing_mtl",
    "missing_texture",
    "gltf_node_tree",
    "gltf_bad_buffer",
];

/// Writes every case into `dir` (seeded: the same seed writes the same files).
pub fn write_all(dir: &Path, seed: u64) -> Result<Vec<HostileCase>> {
    CASES.iter().map(|n| write_case(dir, n, seed)).collect()
}

/// Writes the case `name` into `dir`.
pub fn write_case(dir: &Path, name: &str, seed: u64) -> Result<HostileCase> {
    std::fs::create_dir_all(dir)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ fnv(name));
    let mut m = Obj::default();
    let mut expect = Expect::Loads;
    let mut gltf = None;
    match name {
        "tiled_uv_vehicle" => vehicle(&mut m, &mut rng, 1.0),
        "quad_vehicle" => quad_vehicle(&mut m, &mut rng),
        "uv_far_outside" => {
            m.material("paint", None);
            let s = rng.random_range(300.0..1000.0f32);
            m.cuboid([-2.0, 0.0, -1.0], [2.0, 1.5, 1.0], |_, c| {
                [c[0] * s - 0.5 * s, c[1] * s + 0.3 * s]
            });
        }
        "tiny_1mm" => vehicle(&mut m, &mut rng, 0.001 / 4.5),
        "huge_1km" => vehicle(&mut m, &mut rng, 1000.0 / 4.5),
        "degenerate" => {
            vehicle(&mut m, &mut rng, 1.0);
            degenerate_faces(&mut m);
        }
        "non_finite" => {
            vehicle(&mut m, &mut rng, 1.0);
            non_finite_face(&mut m);
            expect = Expect::Refused("non-finite");
        }
        "million_triangles" => {
            m.material("paint", None);
            sphere(&mut m, 2.0, 500, 1000); // 2 · 500 · 1000 = 1 M triangles
        }
        "tiny_parts" => tiny_parts(&mut m, &mut rng),
        "nonmanifold_fan" => {
            vehicle(&mut m, &mut rng, 1.0);
            fin_fan(&mut m);
        }
        "inverted" => {
            vehicle(&mut m, &mut rng, 1.0);
            m.invert = true;
        }
        "missing_mtl" => {
            vehicle(&mut m, &mut rng, 1.0);
            m.mtllib = Some("does_not_exist.mtl".into());
            expect = Expect::Refused("mtllib does_not_exist.mtl");
        }
        "missing_texture" => {
            m.material("paint", Some("does_not_exist.png"));
            m.cuboid([-2.0, 0.0, -1.0], [2.0, 1.5, 1.0], |_, q| q);
            expect = Expect::Refused("does_not_exist.png");
        }
        "gltf_node_tree" => gltf = Some(node_tree(&mut rng, 2000, false)),
        "gltf_bad_buffer" => {
            gltf = Some(node_tree(&mut rng, 3, true));
            expect = Expect::Refused("refers to missing_buffer.bin");
        }
        other => anyhow::bail!("no hostile case '{other}' (cases: {})", CASES.join(", ")),
    }
    let (mesh, triangles) = match gltf {
        Some((json, tris)) => {
            let p = dir.join(format!("{name}.gltf"));
            cac_core::io::write_atomic(&p, json.as_bytes())?;
            (p, tris)
        }
        None => (m.write(dir, name)?, m.faces),
    };
    Ok(HostileCase {
        name: CASES.iter().find(|c| **c == name).copied().unwrap(),
        mesh,
        expect,
        triangles,
    })
}

/// Zero-area triangles above the cabin: collinear corners, repeated corners, a point.
fn degenerate_faces(m: &mut Obj) {
    let a = m.vertex([0.0, 2.2, 0.0]);
    let b = m.vertex([1.0, 2.2, 0.0]);
    let c = m.vertex([2.0, 2.2, 0.0]);
    let t = m.uv([0.5, 0.5]);
    m.face(&[(a, t), (b, t), (c, t)]);
    m.face(&[(a, t), (a, t), (b, t)]);
    m.face(&[(c, t), (c, t), (c, t)]);
}

/// One triangle whose corners are NaN, +inf and -inf.
fn non_finite_face(m: &mut Obj) {
    let a = m.vertex([f32::NAN, 0.0, 0.0]);
    let b = m.vertex([f32::INFINITY, 1.0, 0.0]);
    let c = m.vertex([0.0, f32::NEG_INFINITY, 1.0]);
    let t = m.uv([0.5, 0.5]);
    m.face(&[(a, t), (b, t), (c, t)]);
}

/// Ten thousand cubes of 4 to 20 mm, each its own group, scattered through a 4 x 2 x 2 m box.
fn tiny_parts(m: &mut Obj, rng: &mut impl Rng) {
    m.material("paint", None);
    for _ in 0..10_000 {
        let c: [f32; 3] = std::array::from_fn(|_| rng.random_range(-2.0..2.0f32));
        let c = [c[0], c[1].abs(), c[2] * 0.5];
        let h = rng.random_range(0.002..0.01f32);
        m.group(&format!("part{}", m.groups));
        m.cuboid(
            [c[0] - h, c[1] - h, c[2] - h],
            [c[0] + h, c[1] + h, c[2] + h],
            |_, q| q,
        );
    }
}

/// Eight fins sharing one edge above the cabin (a non-manifold fan).
fn fin_fan(m: &mut Obj) {
    let a = m.vertex([-0.5, 2.2, 0.0]);
    let b = m.vertex([0.5, 2.2, 0.0]);
    let t0 = m.uv([0.1, 0.1]);
    let t1 = m.uv([0.9, 0.1]);
    let t2 = m.uv([0.5, 0.9]);
    for k in 0..8 {
        let ang = k as f32 * std::f32::consts::TAU / 8.0;
        let c = m.vertex([0.0, 2.2 + 0.4 * ang.sin(), 0.4 * ang.cos()]);
        m.face(&[(a, t0), (b, t1), (c, t2)]);
    }
}

/// FNV-1a of a name, to give each case its own stream from one seed.
fn fnv(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    })
}

/// An OBJ being written (1-based indices, text built in memory).
#[derive(Default)]
struct Obj {
    v: String,
    vt: String,
    f: String,
    nv: usize,
    nt: usize,
    faces: usize,
    groups: usize,
    mtl: String,
    mtllib: Option<String>,
    invert: bool,
}

impl Obj {
    fn vertex(&mut self, p: [f32; 3]) -> usize {
        let _ = writeln!(self.v, "v {} {} {}", p[0], p[1], p[2]);
        self.nv += 1;
        self.nv
    }
    fn uv(&mut self, t: [f32; 2]) -> usize {
        let _ = writeln!(self.vt, "vt {} {}", t[0], t[1]);
        self.nt += 1;
        self.nt
    }
    fn face(&mut self, c: &[(usize, usize)]) {
        self.f.push('f');
        for (v, t) in c {
            let _ = write!(self.f, " {v}/{t}");
        }
        self.f.push('\n');
        self.faces += c.len() - 2;
    }
    fn material(&mut self, name: &str, texture: Option<&str>) {
        let _ = writeln!(self.mtl, "newmtl {name}\nKd 0.6 0.6 0.6");
        if let Some(t) = texture {
            let _ = writeln!(self.mtl, "map_Kd {t}");
        }
        let _ = writeln!(self.f, "usemtl {name}");
    }
    /// Declares a material in the MTL without switching to it.
    fn declare(&mut self, name: &str, kd: [f32; 3]) {
        let _ = writeln!(self.mtl, "newmtl {name}\nKd {} {} {}", kd[0], kd[1], kd[2]);
    }
    /// Switches the following faces to a declared material.
    fn use_material(&mut self, name: &str) {
        let _ = writeln!(self.f, "usemtl {name}");
    }
    fn group(&mut self, name: &str) {
        let _ = writeln!(self.f, "o {name}");
        self.groups += 1;
    }
    /// An axis-aligned box; `uv(face, corner01)` maps each face's unit square to UVs.
    fn cuboid(&mut self, lo: [f32; 3], hi: [f32; 3], uv: impl Fn(usize, [f32; 2]) -> [f32; 2]) {
        self.cuboid_skip(lo, hi, None, uv)
    }
    fn cuboid_skip(
        &mut self,
        lo: [f32; 3],
        hi: [f32; 3],
        skip: Option<usize>,
        uv: impl Fn(usize, [f32; 2]) -> [f32; 2],
    ) {
        let base = self.nv;
        for i in 0..8 {
            self.vertex(std::array::from_fn(|k| {
                if i >> k & 1 == 0 {
                    lo[k]
                } else {
                    hi[k]
                }
            }));
        }
        let corners = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        for (k, f) in crate::mesh::BOX_QUADS.iter().enumerate() {
            if skip == Some(k) {
                continue;
            }
            let t: Vec<usize> = corners.iter().map(|&c| self.uv(uv(k, c))).collect();
            let c: Vec<(usize, usize)> = (0..4).map(|j| (base + 1 + f[j] as usize, t[j])).collect();
            self.face(&c);
        }
    }
    fn write(&self, dir: &Path, name: &str) -> Result<PathBuf> {
        let mut out = String::new();
        match &self.mtllib {
            Some(l) => {
                let _ = writeln!(out, "mtllib {l}");
            }
            None if !self.mtl.is_empty() => {
                let _ = writeln!(out, "mtllib {name}.mtl");
                cac_core::io::write_atomic(&dir.join(format!("{name}.mtl")), self.mtl.as_bytes())?;
            }
            None => {}
        }
        out.push_str(&self.v);
        out.push_str(&self.vt);
        if self.invert {
            // Every face wound the other way round.
            for l in self.f.lines() {
                match l.strip_prefix("f ") {
                    Some(c) => {
                        let mut c: Vec<&str> = c.split(' ').collect();
                        c.reverse();
                        let _ = writeln!(out, "f {}", c.join(" "));
                    }
                    None => {
                        let _ = writeln!(out, "{l}");
                    }
                }
            }
        } else {
            out.push_str(&self.f);
        }
        let p = dir.join(format!("{name}.obj"));
        cac_core::io::write_atomic(&p, out.as_bytes())?;
        Ok(p)
    }
}

/// The issue's box vehicle, `scale` times 4.5 m long: a body box without a floor, a cabin, four
/// wheel boxes intersecting the body, a single-sided window quad 1 cm off the cabin; every
/// face's UVs span 0.05–0.95 of the atlas (tiled, overlapping), jittered by the seed.
fn vehicle(m: &mut Obj, rng: &mut impl Rng, scale: f32) {
    let j = rng.random_range(0.0..0.02f32);
    let tile = move |_: usize, c: [f32; 2]| [0.05 + j + (0.9 - 2.0 * j) * c[0], 0.05 + 0.9 * c[1]];
    let s = |p: [f32; 3]| p.map(|x| x * scale);
    m.material("paint", None);
    m.group("body");
    // Face 2 of `BOX_QUADS` is −y: the floor.
    m.cuboid_skip(s([-2.25, 0.4, -0.9]), s([2.25, 1.4, 0.9]), Some(2), tile);
    m.group("cabin");
    m.cuboid(s([-0.8, 1.4, -0.85]), s([0.9, 2.1, 0.85]), tile);
    for (k, (x, z)) in [(-1.5, -0.95), (-1.5, 0.75), (1.5, -0.95), (1.5, 0.75)]
        .into_iter()
        .enumerate()
    {
        m.group(&format!("wheel{k}"));
        m.cuboid(s([x - 0.4, 0.0, z]), s([x + 0.4, 0.8, z + 0.2]), tile);
    }
    m.group("window");
    window(m, s);
}

/// Issue 49's file, rebuilt from its description: five OBJ objects of quads (four corners per
/// face) whose every face maps the same square 0.05–0.95 of the atlas (the atlas tiled once per
/// face); a `body` box without a floor (five quads, open), a `cabin` box sunk into the body,
/// four box wheels (two objects) pushed through the body's sides, and a single-sided `window`
/// quad 1 cm off the cabin; materials `paint`, `wheel` and `glass` in its MTL. The wheels' depth
/// through the sides varies with the seed.
fn quad_vehicle(m: &mut Obj, rng: &mut impl Rng) {
    let tile = |_: usize, c: [f32; 2]| [0.05 + 0.9 * c[0], 0.05 + 0.9 * c[1]];
    m.declare("paint", [0.45, 0.5, 0.35]);
    m.declare("wheel", [0.1, 0.1, 0.1]);
    m.declare("glass", [0.3, 0.4, 0.5]);
    m.group("body");
    m.use_material("paint");
    m.cuboid_skip([-2.25, 0.4, -0.9], [2.25, 1.4, 0.9], Some(2), tile);
    m.group("cabin");
    m.cuboid([-0.8, 1.2, -0.85], [0.9, 2.1, 0.85], tile);
    let depth = rng.random_range(0.1..0.25f32);
    for (name, x) in [("wheels_front", 1.5f32), ("wheels_rear", -1.5)] {
        m.group(name);
        m.use_material("wheel");
        for side in [-1.0f32, 1.0] {
            // Through the side wall at |z| = 0.9: from `depth` inside to 0.15 outside.
            let (z0, z1) = (side * (0.9 - depth), side * 1.05);
            let (zl, zh) = (z0.min(z1), z0.max(z1));
            m.cuboid([x - 0.4, 0.0, zl], [x + 0.4, 0.8, zh], tile);
        }
    }
    m.group("window");
    m.use_material("glass");
    window(m, |p| p);
}

/// The vehicles' single-sided window: one quad 1 cm off the cabin's front, mapping 0.05–0.95 of
/// the atlas; `place` maps its corners (the vehicle's scale).
fn window(m: &mut Obj, place: impl Fn([f32; 3]) -> [f32; 3]) {
    let corners = [
        [0.91, 1.5, -0.7],
        [0.91, 1.5, 0.7],
        [0.91, 2.0, 0.7],
        [0.91, 2.0, -0.7],
    ];
    let uvs = [[0.05, 0.05], [0.95, 0.05], [0.95, 0.95], [0.05, 0.95]];
    let face: Vec<(usize, usize)> = corners
        .into_iter()
        .zip(uvs)
        .map(|(p, q)| (m.vertex(place(p)), m.uv(q)))
        .collect();
    m.face(&face);
}

/// A UV sphere of `rings` × `segments` quads (two triangles each).
fn sphere(m: &mut Obj, r: f32, rings: usize, segments: usize) {
    let base = m.nv;
    let tbase = m.nt;
    for i in 0..=rings {
        let th = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..=segments {
            let ph = std::f32::consts::TAU * j as f32 / segments as f32;
            m.vertex([
                r * th.sin() * ph.cos(),
                r + r * th.cos(),
                r * th.sin() * ph.sin(),
            ]);
            m.uv([j as f32 / segments as f32, 1.0 - i as f32 / rings as f32]);
        }
    }
    let id = |i: usize, j: usize| i * (segments + 1) + j + 1;
    for i in 0..rings {
        for j in 0..segments {
            let (a, b, c, d) = (id(i, j), id(i, j + 1), id(i + 1, j + 1), id(i + 1, j));
            let q = |k: usize| (base + k, tbase + k);
            m.face(&[q(a), q(b), q(c)]);
            m.face(&[q(a), q(c), q(d)]);
        }
    }
}

/// A glTF of `n` nodes in a random tree (translations, rotations, non-uniform and mirroring
/// scales), every node with the same box mesh; `bad_buffer` points the buffer at a missing file.
fn node_tree(rng: &mut impl Rng, n: usize, bad_buffer: bool) -> (String, usize) {
    // One box: 24 vertices (per-face UVs), 36 indices, as f32 positions, f32 UVs, u16 indices.
    let mut pos: Vec<f32> = vec![];
    let mut uv: Vec<f32> = vec![];
    let mut idx: Vec<u16> = vec![];
    let faces: [([f32; 3], [f32; 3], [f32; 3]); 6] = [
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
        ([-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
        ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
        ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        ([0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]),
    ];
    for (f, (nrm, a, b)) in faces.iter().enumerate() {
        for (s, t) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            for k in 0..3 {
                pos.push(0.5 * (nrm[k] + s * a[k] + t * b[k]));
            }
            uv.extend([0.05 + 0.45 * (s + 1.0), 0.05 + 0.45 * (t + 1.0)]);
        }
        let o = (f * 4) as u16;
        idx.extend([o, o + 1, o + 2, o, o + 2, o + 3]);
    }
    let mut bytes: Vec<u8> = vec![];
    pos.iter().for_each(|x| bytes.extend(x.to_le_bytes()));
    uv.iter().for_each(|x| bytes.extend(x.to_le_bytes()));
    idx.iter().for_each(|x| bytes.extend(x.to_le_bytes()));
    let uri = if bad_buffer {
        "missing_buffer.bin".to_string()
    } else {
        format!(
            "data:application/octet-stream;base64,{}",
            cac_core::report::html::base64(&bytes)
        )
    };
    let mut children: Vec<Vec<usize>> = vec![vec![]; n];
    for i in 1..n {
        children[rng.random_range(0..i)].push(i);
    }
    let nodes: Vec<String> = (0..n)
        .map(|i| {
            let t: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.5..1.5f32));
            let axis = glam::Vec3::new(rng.random(), rng.random(), rng.random()).normalize();
            // 6.28, not TAU: the seeded hostile files stay the ones the tests were measured on.
            #[allow(clippy::approx_constant)]
            let q = glam::Quat::from_axis_angle(axis, rng.random_range(0.0..6.28f32));
            let mut sc: [f32; 3] = std::array::from_fn(|_| rng.random_range(0.3..0.9f32));
            if rng.random_bool(0.1) {
                sc[0] = -sc[0];
            }
            let kids = if children[i].is_empty() {
                String::new()
            } else {
                format!(
                    ",\"children\":[{}]",
                    children[i].iter().map(|c| c.to_string()).collect::<Vec<_>>().join(",")
                )
            };
            format!(
                "{{\"name\":\"paint{i}\",\"mesh\":0,\"translation\":[{},{},{}],\"rotation\":[{},{},{},{}],\"scale\":[{},{},{}]{kids}}}",
                t[0], t[1], t[2], q.x, q.y, q.z, q.w, sc[0], sc[1], sc[2]
            )
        })
        .collect();
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{}],
"meshes":[{{"name":"box","primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":1}},"indices":2,"material":0}}]}}],
"materials":[{{"name":"paint","pbrMetallicRoughness":{{"baseColorFactor":[0.6,0.6,0.6,1]}}}}],
"buffers":[{{"byteLength":{},"uri":"{uri}"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":288}},{{"buffer":0,"byteOffset":288,"byteLength":192}},{{"buffer":0,"byteOffset":480,"byteLength":72}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":24,"type":"VEC3","min":[-0.5,-0.5,-0.5],"max":[0.5,0.5,0.5]}},{{"bufferView":1,"componentType":5126,"count":24,"type":"VEC2"}},{{"bufferView":2,"componentType":5123,"count":36,"type":"SCALAR"}}]}}"#,
        nodes.join(",\n"),
        bytes.len()
    );
    (json, 12 * n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_writes_the_same_files_and_another_seed_others() {
        let d = tempfile::tempdir().unwrap();
        let read = |seed: u64, sub: &str| {
            let c = write_case(&d.path().join(sub), "tiled_uv_vehicle", seed).unwrap();
            std::fs::read(&c.mesh).unwrap()
        };
        assert_eq!(read(3, "a"), read(3, "b"));
        assert_ne!(read(3, "a"), read(4, "c"));
    }
}
