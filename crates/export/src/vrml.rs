//! VRML 2.0 (VRML97, ISO/IEC 14772-1) with its textures: the format most full-colour print
//! services ask for besides 3MF and OBJ. One `Shape` per texture (an `ImageTexture` with the PNG
//! beside the file, per-corner `TextureCoordinate`s) and one per solid colour (a `Material`'s
//! `diffuseColor`); every `IndexedFaceSet` is `solid TRUE` and counter-clockwise. Coordinates are in
//! millimetres (said in the file's header comment: services ask for the unit on upload), +Z up.

use crate::mesh::{Paint, PrintMesh};
use anyhow::Result;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What one shape is painted with: a texture index, or a solid colour's 8-bit sRGB.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Look {
    Texture(u32),
    Solid([u8; 3]),
}

/// Writes `<stem>.wrl` and its textures `<stem>_wrl_texK.png` into `dir`; returns the files.
pub(crate) fn write(mesh: &PrintMesh, dir: &Path, stem: &str) -> Result<Vec<PathBuf>> {
    let mut shapes: BTreeMap<Look, Vec<usize>> = BTreeMap::new();
    for (i, t) in mesh.tris.iter().enumerate() {
        let look = match t.paint {
            Paint::Texture { tex, .. } => Look::Texture(tex),
            Paint::Solid(c) => Look::Solid(cac_core::colour::to_rgb8(c)),
        };
        shapes.entry(look).or_default().push(i);
    }
    let mut s = format!(
        "#VRML V2.0 utf8\n# {}: written by cac export; units: millimetres, +Z up\n",
        mesh.name
    );
    let mut files = vec![];
    for (look, tris) in &shapes {
        match look {
            Look::Texture(k) => {
                let png = format!("{stem}_wrl_tex{k}.png");
                let rgb = mesh.textures[*k as usize].to_rgb8();
                cac_core::io::save_png_atomic(&dir.join(&png), &rgb)?;
                files.push(dir.join(&png));
                writeln!(
                    s,
                    "Shape {{\n  appearance Appearance {{ texture ImageTexture {{ url \"{png}\" }} }}"
                )?;
            }
            Look::Solid(c) => {
                let [r, g, b] = c.map(|v| v as f32 / 255.0);
                writeln!(
                    s,
                    "Shape {{\n  appearance Appearance {{ material Material {{ diffuseColor {r:.4} {g:.4} {b:.4} }} }}"
                )?;
            }
        }
        face_set(&mut s, mesh, tris, matches!(look, Look::Texture(_)))?;
        s.push_str("}\n");
    }
    let wrl = dir.join(format!("{stem}.wrl"));
    cac_core::io::write_atomic(&wrl, s.as_bytes())?;
    files.insert(0, wrl);
    Ok(files)
}

/// The `geometry IndexedFaceSet` of `tris`: only the vertices they use, renumbered.
fn face_set(s: &mut String, mesh: &PrintMesh, tris: &[usize], uv: bool) -> Result<()> {
    let mut index: BTreeMap<u32, usize> = BTreeMap::new();
    let mut points = String::new();
    let mut coord = String::new();
    let (mut uvs, mut uv_index) = (String::new(), String::new());
    for (n, &i) in tris.iter().enumerate() {
        let t = &mesh.tris[i];
        for v in t.v {
            let next = index.len();
            let k = *index.entry(v).or_insert_with(|| {
                let p = mesh.positions[v as usize];
                let _ = write!(points, "{} {} {}, ", p.x, p.y, p.z);
                next
            });
            write!(coord, "{k}, ")?;
        }
        coord.push_str("-1,\n");
        if let Paint::Texture { uv: c, .. } = t.paint {
            for (j, p) in c.iter().enumerate() {
                write!(uvs, "{} {}, ", p.x, p.y)?;
                write!(uv_index, "{}, ", 3 * n + j)?;
            }
            uv_index.push_str("-1,\n");
        }
    }
    writeln!(
        s,
        "  geometry IndexedFaceSet {{\n    solid TRUE\n    ccw TRUE"
    )?;
    writeln!(s, "    coord Coordinate {{ point [ {points}] }}")?;
    writeln!(s, "    coordIndex [\n{coord}    ]")?;
    if uv {
        writeln!(s, "    texCoord TextureCoordinate {{ point [ {uvs}] }}")?;
        writeln!(s, "    texCoordIndex [\n{uv_index}    ]")?;
    }
    s.push_str("  }\n");
    Ok(())
}
