//! [`export`]: the whole of `cac export` — load, check, repair for print, bake and write each
//! requested format — and the [`ExportSummary`] it returns.

use crate::bake::{self, Baked};
use crate::load::{load_mesh, load_texture, prepare};
use crate::mesh::{sanitize, PrintMesh, PrintReport, Scale};
use crate::options::{ExportOptions, Format, RepairMode};
use crate::printability::{self, Printability};
use crate::printable::{format_scale, make_printable};
use crate::solidify::{self, Fidelity, SolidifyReport};
use crate::{obj, painted, sheets, threemf, vrml};
use anyhow::{bail, ensure, Context, Result};
use cac_core::printer::Printer;
use cac_scene::{Scene, Texture};
use serde::Serialize;
use std::path::{Path, PathBuf};

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
    // The loaded scene and texture are held until the export returns, as they always were:
    // `tests/memory_guard.rs`'s stop in the middle of the sheets is tuned to that profile.
    let (mesh, _loaded) = load_and_prepare(mesh_path, texture_path, out, opts, printer.as_ref())?;
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
    let made = for_print(mesh, needs_closed, opts, mesh_path, &mut notes)?;
    let mesh = &made.mesh;
    let baked = if needs_bake {
        Some(bake_colours(&made, opts, mesh_path)?)
    } else {
        None
    };
    let err = baked
        .as_ref()
        .map(|b| bake::colour_error(mesh, b, 100_000, 1));
    let mut fidelity = None;
    if let Some((orig, kinds)) = &made.original {
        let f = solidify::fidelity(orig, kinds, mesh, baked.as_ref(), 20_000, 3);
        notes.push(f.note());
        fidelity = Some(f);
    }
    let job = Writer {
        made: &made,
        baked: baked.as_ref(),
        stem: sanitize(&mesh.name),
        out,
        opts,
        printer: printer.as_ref(),
        mesh_path,
    };
    let mut written = Written::default();
    for f in &formats {
        (opts.progress)(&format!("writing {}", f.name()));
        cac_core::memory::stage(f.stage());
        job.write(*f, &mut written)?;
    }
    Ok(ExportSummary {
        files: written.files,
        report: mesh.report.clone(),
        baked_triangles: baked.as_ref().map(|b| b.tris.len()),
        bake_rmse_8bit: err.as_ref().map(|e| e.rmse_8bit),
        bake_mean_delta_e: err.as_ref().map(|e| e.mean_delta_e),
        notes,
        input_report,
        solid: made.solid,
        fidelity,
        printability: made.printability,
        painting: written.painting,
        slice: written.slice,
    })
}

/// Loads the mesh and the texture (the output folder proved writable in between) and prepares
/// the print mesh at the export's scale, checked against an FDM printer's object size; returns
/// it with what was loaded.
fn load_and_prepare(
    mesh_path: &Path,
    texture_path: &Path,
    out: &Path,
    opts: &ExportOptions,
    printer: Option<&NamedPrinter>,
) -> Result<(PrintMesh, (Scene, Texture))> {
    cac_core::memory::stage_with("mesh and texture loading", "use a smaller texture");
    let scene = load_mesh(mesh_path, &opts.load)?;
    let camo = load_texture(texture_path, &opts.memory)?;
    check_output_dir(out)?;
    let mesh = prepare(&scene, &camo, opts.scale)
        .with_context(|| format!("mesh {}", mesh_path.display()))?;
    if let Some((printer, name)) = printer {
        check_printer_scale(printer, name, &mesh, opts.scale)?;
    }
    Ok((mesh, (scene, camo)))
}

/// The mesh to write and what making it printable found.
struct MadeForPrint {
    mesh: PrintMesh,
    solid: Option<SolidifyReport>,
    printability: Option<Printability>,
    /// The mesh before it was rebuilt as a solid, and its triangles' classification.
    original: Option<(PrintMesh, Vec<printability::TriKind>)>,
}

/// The mesh as the formats need it: left as it is (no geometry format, `--allow-open` or
/// `--repair off`: an open mesh refused or warned about), or repaired at scale.
fn for_print(
    mesh: PrintMesh,
    needs_closed: bool,
    opts: &ExportOptions,
    mesh_path: &Path,
    notes: &mut Vec<String>,
) -> Result<MadeForPrint> {
    let as_is = |mesh| MadeForPrint {
        mesh,
        solid: None,
        printability: None,
        original: None,
    };
    if !needs_closed {
        return Ok(as_is(mesh));
    }
    if opts.allow_open || opts.repair == RepairMode::Off {
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
        return Ok(as_is(mesh));
    }
    (opts.progress)("checking and repairing for print");
    cac_core::memory::stage_with("print repair", "use a smaller texture or mesh");
    let (made, solid, printability, kinds) = make_printable(&mesh, opts, mesh_path, notes)?;
    let original = solid.is_some().then_some((mesh, kinds));
    Ok(MadeForPrint {
        mesh: made,
        solid,
        printability: Some(printability),
        original,
    })
}

/// The baked colours of the mesh to write (a rebuilt solid takes them from the original
/// surface).
fn bake_colours(made: &MadeForPrint, opts: &ExportOptions, mesh_path: &Path) -> Result<Baked> {
    cac_core::memory::stage_with("bake", "raise --max-edge-texels");
    (opts.progress)(&format!(
        "baking the colours of {} triangles",
        made.mesh.tris.len()
    ));
    let mut b = bake::bake(&made.mesh, &opts.bake, &opts.memory)
        .with_context(|| format!("mesh {}", mesh_path.display()))?;
    if let Some((orig, _)) = &made.original {
        solidify::recolour_from(orig, &mut b);
    }
    Ok(b)
}

/// What the formats share while they are written.
struct Writer<'a> {
    made: &'a MadeForPrint,
    baked: Option<&'a Baked>,
    stem: String,
    out: &'a Path,
    opts: &'a ExportOptions,
    printer: Option<&'a NamedPrinter>,
    mesh_path: &'a Path,
}

/// What the formats wrote.
#[derive(Default)]
struct Written {
    files: Vec<PathBuf>,
    painting: Option<painted::PaintSummary>,
    slice: Option<painted::SliceCost>,
}

impl Writer<'_> {
    /// Writes format `f`, adding its files (and the painting's summary and cost) to `w`.
    fn write(&self, f: Format, w: &mut Written) -> Result<()> {
        let (mesh, out, stem) = (&self.made.mesh, self.out, &self.stem);
        match f {
            Format::ThreeMfTexture => {
                let p = out.join(format!("{stem}_texture.3mf"));
                threemf::write_textured(mesh, &p)?;
                w.files.push(p);
            }
            Format::ThreeMfColor => {
                let p = out.join(format!("{stem}_color.3mf"));
                threemf::write_colored(mesh, self.baked.unwrap(), &p)?;
                w.files.push(p);
            }
            Format::Obj => w
                .files
                .extend(obj::write_textured(mesh, out, stem, self.opts.zip_obj)?),
            Format::Vrml => w.files.extend(vrml::write(mesh, out, stem)?),
            Format::ObjVc => {
                let p = out.join(format!("{stem}_vc.obj"));
                obj::write_vertex_colour(self.baked.unwrap(), &p)?;
                w.files.push(p);
            }
            Format::ThreeMfPainted => self.write_painted(w)?,
            Format::Sheets => {
                // Sheets cover the surface as modelled (a person pastes them on the real
                // object): the mesh before it was rebuilt as a solid, whose UV islands are the
                // model's, not the grid's thousands of fragments.
                let surface = self.made.original.as_ref().map_or(mesh, |(m, _)| m);
                let dir = out.join("sheets");
                let o = self.opts;
                w.files.extend(
                    sheets::write_sheets(surface, o.scale, &o.sheets, &dir, &o.memory, o.progress)
                        .with_context(|| format!("mesh {}", self.mesh_path.display()))?,
                );
            }
        }
        Ok(())
    }

    /// The painted 3MF for the FDM printer's filaments, sliced when `--slice` asks.
    fn write_painted(&self, w: &mut Written) -> Result<()> {
        let (mesh, out, stem, opts) = (&self.made.mesh, self.out, &self.stem, self.opts);
        let (printer, name) = self.printer.expect("checked by formats_for_printer");
        let Printer::Fdm { palette, fdm, .. } = printer else {
            unreachable!("formats_for_printer keeps FDM printers only")
        };
        let p = out.join(format!("{stem}_painted.3mf"));
        let painted = painted::paint(mesh, printer, name, &painted::PaintLimits::for_fdm(fdm))
            .with_context(|| format!("mesh {}", self.mesh_path.display()))?;
        let bed = opts.limits.build_volume_mm;
        threemf::write_painted(mesh, &painted.trees, fdm, palette, name, bed, &p)?;
        w.files.push(p.clone());
        if opts.slice {
            (opts.progress)("slicing the painted 3MF with PrusaSlicer");
            let g = out.join(format!("{stem}_painted.gcode"));
            w.slice = Some(painted::slice(&p, &g)?);
            w.files.push(g);
        }
        w.painting = Some(painted.summary);
        Ok(())
    }
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
