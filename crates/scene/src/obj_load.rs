//! OBJ (+MTL, diffuse textures) loading through `tobj`.
//!
//! Positions keep their OBJ indices (so closed meshes stay closed); UV and normal indices are
//! kept separately, so UV seams do not split the geometry. A group without a material takes its
//! object name as its material name, so paint rules can select OBJ parts by name.

use crate::material::Material;
use crate::mesh::{Scene, Triangle};
use crate::texture::Texture;
use anyhow::{anyhow, bail, Context, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::Path;

pub fn load(path: &Path) -> Result<Scene> {
    if !path.is_file() {
        bail!("mesh file {} does not exist", path.display());
    }
    let (models, mats) = read_obj(path)?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("object");
    let mut scene = Scene::empty(name);
    add_materials(&mut scene, &mats, dir, path)?;
    for model in models {
        add_model(&mut scene, &model, path)?;
    }
    scene.paintable = vec![false; scene.materials.len()];
    Ok(scene)
}

/// Parses the OBJ and its material library, naming the `mtllib` when it cannot be opened.
fn read_obj(path: &Path) -> Result<(Vec<tobj::Model>, Vec<tobj::Material>)> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ..Default::default()
    };
    let (models, mats) = tobj::load_obj(path, &opts)
        .map_err(|e| anyhow!("{}: not a readable OBJ file ({e})", path.display()))?;
    let mats = match mats {
        Ok(m) => m,
        Err(tobj::LoadError::OpenFileFailed) => {
            let lib = std::fs::read_to_string(path).ok().and_then(|t| {
                t.lines()
                    .find_map(|l| Some(l.trim().strip_prefix("mtllib")?.trim().to_string()))
            });
            bail!(
                "{}: its material library (mtllib {}) could not be opened next to it",
                path.display(),
                lib.as_deref().unwrap_or("?")
            )
        }
        Err(e) => bail!(
            "{}: its material library is malformed ({e})",
            path.display()
        ),
    };
    Ok((models, mats))
}

/// Adds one scene material per MTL material, loading each diffuse texture once (from `dir`).
fn add_materials(
    scene: &mut Scene,
    mats: &[tobj::Material],
    dir: &Path,
    path: &Path,
) -> Result<()> {
    let mut tex_cache: HashMap<String, usize> = HashMap::new();
    for m in mats {
        let texture = match &m.diffuse_texture {
            Some(t) if !t.is_empty() => {
                let idx = match tex_cache.get(t) {
                    Some(&i) => i,
                    None => {
                        let tp = dir.join(t);
                        let img = cac_core::io::load_rgb(&tp).with_context(|| {
                            format!("texture of material '{}' in {}", m.name, path.display())
                        })?;
                        scene.textures.push(Texture::from_rgb8(&img));
                        tex_cache.insert(t.clone(), scene.textures.len() - 1);
                        scene.textures.len() - 1
                    }
                };
                Some(idx)
            }
            _ => None,
        };
        let base_color = match (m.diffuse, texture) {
            (Some(d), _) => d,
            (None, Some(_)) => [1.0; 3],
            (None, None) => [0.6; 3],
        };
        let specular = m
            .specular
            .map(|s| (s[0] + s[1] + s[2]) / 3.0)
            .unwrap_or(0.04);
        let shininess = m.shininess.unwrap_or(16.0).max(1.0);
        scene.materials.push(Material {
            name: m.name.clone(),
            base_color,
            texture,
            specular,
            shininess,
        });
    }
    Ok(())
}

/// Appends one OBJ object: its material, its vertex attributes and its triangles.
fn add_model(scene: &mut Scene, model: &tobj::Model, path: &Path) -> Result<()> {
    let mesh = &model.mesh;
    if mesh.positions.len() % 3 != 0 || mesh.indices.len() % 3 != 0 {
        bail!(
            "{}: object '{}' has malformed faces",
            path.display(),
            model.name
        );
    }
    let material = match mesh.material_id {
        Some(id) if id < scene.materials.len() => id as u32,
        Some(id) => bail!(
            "{}: object '{}' uses material {id}, which the MTL does not define",
            path.display(),
            model.name
        ),
        None => {
            scene.materials.push(Material::plain(&model.name, [0.6; 3]));
            (scene.materials.len() - 1) as u32
        }
    };
    let (po, uo, no) = (
        scene.positions.len() as u32,
        scene.uvs.len() as u32,
        scene.normals.len() as u32,
    );
    scene.positions.extend(
        mesh.positions
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2])),
    );
    scene.uvs.extend(
        mesh.texcoords
            .chunks_exact(2)
            .map(|c| Vec2::new(c[0], c[1])),
    );
    scene.normals.extend(
        mesh.normals
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]).normalize_or_zero()),
    );
    let has_uv = !mesh.texcoord_indices.is_empty();
    if has_uv && mesh.texcoord_indices.len() != mesh.indices.len() {
        bail!(
            "{}: object '{}' gives texture coordinates for only some faces",
            path.display(),
            model.name
        );
    }
    read_faces(scene, mesh, material, [po, uo, no]);
    Ok(())
}

/// Appends a mesh's triangles, its position, UV and normal indices offset by `po`, `uo`, `no`.
fn read_faces(scene: &mut Scene, mesh: &tobj::Mesh, material: u32, [po, uo, no]: [u32; 3]) {
    let has_uv = !mesh.texcoord_indices.is_empty();
    let has_n = !mesh.normal_indices.is_empty();
    for (f, tri) in mesh.indices.chunks_exact(3).enumerate() {
        let k = f * 3;
        let uv = has_uv.then(|| [0, 1, 2].map(|j| mesh.texcoord_indices[k + j] + uo));
        let n = (has_n && mesh.normal_indices.len() == mesh.indices.len())
            .then(|| [0, 1, 2].map(|j| mesh.normal_indices[k + j] + no));
        scene.triangles.push(Triangle {
            p: [tri[0] + po, tri[1] + po, tri[2] + po],
            uv,
            n,
            material,
        });
    }
}
