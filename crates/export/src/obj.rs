//! OBJ outputs: OBJ + MTL + PNG through [`cac_scene::obj_write`] (optionally zipped into one
//! bundle), and a vertex-colour OBJ (`v x y z r g b`) from the bake, where a vertex is
//! duplicated wherever its corners carry different colours (texture seams). Millimetres, +Z up.

use crate::bake::Baked;
use crate::mesh::{Paint, PrintMesh};
use anyhow::{Context, Result};
use cac_core::colour::to_rgb8;
use cac_scene::{Material, Scene, Triangle};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// The print mesh as a scene (positions in mm, per-corner UVs, one material per part and
/// texture) for the OBJ writer.
fn to_scene(mesh: &PrintMesh) -> Scene {
    let mut s = Scene::empty(&mesh.name);
    s.positions = mesh.positions.clone();
    s.textures = mesh.textures.clone();
    let mut mats: HashMap<(u32, Option<u32>, [u32; 3]), u32> = HashMap::new();
    for t in &mesh.tris {
        let (tex, colour, uv) = match t.paint {
            Paint::Texture { tex, uv } => (Some(tex), [1.0; 3], Some(uv)),
            Paint::Solid(c) => (None, c, None),
        };
        let key = (t.part, tex, colour.map(f32::to_bits));
        let material = *mats.entry(key).or_insert_with(|| {
            let base = &mesh.parts[t.part as usize];
            let name = match (tex, mesh.painted.get(t.part as usize).copied()) {
                (Some(0), _) => format!("{}_camouflage", crate::mesh::sanitize(base)),
                (Some(k), _) => format!("{}_tex{k}", crate::mesh::sanitize(base)),
                _ => crate::mesh::sanitize(base),
            };
            let mut m = Material::plain(&name, colour);
            m.texture = tex.map(|k| k as usize);
            m.specular = 0.0;
            s.materials.push(m);
            s.paintable.push(tex == Some(0));
            s.materials.len() as u32 - 1
        });
        let uv = uv.map(|uv| {
            let base = s.uvs.len() as u32;
            s.uvs.extend(uv);
            [base, base + 1, base + 2]
        });
        s.triangles.push(Triangle {
            p: t.v,
            uv,
            n: None,
            material,
        });
    }
    s
}

/// Writes `<stem>.obj`, `<stem>.mtl`, `<stem>_texK.png` into `dir`, and with `zip` also
/// `<stem>_obj.zip` holding the three kinds of file. Returns the files written.
pub(crate) fn write_textured(
    mesh: &PrintMesh,
    dir: &Path,
    stem: &str,
    zip: bool,
) -> Result<Vec<PathBuf>> {
    let scene = to_scene(mesh);
    cac_scene::obj_write::write_obj(&scene, dir, stem)
        .with_context(|| format!("cannot write OBJ into {}", dir.display()))?;
    let mut files = vec![
        dir.join(format!("{stem}.obj")),
        dir.join(format!("{stem}.mtl")),
    ];
    files.extend((0..scene.textures.len()).map(|k| dir.join(format!("{stem}_tex{k}.png"))));
    if zip {
        let bundle = dir.join(format!("{stem}_obj.zip"));
        cac_core::io::write_atomic_with(&bundle, |w| {
            let mut z = zip::ZipWriter::new(w);
            let opts = zip::write::SimpleFileOptions::default()
                .compression_method(zip::CompressionMethod::Deflated);
            for f in &files {
                let name = f.file_name().unwrap().to_string_lossy();
                z.start_file(name.as_ref(), opts)?;
                z.write_all(
                    &std::fs::read(f).with_context(|| format!("cannot read {}", f.display()))?,
                )?;
            }
            z.finish()?;
            Ok(())
        })?;
        files.push(bundle);
    }
    Ok(files)
}

/// Writes the bake as an OBJ with per-vertex colours (`v x y z r g b`, sRGB in 0..1).
pub(crate) fn write_vertex_colour(baked: &Baked, path: &Path) -> Result<()> {
    let mut index: HashMap<(u32, [u8; 3]), u32> = HashMap::new();
    let mut verts = String::new();
    let mut faces = String::new();
    for t in &baked.tris {
        let mut f = [0u32; 3];
        for (k, fk) in f.iter_mut().enumerate() {
            let c = to_rgb8(t.colour[k]);
            let n = index.len() as u32 + 1;
            *fk = *index.entry((t.v[k], c)).or_insert_with(|| {
                let p = baked.positions[t.v[k] as usize];
                let _ = writeln!(
                    verts,
                    "v {} {} {} {:.4} {:.4} {:.4}",
                    p.x,
                    p.y,
                    p.z,
                    c[0] as f32 / 255.0,
                    c[1] as f32 / 255.0,
                    c[2] as f32 / 255.0
                );
                n
            });
        }
        writeln!(faces, "f {} {} {}", f[0], f[1], f[2])?;
    }
    let head = format!(
        "# written by cac export: baked vertex colours (sRGB), millimetres, +Z up\n# {} vertices, {} triangles\n",
        index.len(),
        baked.tris.len()
    );
    cac_core::io::write_atomic_with(path, |w| {
        w.write_all(head.as_bytes())?;
        w.write_all(verts.as_bytes())?;
        w.write_all(faces.as_bytes())?;
        Ok(())
    })
}
