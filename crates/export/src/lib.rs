//! Fabrication: bakes a learned camouflage texture into files that printers and slicers accept.
//!
//! [`prepare`] turns a [`Scene`] plus the camouflage atlas into a [`PrintMesh`]: welded positions
//! in millimetres at the chosen scale (3MF frame: **+Z up**, X = the object's length, ground at
//! `z = 0`), per-corner paint (texture + UVs, or a solid colour) and a print-readiness report
//! ([`printcheck`]). When the check fails, [`export`] repairs it ([`repair`]: weld, dedupe, zip
//! T-junctions, fill small holes) or rebuilds it as one closed solid keeping its colours
//! ([`solidify`], on the BVH queries of [`surface`]), and checks printability at the chosen scale
//! ([`printability`]: wall thickness, sheets, floating and tiny parts, build volume). Writers then
//! produce:
//! - [`threemf`]: textured 3MF (`m:texture2d` + `m:texture2dgroup`), baked-colour 3MF
//!   (`m:colorgroup` per corner after [`bake`]'s adaptive subdivision) and, for a multi-material
//!   FDM printer profile, the painted 3MF that slicers open as a painted object ([`painted`]:
//!   the slicers' per-triangle painting trees, and the G-code's cost when sliced);
//! - [`obj`]: OBJ + MTL + PNG (optionally zipped) and a vertex-colour OBJ from the same bake;
//! - [`vrml`]: VRML 2.0 + PNG for full-colour print services (with a full-colour profile);
//! - [`sheets`]: paste-on sheets at true physical size (PNG pages, PDF, JSON sidecar).
//!
//! See `docs/export.md` for the conventions, tolerances and the bake's error/run-time table.

pub mod bake;
pub mod benchmark;
pub mod obj;
pub mod painted;
pub mod pdf;
pub mod printability;
pub mod printcheck;
pub mod repair;
pub mod sheets;
pub mod solidify;
pub mod surface;
pub mod threemf;
pub mod vrml;

use anyhow::{bail, ensure, Context, Result};
use cac_core::memory::MemoryBudget;
use cac_core::printer::{Printer, Profile};
use cac_scene::{LoadOptions, PaintRule, Scene, Texture};
use glam::{Vec2, Vec3};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::str::FromStr;

pub use bake::{BakeLimits, Baked};
pub use printability::{PrintLimits, Printability, ThinPolicy};
pub use printcheck::PrintReport;
pub use solidify::{Fidelity, SolidifyReport};

/// Largest accepted texture side, in texels (larger ones are refused before decoding).
pub(crate) const MAX_TEXTURE_SIDE: u32 = 16384;

/// The object scale `1:N` (the printed object is `N` times smaller than the real one).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Scale {
    pub denominator: f64,
}

impl Scale {
    /// Millimetres on the print per metre of the real object.
    pub(crate) fn mm_per_m(&self) -> f64 {
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
    /// `<name>_painted.3mf`: multi-material painting for slicers (needs an FDM printer profile).
    ThreeMfPainted,
    /// `<name>.wrl` + PNGs: VRML 2.0 for full-colour print services (added with a full-colour
    /// printer profile).
    Vrml,
}

impl FromStr for Format {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Format> {
        let s = s.trim();
        if s == "3mf-colour" {
            return Ok(Format::ThreeMfColor);
        }
        let all = Format::ALL
            .into_iter()
            .chain([Format::ThreeMfPainted, Format::Vrml]);
        Ok(match all.into_iter().find(|f| f.name() == s) {
            Some(f) => f,
            None => bail!(
                "unknown export format '{s}' (expected 3mf-texture, 3mf-color, obj, obj-vc, sheets, 3mf-painted, wrl)"
            ),
        })
    }
}

impl Format {
    /// The formats written without a printer profile (the default; `3mf-painted` needs one).
    pub const ALL: [Format; 5] = [
        Format::ThreeMfTexture,
        Format::ThreeMfColor,
        Format::Obj,
        Format::ObjVc,
        Format::Sheets,
    ];
    /// The name `--formats` takes.
    pub fn name(&self) -> &'static str {
        match self {
            Format::ThreeMfTexture => "3mf-texture",
            Format::ThreeMfColor => "3mf-color",
            Format::Obj => "obj",
            Format::ObjVc => "obj-vc",
            Format::Sheets => "sheets",
            Format::ThreeMfPainted => "3mf-painted",
            Format::Vrml => "wrl",
        }
    }

    /// The stage that writes it, as the memory guard names it.
    pub fn stage(&self) -> &'static str {
        match self {
            Format::ThreeMfTexture => "textured 3MF",
            Format::ThreeMfColor => "colour 3MF",
            Format::Obj => "textured OBJ",
            Format::ObjVc => "vertex-colour OBJ",
            Format::Sheets => "paste-on sheets",
            Format::ThreeMfPainted => "painted 3MF",
            Format::Vrml => "VRML",
        }
    }

    /// Does this format carry printable geometry (and so need a closed mesh)?
    pub(crate) fn is_geometry(&self) -> bool {
        !matches!(self, Format::Sheets)
    }
}

/// How `cac export` repairs a mesh that fails the print check (`--repair`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum RepairMode {
    /// Light repair when the check fails, then solidify what it cannot fix (the default).
    Auto,
    /// Light repair only; refuse what it cannot fix.
    Light,
    /// Always rebuild the solid (unites overlapping parts even when the check passes).
    Solid,
    /// No repair: refuse a failing mesh (or write it with `--allow-open`).
    Off,
}

impl FromStr for RepairMode {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        Ok(match s {
            "auto" => RepairMode::Auto,
            "light" => RepairMode::Light,
            "solid" | "solidify" => RepairMode::Solid,
            "off" | "none" => RepairMode::Off,
            o => bail!("unknown --repair '{o}' (expected auto, light, solid or off)"),
        })
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
    pub repair: RepairMode,
    /// Minimum wall and feature, build volume, and what to do with thin regions.
    pub limits: PrintLimits,
    /// Solidify grid spacing in mm at print scale (`None`: [`auto_voxel`]).
    pub voxel_mm: Option<f32>,
    /// Light repair fills holes up to this perimeter, mm at print scale.
    pub max_hole_mm: f32,
    /// The memory budget (default: the process's, [`MemoryBudget::current`]): the texture, the
    /// solid, the bake and the paste-on sheets are estimated against it first.
    pub memory: MemoryBudget,
    /// Told the name of each stage as it starts (the CLI prints it; default: nothing).
    pub progress: fn(&str),
    /// The printer the object is made on (`--printer`). A multi-material FDM profile makes the
    /// 3MF the painted one (`3mf-texture` / `3mf-color` become `3mf-painted`) and its
    /// `object_size_mm` must match the scale; other profiles are refused with a 3MF format.
    pub printer: Option<Profile>,
    /// Slice the painted 3MF with PrusaSlicer's command line and report what the print costs
    /// (`--slice`).
    pub slice: bool,
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
            repair: RepairMode::Auto,
            limits: PrintLimits::default(),
            voxel_mm: None,
            max_hole_mm: 20.0,
            memory: MemoryBudget::current(),
            progress: |_| {},
            printer: None,
            slice: false,
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
        if let Some(mut s) = cac_scene::generate::by_name(&path.to_string_lossy()) {
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
pub(crate) fn check_paint_uvs(scene: &Scene, rule: &PaintRule) -> Result<()> {
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
/// Memory per texel while a texture is decoded and held (8-bit decode, `f32` RGB texels).
const BYTES_PER_TEXEL: u64 = 4 + 3 * 4;

pub fn load_texture(path: &Path, budget: &MemoryBudget) -> Result<Texture> {
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
    budget
        .check(
            &format!("texture {} ({w}x{h} texels)", path.display()),
            w as u64 * h as u64 * BYTES_PER_TEXEL,
            "downscale it",
        )
        .map_err(anyhow::Error::from)?;
    Ok(Texture::from_rgb8(&cac_core::io::load_rgb(path)?))
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
    /// The print check of the mesh as loaded (before any repair).
    pub input_report: PrintReport,
    /// Set when the mesh was rebuilt as a solid.
    pub solid: Option<SolidifyReport>,
    /// The solid against the original surface (geometry and colour), when rebuilt.
    pub fidelity: Option<Fidelity>,
    /// Printability at scale of what was written (geometry formats only).
    pub printability: Option<Printability>,
    /// The multi-material painting (per-filament area), when the painted 3MF was written.
    pub painting: Option<painted::PaintSummary>,
    /// What the print costs, when the painted 3MF was sliced (`--slice`).
    pub slice: Option<painted::SliceCost>,
}

/// What `cac export` prints: the mesh as loaded and as written, the repair notes, the bake's
/// colour error and the files written.
impl std::fmt::Display for ExportSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (i, r) = (&self.input_report, &self.report);
        let state = if i.is_closed() {
            "closed".to_string()
        } else {
            i.problems()
        };
        writeln!(
            f,
            "input: {} triangles, {} vertices after welding, {} shells, {state}",
            i.triangles, i.welded_vertices, i.shells
        )?;
        let [x, y, z] = r.size_mm;
        writeln!(
            f,
            "mesh: {} triangles, {} vertices after welding ({} before), {} shells, size {x:.1} x \
             {y:.1} x {z:.1} mm, volume {:.1} mm3, {} open edges",
            r.triangles, r.welded_vertices, r.input_vertices, r.shells, r.volume_mm3, r.open_edges
        )?;
        for n in &self.notes {
            writeln!(f, "{n}")?;
        }
        if let (Some(t), Some(e), Some(de)) = (
            self.baked_triangles,
            self.bake_rmse_8bit,
            self.bake_mean_delta_e,
        ) {
            writeln!(
                f,
                "bake: {t} triangles, colour RMSE {e:.2} (8-bit), mean dE76 {de:.2}"
            )?;
        }
        if let Some(p) = &self.painting {
            writeln!(f, "{}", p.line())?;
        }
        if let Some(c) = &self.slice {
            writeln!(f, "{}", c.line())?;
        }
        for p in &self.files {
            writeln!(f, "wrote {}", p.display())?;
        }
        Ok(())
    }
}

/// The solidify grid spacing for a print of `size_mm`: half the minimum wall (so walls are
/// resolved), but no finer than 1/600 of the longest side (bounded time and memory).
pub(crate) fn auto_voxel(size_mm: [f32; 3], limits: &PrintLimits) -> f32 {
    let longest = size_mm.iter().copied().fold(0.0f32, f32::max);
    (limits.min_wall_mm * 0.5).max(longest / 600.0).max(1e-3)
}

/// Runs `cac export`: loads, checks, bakes and writes every requested format into `out`.
pub fn export(
    mesh_path: &Path,
    texture_path: &Path,
    out: &Path,
    opts: &ExportOptions,
) -> Result<ExportSummary> {
    ensure!(!opts.formats.is_empty(), "no export format requested");
    let mut pre_notes = vec![];
    let (formats, printer) = formats_for_printer(opts, &mut pre_notes)?;
    cac_core::memory::stage_with("mesh and texture loading", "use a smaller texture");
    let scene = load_mesh(mesh_path, &opts.load)?;
    let camo = load_texture(texture_path, &opts.memory)?;
    check_output_dir(out)?;
    let mesh = prepare(&scene, &camo, opts.scale)
        .with_context(|| format!("mesh {}", mesh_path.display()))?;
    if let Some((printer, name)) = &printer {
        check_printer_scale(printer, name, &mesh, opts.scale)?;
    }
    let input_report = mesh.report.clone();
    let mut notes = vec![format!(
        "check: {}",
        if mesh.report.is_closed() {
            "closed, manifold and oriented".to_string()
        } else {
            mesh.report.problems()
        }
    )];
    notes.extend(pre_notes);
    notes.extend(mesh.report.repairs());
    let needs_closed = formats.iter().any(Format::is_geometry);
    let needs_bake = formats
        .iter()
        .any(|f| matches!(f, Format::ThreeMfColor | Format::ObjVc));
    if needs_bake {
        bake::check_lower_bound(&mesh, &opts.bake, &opts.memory)
            .with_context(|| format!("mesh {}", mesh_path.display()))?;
    }
    let mut mesh = mesh;
    let (mut solid, mut fidelity, mut printability, mut original) = (None, None, None, None);
    if needs_closed && (opts.allow_open || opts.repair == RepairMode::Off) {
        if !mesh.report.is_closed() {
            let msg = format!(
                "mesh {} is not printable: {}",
                mesh_path.display(),
                mesh.report.problems()
            );
            if !opts.allow_open {
                bail!("{msg}; refusing to write geometry (pass --allow-open to write it anyway, or --repair auto)");
            }
            notes.push(format!("warning: {msg}; written anyway (--allow-open)"));
        }
    } else if needs_closed {
        (opts.progress)("checking and repairing for print");
        cac_core::memory::stage_with("print repair", "use a smaller texture or mesh");
        let r = make_printable(&mesh, opts, mesh_path, &mut notes)?;
        if r.1.is_some() {
            original = Some((mesh, r.3));
        }
        mesh = r.0;
        solid = r.1;
        printability = Some(r.2);
    }
    let stem = sanitize(&mesh.name);
    let mut files = vec![];
    let baked = if needs_bake {
        cac_core::memory::stage_with("bake", "raise --max-edge-texels");
        (opts.progress)(&format!(
            "baking the colours of {} triangles",
            mesh.tris.len()
        ));
        let mut b = bake::bake(&mesh, &opts.bake, &opts.memory)
            .with_context(|| format!("mesh {}", mesh_path.display()))?;
        if let Some((orig, _)) = &original {
            solidify::recolour_from(orig, &mut b);
        }
        Some(b)
    } else {
        None
    };
    let err = baked
        .as_ref()
        .map(|b| bake::colour_error(&mesh, b, 100_000, 1));
    if let Some((orig, kinds)) = &original {
        let f = solidify::fidelity(orig, kinds, &mesh, baked.as_ref(), 20_000, 3);
        notes.push(f.note());
        fidelity = Some(f);
    }
    let (mut painting, mut slice) = (None, None);
    for f in &formats {
        (opts.progress)(&format!("writing {}", f.name()));
        cac_core::memory::stage(f.stage());
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
            Format::Vrml => files.extend(vrml::write(&mesh, out, &stem)?),
            Format::ObjVc => {
                let p = out.join(format!("{stem}_vc.obj"));
                obj::write_vertex_colour(baked.as_ref().unwrap(), &p)?;
                files.push(p);
            }
            Format::ThreeMfPainted => {
                let (printer, name) = printer.as_ref().expect("checked by formats_for_printer");
                let Printer::Fdm { palette, fdm, .. } = printer else {
                    unreachable!("formats_for_printer keeps FDM printers only")
                };
                let p = out.join(format!("{stem}_painted.3mf"));
                let painted =
                    painted::paint(&mesh, printer, name, &painted::PaintLimits::for_fdm(fdm))
                        .with_context(|| format!("mesh {}", mesh_path.display()))?;
                let bed = opts.limits.build_volume_mm;
                threemf::write_painted(&mesh, &painted.trees, fdm, palette, name, bed, &p)?;
                files.push(p.clone());
                if opts.slice {
                    (opts.progress)("slicing the painted 3MF with PrusaSlicer");
                    let g = out.join(format!("{stem}_painted.gcode"));
                    slice = Some(painted::slice(&p, &g)?);
                    files.push(g);
                }
                painting = Some(painted.summary);
            }
            Format::Sheets => {
                // Sheets cover the surface as modelled (a person pastes them on the real
                // object): the mesh before it was rebuilt as a solid, whose UV islands are the
                // model's, not the grid's thousands of fragments.
                let surface = original.as_ref().map_or(&mesh, |(m, _)| m);
                let dir = out.join("sheets");
                files.extend(
                    sheets::write_sheets(
                        surface,
                        opts.scale,
                        &opts.sheets,
                        &dir,
                        &opts.memory,
                        opts.progress,
                    )
                    .with_context(|| format!("mesh {}", mesh_path.display()))?,
                );
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
        input_report,
        solid,
        fidelity,
        printability,
        painting,
        slice,
    })
}

/// A loaded printer model and its profile's name.
type NamedPrinter = (Printer, String);

/// The formats to write with `opts.printer`, and the printer (with its profile's name) when it
/// is an FDM one: the 3MF becomes the painted one (`3mf-texture` / `3mf-color` →
/// `3mf-painted`, noted); `3mf-painted` without an FDM profile, a non-FDM profile with a 3MF
/// format, and `--slice` without the painted 3MF are refused.
fn formats_for_printer(
    opts: &ExportOptions,
    notes: &mut Vec<String>,
) -> Result<(Vec<Format>, Option<NamedPrinter>)> {
    let is_3mf = |f: &Format| {
        matches!(
            f,
            Format::ThreeMfTexture | Format::ThreeMfColor | Format::ThreeMfPainted
        )
    };
    let mut formats = vec![];
    let printer = match &opts.printer {
        None => {
            if opts.formats.contains(&Format::ThreeMfPainted) {
                bail!("the 3mf-painted format paints with a printer's filaments: pass --printer with a multi-material FDM profile ([fdm] in docs/formats.md)");
            }
            formats = opts.formats.clone();
            None
        }
        Some(profile) => {
            let printer = profile
                .printer()
                .with_context(|| format!("printer profile {}", profile.name))?;
            if !matches!(printer, Printer::Fdm { .. }) {
                // A full-colour or paper printer prints the texture as sent: every format is
                // written with the requested colours (what `cac train --printer` trains), and a
                // full-colour profile adds VRML for the services that ask for it.
                formats = opts.formats.clone();
                if profile.full_colour.is_some() && !formats.contains(&Format::Vrml) {
                    formats.push(Format::Vrml);
                }
                notes.push(format!(
                    "printer profile {:?} ({}): the texture is written as requested, the colours sent to the printer; the profile's response is what it prints (cac eval --printer judges that)",
                    profile.name,
                    profile.kind()
                ));
                None
            } else {
                for f in &opts.formats {
                    let f = if is_3mf(f) {
                        Format::ThreeMfPainted
                    } else {
                        *f
                    };
                    if !formats.contains(&f) {
                        formats.push(f);
                    }
                }
                let replaced: Vec<&str> = opts
                    .formats
                    .iter()
                    .filter(|f| matches!(f, Format::ThreeMfTexture | Format::ThreeMfColor))
                    .map(Format::name)
                    .collect();
                if !replaced.is_empty() {
                    notes.push(format!(
                        "printer profile {:?} is multi-material FDM: the 3MF is the painted one (3mf-painted instead of {})",
                        profile.name,
                        replaced.join(", ")
                    ));
                }
                Some((printer, profile.name.clone()))
            }
        }
    };
    if opts.slice && !formats.contains(&Format::ThreeMfPainted) {
        bail!("--slice slices the painted 3MF: it needs --printer with a multi-material FDM profile and a 3MF format");
    }
    Ok((formats, printer))
}

/// Most the printed size may differ from a printer profile's `object_size_mm`.
pub const PRINTER_SIZE_TOLERANCE: f64 = 0.01;

/// The object's longest side at the export's scale must be the FDM profile's `object_size_mm`
/// (within 1 %): the profile's nozzle sets the smallest colour region on that object.
fn check_printer_scale(
    printer: &Printer,
    name: &str,
    mesh: &PrintMesh,
    scale: Scale,
) -> Result<()> {
    let Printer::Fdm { fdm, .. } = printer else {
        return Ok(());
    };
    let longest = mesh.report.size_mm.iter().copied().fold(0.0f32, f32::max) as f64;
    let want = fdm.object_size_mm as f64;
    if (longest - want).abs() > PRINTER_SIZE_TOLERANCE * want {
        bail!(
            "printer profile {name:?} is for an object {want:.1} mm long (object_size_mm), but at 1:{} this one is {longest:.1} mm long ({:+.1} %, over the 1 % allowed): export at 1:{} or change object_size_mm",
            scale.denominator,
            (longest / want - 1.0) * 100.0,
            format_scale((scale.denominator * longest / want) as f32)
                .trim_end_matches('0')
                .trim_end_matches('.')
        );
    }
    Ok(())
}

/// Above this share of the surface thinner than the minimum wall, thickening would change the
/// object too much: the scale is refused instead (the jeep at 1:1000 has 18 %).
pub(crate) const MAX_THIN_SHARE: f64 = 0.15;

/// Light repair, solidification and the printability check at scale (`--repair` other than
/// off): the mesh to write, the solidify report when rebuilt, the printability report, and the
/// original's triangle classification (for the fidelity measure).
fn make_printable(
    mesh: &PrintMesh,
    opts: &ExportOptions,
    path: &Path,
    notes: &mut Vec<String>,
) -> Result<(
    PrintMesh,
    Option<SolidifyReport>,
    Printability,
    Vec<printability::TriKind>,
)> {
    let limits = &opts.limits;
    let at = format!("mesh {} at 1:{}", path.display(), opts.scale.denominator);
    // Repair and solidify change the size by less than a voxel: an object that cannot fit is
    // refused before either runs (a 1 km object would be solidified first otherwise).
    check_size(&at, mesh.report.size_mm, opts)?;
    let (mut cur, mut rebuild) = close(mesh, opts, &at, notes)?;
    let a = printability::analyse(&cur, limits.min_wall_mm);
    rebuild |= thin_walls(&cur, &a, limits, &at, notes)?;
    let kinds = a.kinds.clone();
    let mut solid = None;
    if rebuild {
        let (m, rep) = rebuild_solid(&cur, &a, opts, &at, notes)?;
        cur = m;
        solid = Some(rep);
    }
    // The check of what is written (the solid's thin regions were thickened or dropped above).
    let a_out = if solid.is_some() { a_out_for(&cur) } else { a };
    let (cur, p) = tiny_parts(cur, &a_out, limits, &at, notes)?;
    check_size(&at, p.size_mm, opts)?;
    notes.extend(p.lines());
    Ok((cur, solid, p, kinds))
}

/// Light repair of an open mesh: the mesh, and whether it must still be rebuilt as a solid
/// (always under `--repair solid`; where light repair left it open under `auto`).
fn close(
    mesh: &PrintMesh,
    opts: &ExportOptions,
    at: &str,
    notes: &mut Vec<String>,
) -> Result<(PrintMesh, bool)> {
    let rebuild = opts.repair == RepairMode::Solid;
    if mesh.report.is_closed() {
        return Ok((mesh.clone(), rebuild));
    }
    let (m, log) = repair::light_repair(mesh, opts.max_hole_mm)?;
    notes.extend(log.notes());
    if m.report.is_closed() {
        notes.push("light repair closed the mesh".into());
        return Ok((m, rebuild));
    }
    if opts.repair == RepairMode::Light {
        bail!(
            "{at} is not printable after light repair: {}; refusing to write geometry (--repair auto rebuilds it as a solid)",
            m.report.problems()
        );
    }
    notes.push(format!(
        "light repair left {}: rebuilding as a solid",
        m.report.problems()
    ));
    Ok((m, true))
}

/// Walls thinner than the minimum at this scale: refused, or noted to be thickened or left out
/// by the rebuild (true: a rebuild is needed).
fn thin_walls(
    cur: &PrintMesh,
    a: &printability::Analysis,
    limits: &PrintLimits,
    at: &str,
    notes: &mut Vec<String>,
) -> Result<bool> {
    let before = printability::check(cur, a, limits);
    if before.thin_regions.is_empty() {
        return Ok(false);
    }
    let list: Vec<String> = before
        .thin_regions
        .iter()
        .take(10)
        .map(|r| r.describe())
        .collect();
    let head = format!(
        "{at}: {} regions are thinner than the {:.2} mm minimum wall: {}{}",
        before.thin_regions.len(),
        limits.min_wall_mm,
        list.join("; "),
        if before.thin_regions.len() > 10 {
            "; ..."
        } else {
            ""
        }
    );
    // Walls made thin by the scale (single-sided surfaces have no thickness at any scale).
    let thin_area: f64 = before
        .thin_regions
        .iter()
        .filter(|r| r.min_thickness_mm > 0.0)
        .map(|r| r.area_mm2)
        .sum();
    let share = thin_area / cur.report.area_mm2.max(1e-12);
    match limits.thin {
        ThinPolicy::Refuse => bail!(
            "{head}; refusing to write geometry (--thin thicken thickens them, --thin drop leaves them out, or print at a larger scale)"
        ),
        _ if share > MAX_THIN_SHARE => bail!(
            "{head}; that is {:.0} % of the surface: the object is too small to print at this scale (choose a larger scale)",
            share * 100.0
        ),
        ThinPolicy::Thicken => notes.push(format!("{head}; thickened to the minimum wall")),
        ThinPolicy::Drop => notes.push(format!("warning: {head}; left out (--thin drop)")),
    }
    Ok(true)
}

/// The mesh rebuilt as a closed solid on a voxel grid (`--voxel-mm`, or one fitted to the size).
fn rebuild_solid(
    cur: &PrintMesh,
    a: &printability::Analysis,
    opts: &ExportOptions,
    at: &str,
    notes: &mut Vec<String>,
) -> Result<(PrintMesh, SolidifyReport)> {
    let limits = &opts.limits;
    let voxel = opts
        .voxel_mm
        .unwrap_or_else(|| auto_voxel(cur.report.size_mm, limits));
    let so = solidify::SolidifyOptions {
        voxel_mm: voxel,
        min_wall_mm: limits.min_wall_mm,
        thin: limits.thin,
        memory: opts.memory,
    };
    (opts.progress)(&format!("rebuilding as a solid on a {voxel:.3} mm grid"));
    cac_core::memory::stage_with("solidify", "raise --voxel-mm");
    let (m, rep) = solidify::solidify(cur, a, &so).with_context(|| at.to_string())?;
    notes.push(rep.note());
    if !m.report.is_closed() {
        bail!(
            "{at}: the rebuilt solid is still not printable ({}); try another --voxel-mm",
            m.report.problems()
        );
    }
    Ok((m, rep))
}

/// Parts smaller than the minimum feature: refused, left out (`--thin drop`) or warned about;
/// the mesh to write and its printability report.
fn tiny_parts(
    mut cur: PrintMesh,
    a_out: &printability::Analysis,
    limits: &PrintLimits,
    at: &str,
    notes: &mut Vec<String>,
) -> Result<(PrintMesh, Printability)> {
    let mut p = printability::check(&cur, a_out, limits);
    if p.tiny.is_empty() {
        return Ok((cur, p));
    }
    let list: Vec<String> = p.tiny.iter().take(5).map(|q| q.describe()).collect();
    let msg = format!(
        "{at}: {} parts are smaller than the {:.2} mm minimum feature: {}",
        p.tiny.len(),
        limits.min_feature_mm,
        list.join("; ")
    );
    match limits.thin {
        ThinPolicy::Refuse => bail!("{msg}; refusing to write geometry"),
        ThinPolicy::Drop => {
            cur = drop_parts(&cur, limits.min_feature_mm)?;
            notes.push(format!("warning: {msg}; left out (--thin drop)"));
            p = printability::check(&cur, &a_out_for(&cur), limits);
        }
        ThinPolicy::Thicken => notes.push(format!("warning: {msg}")),
    }
    Ok((cur, p))
}

/// Refuses an object of `size` mm that does not fit the build volume, naming the largest scale
/// that does, or that is smaller than the minimum feature.
fn check_size(at: &str, size: [f32; 3], opts: &ExportOptions) -> Result<()> {
    let longest = size.iter().copied().fold(0.0f32, f32::max);
    if longest < opts.limits.min_feature_mm {
        bail!(
            "{at} is {:.3} x {:.3} x {:.3} mm, smaller than the {:.2} mm minimum feature: nothing of it can be printed; choose a larger scale (1:{} makes it 100 mm long)",
            size[0],
            size[1],
            size[2],
            opts.limits.min_feature_mm,
            format_scale(opts.scale.denominator as f32 * longest / 100.0)
        );
    }
    let Some(v) = opts.limits.build_volume_mm else {
        return Ok(());
    };
    if printability::fits(size, v) {
        return Ok(());
    }
    let need = (0..3)
        .map(|k| size[k] / v[k])
        .fold(0.0f32, f32::max)
        .max(size[0].max(size[1]) / v[0].max(v[1]));
    bail!(
        "{at} is {:.1} x {:.1} x {:.1} mm, larger than the build volume {} x {} x {} mm; print at 1:{:.0} or smaller, or pass another --build-volume",
        size[0],
        size[1],
        size[2],
        v[0],
        v[1],
        v[2],
        (opts.scale.denominator as f32 * need).ceil()
    )
}

/// `24`, `1.5`, `0.0042`: a scale denominator to three significant digits.
fn format_scale(n: f32) -> String {
    let digits = (2 - n.abs().log10().floor() as i32).max(0) as usize;
    format!("{n:.digits$}")
}

fn a_out_for(m: &PrintMesh) -> printability::Analysis {
    printability::Analysis {
        kinds: vec![printability::TriKind::Boundary; m.tris.len()],
        thickness: vec![f32::INFINITY; m.tris.len()],
        thin: vec![false; m.tris.len()],
        relief: 0,
    }
}

/// Removes the parts (connected through edges) whose largest extent is below `min_mm`.
fn drop_parts(m: &PrintMesh, min_mm: f32) -> Result<PrintMesh> {
    let comp = repair::components(&m.tris.iter().map(|t| t.v).collect::<Vec<_>>());
    let parts = printability::parts(m);
    let mut tris: Vec<PrintTri> = m
        .tris
        .iter()
        .zip(&comp)
        .filter(|(_, &c)| parts[c as usize].extent() >= min_mm)
        .map(|(t, _)| *t)
        .collect();
    ensure!(
        !tris.is_empty(),
        "every part is smaller than the minimum feature"
    );
    let (positions, report) = printcheck::weld_and_check(&m.positions, &mut tris)?;
    Ok(PrintMesh {
        positions,
        tris,
        report,
        ..m.clone()
    })
}

/// Creates the output folder and proves it is writable before any work is done.
pub(crate) fn check_output_dir(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create output folder {}", out.display()))?;
    tempfile::Builder::new()
        .prefix(".cac-probe-")
        .tempfile_in(out)
        .with_context(|| format!("output folder {} is not writable", out.display()))?;
    Ok(())
}

/// A file-name-safe stem.
pub(crate) fn sanitize(name: &str) -> String {
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

/// Meshes the export modules' unit tests share.
#[cfg(test)]
pub(crate) mod fixtures {
    use glam::Vec3;

    /// The unit cube's six faces, outward, as corner indices (see [`corner`]).
    pub use cac_scene::BOX_QUADS as CUBE_QUADS;

    /// Corner `i` of the unit cube: `(i & 1, i >> 1 & 1, i >> 2 & 1)`.
    pub fn corner(i: u32) -> Vec3 {
        Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32)
    }

    /// A one-part mesh of `tris` over `positions`, welded and checked as the exporter does.
    pub fn print_mesh(
        name: &str,
        positions: &[Vec3],
        mut tris: Vec<super::PrintTri>,
    ) -> super::PrintMesh {
        let (positions, report) = super::printcheck::weld_and_check(positions, &mut tris).unwrap();
        super::PrintMesh {
            name: name.into(),
            positions,
            tris,
            textures: vec![],
            parts: vec!["body".into()],
            painted: vec![false],
            report,
        }
    }

    /// A closed, outward cube (12 triangles) of side `s` at `o`.
    pub fn cube(s: f32, o: Vec3) -> Vec<[Vec3; 3]> {
        cuboid(o, o + Vec3::splat(s), &[])
    }

    /// The box from `lo` to `hi` as outward triangles, without the faces whose indices into
    /// [`CUBE_QUADS`] are in `skip`.
    pub fn cuboid(lo: Vec3, hi: Vec3, skip: &[usize]) -> Vec<[Vec3; 3]> {
        let c = |i: u32| lo + corner(i) * (hi - lo);
        CUBE_QUADS
            .iter()
            .enumerate()
            .filter(|(k, _)| !skip.contains(k))
            .flat_map(|(_, q)| [[c(q[0]), c(q[1]), c(q[2])], [c(q[0]), c(q[2]), c(q[3])]])
            .collect()
    }
}
