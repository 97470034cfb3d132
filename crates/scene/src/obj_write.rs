//! Writes a [`Scene`] as OBJ + MTL + one PNG per texture, atomically, so it can be read back by
//! [`Scene::load`] (and by any other OBJ reader). Used by the mesh generator and by `export`.

use crate::mesh::Scene;
use anyhow::Result;
use std::fmt::Write as _;
use std::path::Path;

/// Writes `dir/<stem>.obj`, `dir/<stem>.mtl` and `dir/<stem>_tex<k>.png`.
pub fn write_obj(scene: &Scene, dir: &Path, stem: &str) -> Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut mtl = String::from("# written by cac\n");
    for (k, t) in scene.textures.iter().enumerate() {
        cac_core::io::save_png_atomic(&dir.join(format!("{stem}_tex{k}.png")), &t.to_rgb8())?;
    }
    for m in &scene.materials {
        let [r, g, b] = m.base_color;
        let s = m.specular;
        writeln!(mtl, "newmtl {}\nKa 0 0 0\nKd {r:.6} {g:.6} {b:.6}\nKs {s:.4} {s:.4} {s:.4}\nNs {:.2}\nillum 2", m.name, m.shininess)?;
        if let Some(t) = m.texture {
            writeln!(mtl, "map_Kd {stem}_tex{t}.png")?;
        }
        mtl.push('\n');
    }
    let mut obj = format!("# written by cac\nmtllib {stem}.mtl\n");
    for p in &scene.positions {
        writeln!(obj, "v {:.6} {:.6} {:.6}", p.x, p.y, p.z)?;
    }
    for t in &scene.uvs {
        writeln!(obj, "vt {:.6} {:.6}", t.x, t.y)?;
    }
    for n in &scene.normals {
        writeln!(obj, "vn {:.5} {:.5} {:.5}", n.x, n.y, n.z)?;
    }
    // One group per material, so that OBJ readers keep the part names.
    for (mi, m) in scene.materials.iter().enumerate() {
        let tris: Vec<_> = scene
            .triangles
            .iter()
            .filter(|t| t.material as usize == mi)
            .collect();
        if tris.is_empty() {
            continue;
        }
        writeln!(obj, "o {}\nusemtl {}", m.name, m.name)?;
        for t in tris {
            obj.push('f');
            for j in 0..3 {
                let p = t.p[j] + 1;
                match (t.uv, t.n) {
                    (Some(uv), Some(n)) => write!(obj, " {p}/{}/{}", uv[j] + 1, n[j] + 1)?,
                    (Some(uv), None) => write!(obj, " {p}/{}", uv[j] + 1)?,
                    (None, Some(n)) => write!(obj, " {p}//{}", n[j] + 1)?,
                    (None, None) => write!(obj, " {p}")?,
                }
            }
            obj.push('\n');
        }
    }
    cac_core::io::write_atomic(&dir.join(format!("{stem}.mtl")), mtl.as_bytes())?;
    cac_core::io::write_atomic(&dir.join(format!("{stem}.obj")), obj.as_bytes())?;
    Ok(())
}
