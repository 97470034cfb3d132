//! glTF 2.0 / GLB loading through the `gltf` crate.
//!
//! Walks the default scene's node tree (so a mesh used by several nodes appears once per node,
//! with that node's world transform), reads each primitive's positions, normals and the texture
//! coordinate set its base-colour texture names, and the materials' base colour factor (linear in
//! glTF, converted to display values here) and texture. Primitives without UVs keep a fixed colour.

use crate::material::Material;
use crate::mesh::{Scene, Triangle};
use crate::texture::Texture;
use anyhow::{anyhow, bail, Result};
use glam::{Mat4, Vec2, Vec3};
use std::path::Path;

fn texture_from(data: &gltf::image::Data, path: &Path) -> Result<Texture> {
    use gltf::image::Format::*;
    let (w, h) = (data.width as usize, data.height as usize);
    let ch = match data.format {
        R8 => 1,
        R8G8 => 2,
        R8G8B8 => 3,
        R8G8B8A8 => 4,
        f => bail!(
            "{}: texture pixel format {f:?} is not supported (8-bit only)",
            path.display()
        ),
    };
    if data.pixels.len() != w * h * ch {
        bail!(
            "{}: texture data size does not match its dimensions",
            path.display()
        );
    }
    let texels = data
        .pixels
        .chunks_exact(ch)
        .map(|p| {
            let g = |i: usize| p[i.min(ch - 1)] as f32 / 255.0;
            if ch <= 2 {
                [g(0); 3]
            } else {
                [g(0), g(1), g(2)]
            }
        })
        .collect();
    Ok(Texture {
        width: w,
        height: h,
        texels,
    })
}

/// Refuses a glTF whose buffers or images refer to files that are not next to it, naming them
/// (the importer's own error says only "No such file or directory").
fn missing_files(path: &Path) -> Result<()> {
    let Ok(g) = gltf::Gltf::open(path) else {
        return Ok(()); // unreadable: the importer says why
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let external = |uri: &str| !uri.starts_with("data:") && !dir.join(uri).is_file();
    for b in g.buffers() {
        if let gltf::buffer::Source::Uri(uri) = b.source() {
            if external(uri) {
                bail!(
                    "{}: buffer {} refers to {uri}, which is not next to it",
                    path.display(),
                    b.index()
                );
            }
        }
    }
    for i in g.images() {
        if let gltf::image::Source::Uri { uri, .. } = i.source() {
            if external(uri) {
                bail!(
                    "{}: image {} refers to {uri}, which is not next to it",
                    path.display(),
                    i.index()
                );
            }
        }
    }
    Ok(())
}

pub fn load(path: &Path) -> Result<Scene> {
    if !path.is_file() {
        bail!("mesh file {} does not exist", path.display());
    }
    missing_files(path)?;
    let (doc, buffers, images) = gltf::import(path)
        .map_err(|e| anyhow!("{}: not a readable glTF/GLB file ({e})", path.display()))?;
    let name = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("object");
    let mut scene = Scene::empty(name);
    for img in &images {
        scene.textures.push(texture_from(img, path)?);
    }
    let (default_mat, texcoord_set) = add_materials(&mut scene, &doc);
    let prims = Primitives {
        path,
        buffers: &buffers,
        texcoord_set,
        default_mat,
    };

    let gscene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| anyhow!("{}: the file has no scene", path.display()))?;
    let mut stack: Vec<(gltf::Node, Mat4)> = gscene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
    let mut depth_guard = 0usize;
    while let Some((node, parent)) = stack.pop() {
        depth_guard += 1;
        if depth_guard > 1_000_000 {
            bail!("{}: the node tree is cyclic or too large", path.display());
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                if prim.mode() != gltf::mesh::Mode::Triangles {
                    continue;
                }
                prims.add(&mut scene, &mesh, &prim, world)?;
            }
        }
        for c in node.children() {
            stack.push((c, world));
        }
    }
    scene.paintable = vec![false; scene.materials.len()];
    Ok(scene)
}

/// Adds one scene material per glTF material, plus a default one at the end; gives the default's
/// index and each material's base-colour texture coordinate set (the default's: 0).
fn add_materials(scene: &mut Scene, doc: &gltf::Document) -> (u32, Vec<u32>) {
    let mut texcoord_set = Vec::new();
    for (i, m) in doc.materials().enumerate() {
        let pbr = m.pbr_metallic_roughness();
        let f = pbr.base_color_factor();
        let tex = pbr.base_color_texture();
        let texture = tex.as_ref().map(|t| t.texture().source().index());
        let metallic = pbr.metallic_factor();
        let rough = pbr.roughness_factor();
        scene.materials.push(Material {
            name: m
                .name()
                .map(String::from)
                .unwrap_or_else(|| format!("material{i}")),
            base_color: [f[0], f[1], f[2]].map(|c| cac_core::colour::encode(c.clamp(0.0, 1.0))),
            texture,
            specular: 0.04 + 0.5 * metallic * (1.0 - rough) + 0.2 * (1.0 - rough),
            shininess: 2.0 + 126.0 * (1.0 - rough) * (1.0 - rough),
        });
        texcoord_set.push(tex.map(|t| t.tex_coord()).unwrap_or(0));
    }
    let default_mat = scene.materials.len() as u32;
    scene.materials.push(Material::plain("default", [0.6; 3]));
    texcoord_set.push(0);
    (default_mat, texcoord_set)
}

/// One primitive's vertex attributes (world frame) and triangle indices, as read.
struct PrimitiveData {
    pos: Vec<Vec3>,
    nrm: Option<Vec<Vec3>>,
    uv: Option<Vec<Vec2>>,
    idx: Vec<u32>,
}

/// What reading primitives needs besides the scene: the file, its buffers and the materials.
struct Primitives<'a> {
    path: &'a Path,
    buffers: &'a [gltf::buffer::Data],
    /// Per scene material, the texture coordinate set its base-colour texture reads.
    texcoord_set: Vec<u32>,
    /// The material of primitives that name none.
    default_mat: u32,
}

impl Primitives<'_> {
    /// Appends a triangle primitive of `mesh`, placed by `world`, to the scene.
    fn add(
        &self,
        scene: &mut Scene,
        mesh: &gltf::Mesh,
        prim: &gltf::Primitive,
        world: Mat4,
    ) -> Result<()> {
        let mat = prim
            .material()
            .index()
            .map(|i| i as u32)
            .unwrap_or(self.default_mat);
        let set = self.texcoord_set[mat as usize];
        let PrimitiveData { pos, nrm, uv, idx } = self.read(mesh, prim, world, set)?;
        let flip = world.determinant() < 0.0;
        let (po, uo, no) = (
            scene.positions.len() as u32,
            scene.uvs.len() as u32,
            scene.normals.len() as u32,
        );
        let has_uv = uv.as_ref().is_some_and(|u| u.len() == pos.len());
        let has_n = nrm.as_ref().is_some_and(|n| n.len() == pos.len());
        scene.positions.extend(&pos);
        if has_uv {
            scene.uvs.extend(uv.unwrap());
        }
        if has_n {
            scene.normals.extend(nrm.unwrap());
        }
        for t in idx.chunks_exact(3) {
            let t = if flip {
                [t[0], t[2], t[1]]
            } else {
                [t[0], t[1], t[2]]
            };
            scene.triangles.push(Triangle {
                p: t.map(|i| i + po),
                uv: has_uv.then(|| t.map(|i| i + uo)),
                n: has_n.then(|| t.map(|i| i + no)),
                material: mat,
            });
        }
        Ok(())
    }

    /// Reads a primitive's positions and normals (into the world frame), its texture
    /// coordinates of set `set` (flipped to a bottom-left origin) and its checked indices.
    fn read(
        &self,
        mesh: &gltf::Mesh,
        prim: &gltf::Primitive,
        world: Mat4,
        set: u32,
    ) -> Result<PrimitiveData> {
        let path = self.path;
        let reader = prim.reader(|b| self.buffers.get(b.index()).map(|d| &d.0[..]));
        let pos: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| {
                anyhow!(
                    "{}: a primitive of mesh '{}' has no positions",
                    path.display(),
                    mesh.name().unwrap_or("?")
                )
            })?
            .map(|p| world.transform_point3(Vec3::from(p)))
            .collect();
        let nm = world.inverse().transpose();
        let nrm: Option<Vec<Vec3>> = reader.read_normals().map(|it| {
            it.map(|n| nm.transform_vector3(Vec3::from(n)).normalize_or_zero())
                .collect()
        });
        let uv: Option<Vec<Vec2>> = reader.read_tex_coords(set).map(|t| {
            // glTF's UV origin is the top-left; cac's (like OBJ's) is bottom-left.
            t.into_f32().map(|[u, v]| Vec2::new(u, 1.0 - v)).collect()
        });
        let idx: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..pos.len() as u32).collect(),
        };
        if idx.len() % 3 != 0 || idx.iter().any(|&i| i as usize >= pos.len()) {
            bail!(
                "{}: mesh '{}' has out-of-range or incomplete indices",
                path.display(),
                mesh.name().unwrap_or("?")
            );
        }
        Ok(PrimitiveData { pos, nrm, uv, idx })
    }
}
