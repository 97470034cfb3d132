//! Fabrication: bakes a learned camouflage texture into files that printers and slicers accept.
//!
//! [`prepare`] turns a [`Scene`] plus the camouflage atlas into a [`PrintMesh`]: welded positions
//! in millimetres at the chosen scale (3MF frame: **+Z up**, X = the object's length, ground at
//! `z = 0`), per-corner paint (texture + UVs, or a solid colour) and a print-readiness report
//! ([`printcheck`]). Writers then produce:
//! - [`threemf`]: textured 3MF (`m:texture2d` + `m:texture2dgroup`) and baked-colour 3MF
//!   (`m:colorgroup` per corner after [`bake`]'s adaptive subdivision);
//! - [`obj`]: OBJ + MTL + PNG (optionally zipped) and a vertex-colour OBJ from the same bake;
//! - [`sheets`]: paste-on sheets at true physical size (PNG pages, PDF, JSON sidecar).
//!
//! See `docs/export.md` for the conventions, tolerances and the bake's error/run-time table.

pub mod bake;
pub mod benchmark;
pub mod obj;
pub mod pdf;
pub mod printcheck;
pub mod sheets;
pub mod texture;
pub mod threemf;

use crate::scene::{LoadOptions, PaintRule, Scene, Texture};
use anyhow::{bail, ensure, Context, Result};
use glam::{Vec2, Vec3};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::str::FromStr;

pub use bake::{BakeLimits, Baked};
pub use printcheck::PrintReport;

/// Largest accepted texture side, in texels (larger ones are refused before decoding).
pub const MAX_TEXTURE_SIDE: u32 = 16384;

/// The object scale `1:N` (the printed object is `N` times smaller than the real one).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Scale {
    pub denominator: f64,
}

impl Scale {
    /// Millimetres on the print per metre of the real object.
    pub fn mm_per_m(&self) -> f64 {
        1000.0 / self.denominator
    }
}

impl FromStr for Scale {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Scale> {
        let (num, den) = match s.split_once(':') {
            Some((a, b)) => (a.trim(), b.trim()),
            None => ("1", s.trim()),
        };
        let num: f64 = num
            .parse()
            .with_context(|| format!("scale '{s}': '{num}' is not a number (expected 1:N)"))?;
        let den: f64 = den
            .parse()
            .with_context(|| format!("scale '{s}': '{den}' is not a number (expected 1:N)"))?;
        ensure!(
            num.is_finite() && den.is_finite() && num > 0.0 && den > 0.0,
            "scale '{s}' must be 1:N with N > 0 (a zero or negative scale has no size)"
        );
        Ok(Scale {
            denominator: den / num,
        })
    }
}

/// An output format of `cac export`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
pub enum Format {
    /// `<name>_texture.3mf`: Materials extension texture.
    ThreeMfTexture,
    /// `<name>_color.3mf`: baked per-corner colours.
    ThreeMfColor,
    /// `<name>.obj` + `.mtl` + PNGs (and `<name>_obj.zip` when zipping).
    Obj,
    /// `<name>_vc.obj`: baked vertex colours.
    ObjVc,
    /// `sheets/`: paste-on pages (PNG, PDF, JSON).
    Sheets,
}

impl FromStr for Format {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Format> {
        Ok(match s.trim() {
            "3mf-texture" => Format::ThreeMfTexture,
            "3mf-color" | "3mf-colour" => Format::ThreeMfColor,
            "obj" => Format::Obj,
            "obj-vc" => Format::ObjVc,
            "sheets" => Format::Sheets,
            o => bail!(
                "unknown export format '{o}' (expected 3mf-texture, 3mf-color, obj, obj-vc, sheets)"
            ),
        })
    }
}

impl Format {
    pub const ALL: [Format; 5] = [
        Format::ThreeMfTexture,
        Format::ThreeMfColor,
        Format::Obj,
        Format::ObjVc,
        Format::Sheets,
    ];
    /// Does this format carry printable geometry (and so need a closed mesh)?
    pub fn is_geometry(&self) -> bool {
        !matches!(self, Format::Sheets)
    }
}

/// Everything `cac export` needs besides the input files.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    pub formats: Vec<Format>,
    pub scale: Scale,
    pub bake: BakeLimits,
    pub sheets: sheets::SheetOptions,
    /// Also bundle the OBJ, MTL and PNGs into `<name>_obj.zip`.
    pub zip_obj: bool,
    /// Write geometry even when the mesh is open or non-manifold (a warning instead of an error).
    pub allow_open: bool,
    pub load: LoadOptions,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            formats: Format::ALL.to_vec(),
            scale: Scale { denominator: 1.0 },
            bake: BakeLimits::default(),
            sheets: sheets::SheetOptions::default(),
            zip_obj: false,
            allow_open: false,
            load: LoadOptions::default(),
        }
    }
}

/// How one triangle corner set is coloured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Paint {
    /// Texture `tex` of [`PrintMesh::textures`] at per-corner UVs (origin lower-left, v up).
    Texture { tex: u32, uv: [Vec2; 3] },
    /// One sRGB colour.
    Solid([f32; 3]),
}

/// One printable triangle: welded vertex indices (counter-clockwise seen from outside).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrintTri {
    pub v: [u32; 3],
    pub paint: Paint,
    /// Index into [`PrintMesh::parts`].
    pub part: u32,
}

/// A mesh ready for the writers: millimetres, +Z up, welded, checked.
#[derive(Clone, Debug)]
pub struct PrintMesh {
    pub name: String,
    pub positions: Vec<Vec3>,
    pub tris: Vec<PrintTri>,
    /// Final colours (display sRGB); texture 0 is the camouflage. Other parts' textures already
    /// include their material's base colour.
    pub textures: Vec<Texture>,
    /// Part (material) names.
    pub parts: Vec<String>,
    /// Per part: painted with the camouflage?
    pub painted: Vec<bool>,
    pub report: PrintReport,
}

impl PrintMesh {
    /// The corner UVs of triangle `t` if it is textured with texture 0 (the camouflage).
    pub fn camo_uv(&self, t: &PrintTri) -> Option<[Vec2; 3]> {
        match t.paint {
            Paint::Texture { tex: 0, uv } => Some(uv),
            _ => None,
        }
    }
}

/// Loads the mesh (a file, or a default object name: pickup, jeep, barrel, container) and checks that
/// every part the paint rule selects has UVs.
pub fn load_mesh(path: &Path, opts: &LoadOptions) -> Result<Scene> {
    if !path.exists() {
        if let Some(mut s) = crate::scene::generate::by_name(&path.to_string_lossy()) {
            s.normalise(opts.yaw_deg, opts.length_m);
            return Ok(s);
        }
        bail!("mesh file {} does not exist", path.display());
    }
    let scene = Scene::load(path, opts)?;
    check_paint_uvs(&scene, &opts.paint).with_context(|| format!("mesh {}", path.display()))?;
    Ok(scene)
}

/// Every material that the paint rule selects must have UVs on all its triangles, and at least
/// one part must be paintable.
pub fn check_paint_uvs(scene: &Scene, rule: &PaintRule) -> Result<()> {
    for (mi, m) in scene.materials.iter().enumerate() {
        if !rule.is_paintable(&m.name) {
            continue;
        }
        let tris = scene.triangles.iter().filter(|t| t.material as usize == mi);
        let (n, missing) = tris.fold((0, 0), |(n, k), t| (n + 1, k + t.uv.is_none() as usize));
        if missing > 0 {
            bail!(
                "part '{}' is to be painted but {missing} of its {n} triangles have no texture \
                 coordinates (UVs); unwrap it in a 3D editor or exclude it from the paint rule",
                m.name
            );
        }
    }
    if !scene.paintable.iter().any(|&p| p) {
        bail!("no part of the mesh is paintable (no material matches the paint rule)");
    }
    Ok(())
}

/// Loads the camouflage texture, refusing huge images before decoding them.
pub fn load_texture(path: &Path) -> Result<Texture> {
    let (w, h) = image::ImageReader::open(path)
        .with_context(|| format!("cannot open texture {}", path.display()))?
        .with_guessed_format()
        .with_context(|| format!("cannot read texture {}", path.display()))?
        .into_dimensions()
        .with_context(|| format!("{} is not a readable PNG/JPEG image", path.display()))?;
    if w > MAX_TEXTURE_SIDE || h > MAX_TEXTURE_SIDE {
        bail!(
            "texture {} is {w}x{h} texels; the largest accepted side is {MAX_TEXTURE_SIDE} \
             (downscale it first)",
            path.display()
        );
    }
    if w == 0 || h == 0 {
        bail!("texture {} is empty ({w}x{h})", path.display());
    }
    Ok(Texture::from_rgb8(&crate::io::load_rgb(path)?))
}

/// Scene (metres, +Y up) to print frame (mm, +Z up): `(x, y, z) -> (x, -z, y) * s`, a rotation
/// (orientation preserved).
fn to_print_frame(p: Vec3, mm_per_m: f32) -> Vec3 {
    Vec3::new(p.x, -p.z, p.y) * mm_per_m
}

/// Builds the print mesh: scales to mm, applies the camouflage to the paintable parts, welds
/// the positions (glTF splits vertices at UV seams) and runs the print-readiness check.
pub fn prepare(scene: &Scene, camo: &Texture, scale: Scale) -> Result<PrintMesh> {
    ensure!(
        scale.denominator.is_finite() && scale.denominator > 0.0,
        "scale 1:{} has no size",
        scale.denominator
    );
    let s = scale.mm_per_m() as f32;
    let raw: Vec<Vec3> = scene
        .positions
        .iter()
        .map(|&p| to_print_frame(p, s))
        .collect();
    let mut textures = vec![camo.clone()];
    // Other parts' textures, multiplied by their base colour, deduplicated.
    let mut tex_map: Vec<((usize, [u32; 3]), u32)> = vec![];
    let mut tris = Vec::with_capacity(scene.triangles.len());
    for t in &scene.triangles {
        let m = &scene.materials[t.material as usize];
        let uv = t.uv.map(|u| u.map(|i| scene.uvs[i as usize]));
        let paint = match (scene.is_paintable(t), uv, m.texture) {
            (true, Some(uv), _) => Paint::Texture { tex: 0, uv },
            (false, Some(uv), Some(ti)) => {
                let key = (ti, m.base_color.map(f32::to_bits));
                let tex = match tex_map.iter().find(|(k, _)| *k == key) {
                    Some(&(_, i)) => i,
                    None => {
                        let mut tx = scene.textures[ti].clone();
                        for c in &mut tx.texels {
                            for (ck, bk) in c.iter_mut().zip(m.base_color) {
                                *ck *= bk;
                            }
                        }
                        textures.push(tx);
                        tex_map.push((key, textures.len() as u32 - 1));
                        textures.len() as u32 - 1
                    }
                };
                Paint::Texture { tex, uv }
            }
            _ => Paint::Solid(m.base_color),
        };
        tris.push(PrintTri {
            v: t.p,
            paint,
            part: t.material,
        });
    }
    let (positions, report) = printcheck::weld_and_check(&raw, &mut tris)?;
    Ok(PrintMesh {
        name: scene.name.clone(),
        positions,
        tris,
        textures,
        parts: scene.materials.iter().map(|m| m.name.clone()).collect(),
        painted: scene.paintable.clone(),
        report,
    })
}

/// What one export wrote and measured.
#[derive(Clone, Debug, Serialize)]
pub struct ExportSummary {
    pub files: Vec<PathBuf>,
    pub report: PrintReport,
    pub baked_triangles: Option<usize>,
    pub bake_rmse_8bit: Option<f64>,
    pub bake_mean_delta_e: Option<f64>,
    /// What was repaired, and warnings.
    pub notes: Vec<String>,
}

/// Runs `cac export`: loads, checks, bakes and writes every requested format into `out`.
pub fn export(
    mesh_path: &Path,
    texture_path: &Path,
    out: &Path,
    opts: &ExportOptions,
) -> Result<ExportSummary> {
    ensure!(!opts.formats.is_empty(), "no export format requested");
    let scene = load_mesh(mesh_path, &opts.load)?;
    let camo = load_texture(texture_path)?;
    check_output_dir(out)?;
    let mesh = prepare(&scene, &camo, opts.scale)
        .with_context(|| format!("mesh {}", mesh_path.display()))?;
    let mut notes = mesh.report.repairs();
    let needs_closed = opts.formats.iter().any(Format::is_geometry);
    if needs_closed && !mesh.report.is_closed() {
        let msg = format!(
            "mesh {} is not printable: {}",
            mesh_path.display(),
            mesh.report.problems()
        );
        if !opts.allow_open {
            bail!("{msg}; refusing to write geometry (pass --allow-open to write it anyway, or repair the mesh)");
        }
        notes.push(format!("warning: {msg}; written anyway (--allow-open)"));
    }
    let stem = sanitize(&mesh.name);
    let mut files = vec![];
    let needs_bake = opts
        .formats
        .iter()
        .any(|f| matches!(f, Format::ThreeMfColor | Format::ObjVc));
    let baked = if needs_bake {
        Some(bake::bake(&mesh, &opts.bake)?)
    } else {
        None
    };
    let err = baked
        .as_ref()
        .map(|b| bake::colour_error(&mesh, b, 100_000, 1));
    for f in &opts.formats {
        match f {
            Format::ThreeMfTexture => {
                let p = out.join(format!("{stem}_texture.3mf"));
                threemf::write_textured(&mesh, &p)?;
                files.push(p);
            }
            Format::ThreeMfColor => {
                let p = out.join(format!("{stem}_color.3mf"));
                threemf::write_colored(&mesh, baked.as_ref().unwrap(), &p)?;
                files.push(p);
            }
            Format::Obj => files.extend(obj::write_textured(&mesh, out, &stem, opts.zip_obj)?),
            Format::ObjVc => {
                let p = out.join(format!("{stem}_vc.obj"));
                obj::write_vertex_colour(baked.as_ref().unwrap(), &p)?;
                files.push(p);
            }
            Format::Sheets => {
                let dir = out.join("sheets");
                files.extend(sheets::write_sheets(&mesh, opts.scale, &opts.sheets, &dir)?);
            }
        }
    }
    Ok(ExportSummary {
        files,
        report: mesh.report.clone(),
        baked_triangles: baked.as_ref().map(|b| b.tris.len()),
        bake_rmse_8bit: err.as_ref().map(|e| e.rmse_8bit),
        bake_mean_delta_e: err.as_ref().map(|e| e.mean_delta_e),
        notes,
    })
}

/// Creates the output folder and proves it is writable before any work is done.
pub fn check_output_dir(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create output folder {}", out.display()))?;
    tempfile::Builder::new()
        .prefix(".cac-probe-")
        .tempfile_in(out)
        .with_context(|| format!("output folder {} is not writable", out.display()))?;
    Ok(())
}

/// A file-name-safe stem.
pub fn sanitize(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "object".into()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_parses_and_refuses_zero() {
        assert_eq!("1:24".parse::<Scale>().unwrap().denominator, 24.0);
        assert_eq!("35".parse::<Scale>().unwrap().denominator, 35.0);
        for bad in ["1:0", "0:5", "1:-3", "1:x", "1:inf"] {
            let e = format!("{:#}", bad.parse::<Scale>().unwrap_err());
            assert!(e.contains(bad), "{e}");
        }
    }

    #[test]
    fn formats_parse() {
        assert_eq!("3mf-color".parse::<Format>().unwrap(), Format::ThreeMfColor);
        assert!("stl".parse::<Format>().is_err());
    }
}
