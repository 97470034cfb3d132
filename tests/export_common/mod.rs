//! Helpers shared by the export integration tests: inputs made at test time, and external tools
//! that must be present under CI (`CI=true`) and are skipped with a message locally (through
//! tests/support's `require`).
#![allow(dead_code)]

#[path = "../support/mod.rs"]
mod support;
pub use support::require;

use anyhow::{anyhow, bail, Context, Result};
use cac::bench::export as benchmark;
use cac::export::{self, ExportOptions, PrintMesh, Scale};
use glam::{Vec2, Vec3};
use quick_xml::events::Event;
use std::collections::HashMap;
use std::io::{Read, Seek};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Writes a synthetic camouflage PNG of `res` texels into `dir`.
pub fn camo_png(dir: &Path, res: usize) -> PathBuf {
    let p = dir.join("camo.png");
    cac::io::save_png_atomic(&p, &benchmark::synthetic_camouflage(res, 5).to_rgb8()).unwrap();
    p
}

/// The print mesh the exporter builds for `mesh` with `texture` at `scale`.
pub fn print_mesh(mesh: &Path, texture: &Path, scale: Scale) -> PrintMesh {
    let opts = ExportOptions::default();
    let scene = export::load_mesh(mesh, &opts.load).unwrap();
    let camo = export::load_texture(texture, &Default::default()).unwrap();
    export::prepare(&scene, &camo, scale).unwrap()
}

/// The third-party truck of the shared folder (`None`, a failure under CI, when it is missing).
pub fn truck() -> Option<PathBuf> {
    support::require_path(
        &support::root().join("../shared/meshes/CesiumMilkTruck/CesiumMilkTruck.glb"),
        "the Cesium milk truck of ../shared (a third-party mesh)",
    )
}

/// lib3mf (Python) present?
pub fn have_lib3mf() -> bool {
    require(
        "python3",
        &["-c", "import lib3mf"],
        "lib3mf (pip install lib3mf)",
    )
}

/// Runs the lib3mf strict-mode checker on a 3MF and returns its JSON summary.
pub fn lib3mf_check(file: &Path) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/check_3mf.py");
    let o = Command::new("python3")
        .arg(script)
        .arg(file)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "lib3mf refused {}: {}",
        file.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

/// PrusaSlicer present?
pub fn have_prusa() -> bool {
    require(
        "prusa-slicer",
        &["--help"],
        "PrusaSlicer CLI (apt-get install prusa-slicer)",
    )
}

/// `prusa-slicer --info FILE`: the `key = value` lines.
pub fn prusa_info(file: &Path) -> std::collections::HashMap<String, String> {
    let o = Command::new("prusa-slicer")
        .arg("--info")
        .arg(file)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "PrusaSlicer failed on {}: {}{}",
        file.display(),
        out,
        String::from_utf8_lossy(&o.stderr)
    );
    out.lines()
        .filter_map(|l| l.split_once(" = "))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect()
}

/// Poppler's pdfinfo present?
pub fn have_pdfinfo() -> bool {
    require(
        "pdfinfo",
        &["-v"],
        "pdfinfo (apt-get install poppler-utils)",
    )
}

/// What [`read_3mf`] finds in a 3MF written by `cac export` (one mesh object).
#[derive(Clone, Debug, Default)]
pub struct Model3mf {
    pub unit: String,
    pub vertices: Vec<Vec3>,
    /// `(v, pid, [p1, p2, p3])`; `pid` 0 when absent.
    pub triangles: Vec<([u32; 3], u32, [u32; 3])>,
    pub color_groups: HashMap<u32, Vec<[u8; 3]>>,
    /// id → (texture id, coordinates).
    pub tex_groups: HashMap<u32, (u32, Vec<Vec2>)>,
    /// texture2d id → package path.
    pub textures: HashMap<u32, String>,
    /// Package files.
    pub files: Vec<String>,
}

impl Model3mf {
    /// The three corner colours of triangle `i` if it is coloured by a colour group.
    pub fn corner_colours(&self, i: usize) -> Option<[[u8; 3]; 3]> {
        let (_, pid, p) = self.triangles[i];
        let g = self.color_groups.get(&pid)?;
        Some([
            g.get(p[0] as usize)?.to_owned(),
            *g.get(p[1] as usize)?,
            *g.get(p[2] as usize)?,
        ])
    }
}

/// Reads the model part of a 3MF package as `cac export` writes it (the tests' reader: lib3mf and
/// PrusaSlicer are the independent ones).
pub fn read_3mf(path: &Path) -> Result<Model3mf> {
    let f = std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    read_from(f).with_context(|| format!("cannot read 3MF {}", path.display()))
}

fn read_from<R: Read + Seek>(r: R) -> Result<Model3mf> {
    let mut zip = zip::ZipArchive::new(r)?;
    let mut m = Model3mf {
        files: zip.file_names().map(String::from).collect(),
        ..Default::default()
    };
    let mut xml = String::new();
    zip.by_name("3D/3dmodel.model")?.read_to_string(&mut xml)?;
    let mut rd = quick_xml::Reader::from_str(&xml);
    let mut group: Option<(bool, u32)> = None; // (is colour group, id)
    loop {
        let ev = rd.read_event()?;
        let (e, _is_empty) = match &ev {
            Event::Start(e) => (e, false),
            Event::Empty(e) => (e, true),
            Event::End(e) => {
                if matches!(e.name().as_ref(), b"m:colorgroup" | b"m:texture2dgroup") {
                    group = None;
                }
                continue;
            }
            Event::Eof => break,
            _ => continue,
        };
        let mut a: HashMap<String, String> = HashMap::new();
        for at in e.attributes() {
            let at = at?;
            a.insert(
                String::from_utf8_lossy(at.key.as_ref()).into_owned(),
                at.normalized_value(quick_xml::XmlVersion::Explicit1_0)?
                    .into_owned(),
            );
        }
        let num = |k: &str| -> Result<f32> {
            a.get(k)
                .ok_or_else(|| anyhow!("missing attribute {k}"))?
                .parse::<f32>()
                .with_context(|| format!("attribute {k}"))
        };
        let int = |k: &str| -> Result<u32> {
            a.get(k).map_or(Ok(0), |v| {
                v.parse::<u32>().with_context(|| format!("attribute {k}"))
            })
        };
        match e.name().as_ref() {
            b"model" => m.unit = a.get("unit").cloned().unwrap_or_default(),
            b"vertex" => m.vertices.push(Vec3::new(num("x")?, num("y")?, num("z")?)),
            b"triangle" => {
                let p1 = int("p1")?;
                let p2 = a.get("p2").map_or(Ok(p1), |_| int("p2"))?;
                let p3 = a.get("p3").map_or(Ok(p1), |_| int("p3"))?;
                m.triangles.push((
                    [int("v1")?, int("v2")?, int("v3")?],
                    int("pid")?,
                    [p1, p2, p3],
                ));
            }
            b"m:colorgroup" => {
                group = Some((true, int("id")?));
                m.color_groups.insert(int("id")?, vec![]);
            }
            b"m:texture2dgroup" => {
                group = Some((false, int("id")?));
                m.tex_groups.insert(int("id")?, (int("texid")?, vec![]));
            }
            b"m:texture2d" => {
                m.textures
                    .insert(int("id")?, a.get("path").cloned().unwrap_or_default());
            }
            b"m:color" => {
                let Some((true, id)) = group else {
                    bail!("m:color outside a colour group")
                };
                let s = a
                    .get("color")
                    .ok_or_else(|| anyhow!("m:color without color"))?;
                let hex = s.trim_start_matches('#');
                if hex.len() < 6 {
                    bail!("bad colour '{s}'");
                }
                let c = |i: usize| u8::from_str_radix(&hex[i..i + 2], 16);
                m.color_groups
                    .get_mut(&id)
                    .unwrap()
                    .push([c(0)?, c(2)?, c(4)?]);
            }
            b"m:tex2coord" => {
                let Some((false, id)) = group else {
                    bail!("m:tex2coord outside a texture group")
                };
                let q = Vec2::new(num("u")?, num("v")?);
                m.tex_groups.get_mut(&id).unwrap().1.push(q);
            }
            _ => {}
        }
    }
    Ok(m)
}
