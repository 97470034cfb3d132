//! [`Scene`]: the object as one indexed triangle mesh with UVs, materials and the paintable
//! parts, and what is done to it in place (validation, the common frame, transforms, appending).

use crate::material::{Material, PaintRule};
use crate::texture::Texture;
use anyhow::{bail, Result};
use glam::{Mat4, Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// The six faces of an axis-aligned box as corner indices, each counter-clockwise seen from
/// outside, in the order −z, +z, −y, +y, −x, +x; corner `i` is at `(i & 1, i >> 1 & 1, i >> 2 & 1)`
/// of the box (0: low side, 1: high side). Shared by the hostile meshes and the export tests.
pub const BOX_QUADS: [[u32; 4]; 6] = [
    [0, 2, 3, 1],
    [4, 5, 7, 6],
    [0, 1, 5, 4],
    [2, 6, 7, 3],
    [0, 4, 6, 2],
    [1, 3, 7, 5],
];

/// One triangle: three position indices, optional UV and normal indices, and a material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Triangle {
    pub p: [u32; 3],
    /// Indices into [`Scene::uvs`]; `None` for primitives without texture coordinates.
    pub uv: Option<[u32; 3]>,
    /// Indices into [`Scene::normals`]; `None` for flat shading.
    pub n: Option<[u32; 3]>,
    pub material: u32,
}

/// A loaded object: an indexed triangle mesh with materials, textures and paintable parts.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub uvs: Vec<Vec2>,
    pub triangles: Vec<Triangle>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    /// Per material: may the camouflage paint it? A material is only paintable when its
    /// triangles carry UVs.
    pub paintable: Vec<bool>,
}

/// How a file is turned into a normalised scene.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LoadOptions {
    pub paint: PaintRule,
    /// Extra rotation about +Y (degrees) applied after the automatic orientation, to turn the
    /// object's front to +X when the automatic choice (longest horizontal axis) faces backwards.
    pub yaw_deg: f32,
    /// Rescale so that the object's length is this many metres (`None`: keep the file's units).
    pub length_m: Option<f32>,
}

impl Scene {
    /// Marks materials paintable by name; untextured (UV-less) parts are never painted.
    pub(crate) fn apply_paint_rule(&mut self, rule: &PaintRule) {
        let mut has_uv = vec![true; self.materials.len()];
        let mut used = vec![false; self.materials.len()];
        for t in &self.triangles {
            used[t.material as usize] = true;
            if t.uv.is_none() {
                has_uv[t.material as usize] = false;
            }
        }
        self.paintable = self
            .materials
            .iter()
            .enumerate()
            .map(|(i, m)| used[i] && has_uv[i] && rule.is_paintable(&m.name))
            .collect();
    }

    /// Checks indices and values: every index in range, every coordinate finite.
    pub fn validate(&self) -> Result<()> {
        if self.triangles.is_empty() {
            bail!("the mesh has no triangles");
        }
        if let Some(i) = self.positions.iter().position(|p| !p.is_finite()) {
            bail!("vertex {i} has a non-finite position");
        }
        if let Some(i) = self.uvs.iter().position(|p| !p.is_finite()) {
            bail!("texture coordinate {i} is not finite");
        }
        for (k, t) in self.triangles.iter().enumerate() {
            let bad = |idx: &[u32; 3], n: usize| idx.iter().any(|&i| i as usize >= n);
            if bad(&t.p, self.positions.len()) {
                bail!(
                    "triangle {k} refers to a vertex index beyond the {} vertices",
                    self.positions.len()
                );
            }
            if t.uv.is_some_and(|uv| bad(&uv, self.uvs.len())) {
                bail!(
                    "triangle {k} refers to a texture coordinate beyond the {} given",
                    self.uvs.len()
                );
            }
            if t.n.is_some_and(|n| bad(&n, self.normals.len())) {
                bail!(
                    "triangle {k} refers to a normal beyond the {} given",
                    self.normals.len()
                );
            }
            if t.material as usize >= self.materials.len() {
                bail!(
                    "triangle {k} refers to material {} of {}",
                    t.material,
                    self.materials.len()
                );
            }
        }
        for m in &self.materials {
            if let Some(ti) = m.texture {
                if ti >= self.textures.len() {
                    bail!("material '{}' refers to a missing texture {ti}", m.name);
                }
            }
        }
        Ok(())
    }

    /// Axis-aligned bounds `(min, max)` of the positions used by triangles.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for t in &self.triangles {
            for &i in &t.p {
                lo = lo.min(self.positions[i as usize]);
                hi = hi.max(self.positions[i as usize]);
            }
        }
        (lo, hi)
    }

    /// The object's length: its extent along X (after [`Scene::normalise`]).
    pub fn length(&self) -> f32 {
        let (lo, hi) = self.bounds();
        hi.x - lo.x
    }

    /// Puts the object in the project's frame: the longer horizontal axis becomes X, then
    /// `yaw_deg` about +Y, optional rescale, centred in X/Z, lowest point at `y = 0`.
    pub fn normalise(&mut self, yaw_deg: f32, length_m: Option<f32>) {
        let (lo, hi) = self.bounds();
        let ext = hi - lo;
        let mut m = if ext.z > ext.x {
            Mat4::from_rotation_y(std::f32::consts::FRAC_PI_2)
        } else {
            Mat4::IDENTITY
        };
        m = Mat4::from_rotation_y(yaw_deg.to_radians()) * m;
        self.transform(&m);
        if let Some(len) = length_m {
            let s = len / self.length().max(1e-9);
            self.transform(&Mat4::from_scale(Vec3::splat(s)));
        }
        let (lo, hi) = self.bounds();
        let c = (lo + hi) * 0.5;
        self.transform(&Mat4::from_translation(Vec3::new(-c.x, -lo.y, -c.z)));
    }

    /// Applies an affine transform to positions and (inverse-transpose) normals.
    pub fn transform(&mut self, m: &Mat4) {
        for p in &mut self.positions {
            *p = m.transform_point3(*p);
        }
        let nm = m.inverse().transpose();
        for n in &mut self.normals {
            *n = nm.transform_vector3(*n).normalize_or_zero();
        }
    }

    /// Appends another scene's geometry and materials (used by loaders and generators).
    pub fn append(&mut self, other: Scene) {
        let (po, uo, no) = (
            self.positions.len() as u32,
            self.uvs.len() as u32,
            self.normals.len() as u32,
        );
        let (mo, to) = (self.materials.len() as u32, self.textures.len());
        self.positions.extend(other.positions);
        self.uvs.extend(other.uvs);
        self.normals.extend(other.normals);
        self.textures.extend(other.textures);
        self.paintable.extend(other.paintable);
        self.materials
            .extend(other.materials.into_iter().map(|mut m| {
                m.texture = m.texture.map(|t| t + to);
                m
            }));
        self.triangles
            .extend(other.triangles.into_iter().map(|t| Triangle {
                p: t.p.map(|i| i + po),
                uv: t.uv.map(|u| u.map(|i| i + uo)),
                n: t.n.map(|n| n.map(|i| i + no)),
                material: t.material + mo,
            }));
    }

    /// An empty scene to build into.
    pub fn empty(name: &str) -> Scene {
        Scene {
            name: name.into(),
            positions: vec![],
            normals: vec![],
            uvs: vec![],
            triangles: vec![],
            materials: vec![],
            textures: vec![],
            paintable: vec![],
        }
    }

    /// Is triangle `t` on a paintable part?
    pub fn is_paintable(&self, t: &Triangle) -> bool {
        self.paintable
            .get(t.material as usize)
            .copied()
            .unwrap_or(false)
            && t.uv.is_some()
    }

    /// The texture of the paintable parts (the camouflage atlas): the first paintable material's
    /// texture, or `None` when the paintable parts are untextured (the attack then starts from
    /// the material colour).
    pub fn paint_texture(&self) -> Option<&Texture> {
        self.materials
            .iter()
            .zip(&self.paintable)
            .find(|(m, &p)| p && m.texture.is_some())
            .and_then(|(m, _)| m.texture.map(|t| &self.textures[t]))
    }

    /// The initial camouflage atlas at `res x res`: the paintable texture resampled, or the
    /// first paintable material's base colour.
    pub fn initial_atlas(&self, res: usize) -> Texture {
        if let Some(t) = self.paint_texture() {
            return t.resized(res, res);
        }
        let c = self
            .materials
            .iter()
            .zip(&self.paintable)
            .find(|(_, &p)| p)
            .map(|(m, _)| m.base_color)
            .unwrap_or([0.5; 3]);
        Texture::solid(res, res, c)
    }

    /// The triangle's geometric (face) normal, unnormalised (zero for degenerate triangles).
    pub fn face_normal(&self, t: &Triangle) -> Vec3 {
        let [a, b, c] = t.p.map(|i| self.positions[i as usize]);
        (b - a).cross(c - a)
    }
}
