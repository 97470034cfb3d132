//! 3MF writer (core + Materials and Properties extension) on the `zip` and `quick-xml` crates,
//! and a small reader of what it writes (for round-trip checks).
//!
//! Package layout: `[Content_Types].xml`, `_rels/.rels` (→ `/3D/3dmodel.model`),
//! `3D/_rels/3dmodel.model.rels` (→ each texture, relationship type `3dtexture`),
//! `3D/Textures/texK.png`, `3D/3dmodel.model` (`unit="millimeter"`). UVs are written as they
//! are in the scene: origin lower-left, `v` up, which is 3MF's convention. Every triangle of the
//! textured and baked-colour files carries `pid`/`p1`/`p2`/`p3`; the object's own `pid`/`pindex`
//! is that of its first triangle. The painted multi-material file ([`write_painted`]) has no
//! colour properties: each triangle carries the slicers' painting (`slic3rpe:mmu_segmentation`
//! and `paint_color`, see [`super::painted`]) and the package holds the slicers' settings files
//! (`Metadata/Slic3r_PE.config`, `Metadata/project_settings.config`).

use crate::bake::Baked;
use crate::mesh::{Paint, PrintMesh};
use crate::painted;
use anyhow::{Context, Result};
use cac_core::colour::to_rgb8;
use glam::{Vec2, Vec3};
use quick_xml::events::{BytesDecl, BytesEnd, BytesStart, Event};
use quick_xml::Writer;
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;
use zip::write::SimpleFileOptions;

const NS_CORE: &str = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02";
const NS_MAT: &str = "http://schemas.microsoft.com/3dmanufacturing/material/2015/02";
const REL_MODEL: &str = "http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel";
const REL_TEXTURE: &str = "http://schemas.microsoft.com/3dmanufacturing/2013/01/3dtexture";
const CT_RELS: &str = "application/vnd.openxmlformats-package.relationships+xml";
const CT_MODEL: &str = "application/vnd.ms-package.3dmanufacturing-3dmodel+xml";
const CT_TEXTURE: &str = "application/vnd.ms-package.3dmanufacturing-3dmodeltexture";
/// PrusaSlicer's namespace for its attributes and metadata (`slic3rpe:`).
const NS_SLIC3RPE: &str = "http://schemas.slic3r.org/3mf/2017/06";

type XmlW<'a, W> = Writer<&'a mut zip::ZipWriter<W>>;

fn start<W: Write>(w: &mut Writer<W>, name: &str, attrs: &[(&str, &str)]) -> Result<()> {
    w.write_event(Event::Start(
        BytesStart::new(name).with_attributes(attrs.iter().copied()),
    ))?;
    Ok(())
}
fn empty<W: Write>(w: &mut Writer<W>, name: &str, attrs: &[(&str, &str)]) -> Result<()> {
    w.write_event(Event::Empty(
        BytesStart::new(name).with_attributes(attrs.iter().copied()),
    ))?;
    Ok(())
}
fn end<W: Write>(w: &mut Writer<W>, name: &str) -> Result<()> {
    w.write_event(Event::End(BytesEnd::new(name)))?;
    Ok(())
}
fn decl<W: Write>(w: &mut Writer<W>) -> Result<()> {
    w.write_event(Event::Decl(BytesDecl::new("1.0", Some("UTF-8"), None)))?;
    Ok(())
}

/// Writes the package around a model: parts, relationships, textures (PNG bytes), other files
/// (`(path in the package, bytes)`, `.config` files as text), then the model XML produced by
/// `model`. Atomic (temporary file, then rename).
fn package<F>(path: &Path, textures: &[Vec<u8>], extra: &[(&str, Vec<u8>)], model: F) -> Result<()>
where
    F: FnOnce(&mut XmlW<'_, &mut std::io::BufWriter<&mut std::fs::File>>) -> Result<()>,
{
    cac_core::io::write_atomic_with(path, |out| {
        let mut zip = zip::ZipWriter::new(out);
        let deflate =
            SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
        let stored =
            SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
        zip.start_file("[Content_Types].xml", deflate)?;
        {
            let mut w = Writer::new(&mut zip);
            decl(&mut w)?;
            start(
                &mut w,
                "Types",
                &[(
                    "xmlns",
                    "http://schemas.openxmlformats.org/package/2006/content-types",
                )],
            )?;
            empty(
                &mut w,
                "Default",
                &[("Extension", "rels"), ("ContentType", CT_RELS)],
            )?;
            empty(
                &mut w,
                "Default",
                &[("Extension", "model"), ("ContentType", CT_MODEL)],
            )?;
            if !textures.is_empty() {
                empty(
                    &mut w,
                    "Default",
                    &[("Extension", "png"), ("ContentType", CT_TEXTURE)],
                )?;
            }
            if extra.iter().any(|(name, _)| name.ends_with(".config")) {
                empty(
                    &mut w,
                    "Default",
                    &[("Extension", "config"), ("ContentType", "text/plain")],
                )?;
            }
            end(&mut w, "Types")?;
        }
        let rels =
            |zip: &mut zip::ZipWriter<_>, name: &str, targets: &[(String, &str)]| -> Result<()> {
                zip.start_file(name, deflate)?;
                let mut w = Writer::new(zip);
                decl(&mut w)?;
                start(
                    &mut w,
                    "Relationships",
                    &[(
                        "xmlns",
                        "http://schemas.openxmlformats.org/package/2006/relationships",
                    )],
                )?;
                for (i, (target, ty)) in targets.iter().enumerate() {
                    let id = format!("rel{i}");
                    empty(
                        &mut w,
                        "Relationship",
                        &[("Target", target), ("Id", &id), ("Type", ty)],
                    )?;
                }
                end(&mut w, "Relationships")
            };
        rels(
            &mut zip,
            "_rels/.rels",
            &[("/3D/3dmodel.model".into(), REL_MODEL)],
        )?;
        if !textures.is_empty() {
            let t: Vec<(String, &str)> = (0..textures.len())
                .map(|k| (format!("/3D/Textures/tex{k}.png"), REL_TEXTURE))
                .collect();
            rels(&mut zip, "3D/_rels/3dmodel.model.rels", &t)?;
        }
        for (k, png) in textures.iter().enumerate() {
            zip.start_file(format!("3D/Textures/tex{k}.png"), stored)?;
            zip.write_all(png)?;
        }
        for (name, bytes) in extra {
            zip.start_file(*name, deflate)?;
            zip.write_all(bytes)?;
        }
        zip.start_file("3D/3dmodel.model", deflate)?;
        {
            let mut w = Writer::new(&mut zip);
            decl(&mut w)?;
            model(&mut w)?;
        }
        zip.finish()?;
        Ok(())
    })
}

fn model_start<W: Write>(w: &mut Writer<W>, title: &str) -> Result<()> {
    model_start_with(w, title, &[("xmlns:m", NS_MAT)], &[])
}

/// The `<model>` element with extra namespaces and metadata, and `<resources>` opened.
fn model_start_with<W: Write>(
    w: &mut Writer<W>,
    title: &str,
    namespaces: &[(&str, &str)],
    metadata: &[(&str, &str)],
) -> Result<()> {
    let mut attrs = vec![
        ("unit", "millimeter"),
        ("xml:lang", "en-US"),
        ("xmlns", NS_CORE),
    ];
    attrs.extend_from_slice(namespaces);
    start(w, "model", &attrs)?;
    let base = [("Title", title), ("Application", "cac export")];
    for &(name, value) in base.iter().chain(metadata) {
        start(w, "metadata", &[("name", name)])?;
        w.write_event(Event::Text(quick_xml::events::BytesText::new(value)))?;
        end(w, "metadata")?;
    }
    start(w, "resources", &[])
}

/// Writes the object with its vertices and triangles; `props[i]` is triangle i's
/// `(pid, [p1,p2,p3])`.
fn object<W: Write>(
    w: &mut Writer<W>,
    id: u32,
    name: &str,
    positions: &[Vec3],
    tris: impl Iterator<Item = [u32; 3]>,
    props: &[(u32, [u32; 3])],
) -> Result<()> {
    let (pid, pindex) = (props[0].0.to_string(), props[0].1[0].to_string());
    let id = id.to_string();
    start(
        w,
        "object",
        &[
            ("id", &id),
            ("type", "model"),
            ("name", name),
            ("pid", &pid),
            ("pindex", &pindex),
        ],
    )?;
    vertices(w, positions)?;
    start(w, "triangles", &[])?;
    for (t, (pid, p)) in tris.zip(props) {
        let s: [String; 7] = [t[0], t[1], t[2], *pid, p[0], p[1], p[2]].map(|x| x.to_string());
        let names = ["v1", "v2", "v3", "pid", "p1", "p2", "p3"];
        let attrs: Vec<(&str, &str)> = names
            .iter()
            .zip(&s)
            .map(|(n, v)| (*n, v.as_str()))
            .collect();
        empty(w, "triangle", &attrs)?;
    }
    object_end(w, &id)
}

/// Opens `<mesh>` and writes `<vertices>`.
fn vertices<W: Write>(w: &mut Writer<W>, positions: &[Vec3]) -> Result<()> {
    start(w, "mesh", &[])?;
    start(w, "vertices", &[])?;
    for p in positions {
        let (x, y, z) = (p.x.to_string(), p.y.to_string(), p.z.to_string());
        empty(w, "vertex", &[("x", &x), ("y", &y), ("z", &z)])?;
    }
    end(w, "vertices")
}

/// Closes `<triangles>`, the object and the resources, and writes the build (one item).
fn object_end<W: Write>(w: &mut Writer<W>, id: &str) -> Result<()> {
    end(w, "triangles")?;
    end(w, "mesh")?;
    end(w, "object")?;
    end(w, "resources")?;
    start(w, "build", &[])?;
    empty(w, "item", &[("objectid", id)])?;
    end(w, "build")?;
    end(w, "model")
}

/// Deduplicating index of colours.
#[derive(Default)]
struct Colours {
    list: Vec<[u8; 3]>,
    index: HashMap<[u8; 3], u32>,
}
impl Colours {
    fn get(&mut self, c: [f32; 3]) -> u32 {
        let q = to_rgb8(c);
        *self.index.entry(q).or_insert_with(|| {
            self.list.push(q);
            self.list.len() as u32 - 1
        })
    }
    fn write<W: Write>(&self, w: &mut Writer<W>, id: u32) -> Result<()> {
        start(w, "m:colorgroup", &[("id", &id.to_string())])?;
        for c in &self.list {
            let s = format!("#{:02X}{:02X}{:02X}", c[0], c[1], c[2]);
            empty(w, "m:color", &[("color", &s)])?;
        }
        end(w, "m:colorgroup")
    }
}

fn png_bytes(t: &cac_scene::Texture) -> Result<Vec<u8>> {
    let mut buf = Vec::new();
    t.to_rgb8()
        .write_to(&mut std::io::Cursor::new(&mut buf), image::ImageFormat::Png)
        .context("cannot encode texture PNG")?;
    Ok(buf)
}

/// Textured 3MF: one `m:texture2d` + `m:texture2dgroup` per texture, a `m:colorgroup` for
/// untextured parts.
pub(crate) fn write_textured(mesh: &PrintMesh, path: &Path) -> Result<()> {
    let used: Vec<bool> = (0..mesh.textures.len())
        .map(|k| {
            mesh.tris
                .iter()
                .any(|t| matches!(t.paint, Paint::Texture { tex, .. } if tex as usize == k))
        })
        .collect();
    // Texture k (if used) gets package file texN, texture2d id and group id.
    let mut pngs = vec![];
    let mut tex_ids: Vec<Option<(u32, u32)>> = vec![None; mesh.textures.len()];
    let mut next_id = 1;
    for (k, t) in mesh.textures.iter().enumerate() {
        if used[k] {
            pngs.push(png_bytes(t)?);
            tex_ids[k] = Some((next_id, next_id + 1));
            next_id += 2;
        }
    }
    let colour_id = next_id;
    let object_id = next_id + 1;
    // Per texture: its coordinates and their index by bit pattern.
    type Coords = (Vec<Vec2>, HashMap<[u32; 2], u32>);
    let mut coords: Vec<Coords> = vec![(vec![], HashMap::new()); mesh.textures.len()];
    let mut colours = Colours::default();
    let props: Vec<(u32, [u32; 3])> = mesh
        .tris
        .iter()
        .map(|t| match t.paint {
            Paint::Texture { tex, uv } => {
                let (list, idx) = &mut coords[tex as usize];
                let p = uv.map(|q| {
                    *idx.entry([q.x.to_bits(), q.y.to_bits()])
                        .or_insert_with(|| {
                            list.push(q);
                            list.len() as u32 - 1
                        })
                });
                (tex_ids[tex as usize].unwrap().1, p)
            }
            Paint::Solid(c) => (colour_id, [colours.get(c); 3]),
        })
        .collect();
    package(path, &pngs, &[], |w| {
        model_start(w, &mesh.name)?;
        let mut file = 0;
        for (k, ids) in tex_ids.iter().enumerate() {
            let Some((tid, gid)) = ids else { continue };
            let p = format!("/3D/Textures/tex{file}.png");
            file += 1;
            empty(
                w,
                "m:texture2d",
                &[
                    ("id", &tid.to_string()),
                    ("path", &p),
                    ("contenttype", "image/png"),
                    ("tilestyleu", "wrap"),
                    ("tilestylev", "wrap"),
                    ("filter", "linear"),
                ],
            )?;
            start(
                w,
                "m:texture2dgroup",
                &[("id", &gid.to_string()), ("texid", &tid.to_string())],
            )?;
            for q in &coords[k].0 {
                empty(
                    w,
                    "m:tex2coord",
                    &[("u", &q.x.to_string()), ("v", &q.y.to_string())],
                )?;
            }
            end(w, "m:texture2dgroup")?;
        }
        if !colours.list.is_empty() {
            colours.write(w, colour_id)?;
        }
        object(
            w,
            object_id,
            &mesh.name,
            &mesh.positions,
            mesh.tris.iter().map(|t| t.v),
            &props,
        )
    })
}

/// Baked-colour 3MF: the subdivided mesh with one `m:colorgroup` entry per distinct corner
/// colour (8-bit sRGB); every triangle coloured.
pub(crate) fn write_colored(mesh: &PrintMesh, baked: &Baked, path: &Path) -> Result<()> {
    let mut colours = Colours::default();
    let props: Vec<(u32, [u32; 3])> = baked
        .tris
        .iter()
        .map(|t| (1, t.colour.map(|c| colours.get(c))))
        .collect();
    package(path, &[], &[], |w| {
        model_start(w, &mesh.name)?;
        colours.write(w, 1)?;
        object(
            w,
            2,
            &mesh.name,
            &baked.positions,
            baked.tris.iter().map(|t| t.v),
            &props,
        )
    })
}

/// Painted multi-material 3MF for slicers: the mesh as it is, no colour properties; every
/// triangle carries its painting ([`painted::encode`]) twice, as `slic3rpe:mmu_segmentation`
/// (PrusaSlicer) and `paint_color` (Bambu Studio, OrcaSlicer); the model declares
/// `slic3rpe:MmPaintingVersion` 1; the package holds `Metadata/Slic3r_PE.config` (PrusaSlicer's
/// extruder count, colours and wipe tower, [`painted::prusa_config`]) and
/// `Metadata/project_settings.config` (Bambu Studio / OrcaSlicer's filament colours,
/// [`painted::bambu_config`]).
pub(crate) fn write_painted(
    mesh: &PrintMesh,
    trees: &[painted::Node],
    fdm: &cac_core::printer::Fdm,
    palette: &[[f32; 3]],
    printer_name: &str,
    build_volume_mm: Option<[f32; 3]>,
    path: &Path,
) -> Result<()> {
    anyhow::ensure!(
        trees.len() == mesh.tris.len(),
        "{} paintings for {} triangles",
        trees.len(),
        mesh.tris.len()
    );
    let extra = [
        (
            "Metadata/Slic3r_PE.config",
            painted::prusa_config(fdm, palette, printer_name, build_volume_mm).into_bytes(),
        ),
        (
            "Metadata/project_settings.config",
            painted::bambu_config(fdm, palette).into_bytes(),
        ),
    ];
    package(path, &[], &extra, |w| {
        model_start_with(
            w,
            &mesh.name,
            &[("xmlns:slic3rpe", NS_SLIC3RPE)],
            &[("slic3rpe:MmPaintingVersion", "1")],
        )?;
        start(
            w,
            "object",
            &[("id", "1"), ("type", "model"), ("name", &mesh.name)],
        )?;
        vertices(w, &mesh.positions)?;
        start(w, "triangles", &[])?;
        for (t, tree) in mesh.tris.iter().zip(trees) {
            let [a, b, c] = t.v.map(|i| i.to_string());
            let code = painted::encode(tree);
            empty(
                w,
                "triangle",
                &[
                    ("v1", &a),
                    ("v2", &b),
                    ("v3", &c),
                    ("slic3rpe:mmu_segmentation", &code),
                    ("paint_color", &code),
                ],
            )?;
        }
        object_end(w, "1")
    })
}
