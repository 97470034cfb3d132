//! `cac export` (bake a learned texture into 3MF / OBJ / paste-on sheets) and `cac bench export`
//! (the bake's colour error against triangles and seconds). Parses, calls `cac::export`, prints.

use anyhow::Result;
use cac::bench::export as benchmark;
use cac::export::{
    self, printability::BuildVolume, BakeLimits, ExportOptions, Format, RepairMode, Scale,
    ThinPolicy,
};
use cac::printer::Profile;
use clap::Args as ClapArgs;
use std::path::PathBuf;

/// Bake the learned texture into files for full-colour 3D printing and paste-on sheets.
#[derive(ClapArgs, Debug)]
pub struct Args {
    /// The object: an OBJ/glTF/GLB file, or a default object name (pickup, jeep, barrel, container).
    #[arg(long)]
    pub mesh: PathBuf,
    /// The learned camouflage texture (PNG): the UV atlas of the paintable parts.
    #[arg(long)]
    pub texture: PathBuf,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Comma-separated: 3mf-texture, 3mf-color, obj, obj-vc, sheets, 3mf-painted (with an FDM
    /// --printer, the 3MF formats are written as 3mf-painted).
    #[arg(
        long,
        default_value = "3mf-texture,3mf-color,obj,obj-vc,sheets",
        value_delimiter = ','
    )]
    pub formats: Vec<Format>,
    /// Object scale 1:N (real object N times larger than the print), e.g. 1:24; 1:1 for
    /// paste-on sheets for the real object.
    #[arg(long)]
    pub scale: Scale,
    /// Bake: longest edge of a textured triangle, in texels.
    #[arg(long, default_value_t = BakeLimits::default().max_edge_texels)]
    pub max_edge_texels: f32,
    /// Bake: longest edge of any triangle, in mm (default: no limit).
    #[arg(long)]
    pub max_edge_mm: Option<f32>,
    /// Sheets: paper (a4 or letter).
    #[arg(long, default_value = "a4")]
    pub paper: export::sheets::Paper,
    /// Sheets: resolution.
    #[arg(long, default_value_t = 300)]
    pub dpi: u32,
    /// Sheets: layouts of more pages are refused before any page is drawn.
    #[arg(long, default_value_t = export::sheets::DEFAULT_MAX_PAGES)]
    pub max_sheet_pages: usize,
    /// Also bundle the OBJ, MTL and PNGs into one zip.
    #[arg(long)]
    pub zip: bool,
    /// Write geometry even if the mesh is open or non-manifold (no repair).
    #[arg(long)]
    pub allow_open: bool,
    /// When the print check fails: auto (light repair, then rebuild as a solid), light (light
    /// repair only), solid (always rebuild, uniting overlapping parts), off (refuse).
    #[arg(long, default_value = "auto")]
    pub repair: RepairMode,
    /// Regions thinner than the minimum wall: thicken, drop (with a warning) or refuse.
    #[arg(long, default_value = "thicken")]
    pub thin: ThinPolicy,
    /// Thinnest wall the printer makes, mm.
    #[arg(long, default_value_t = 0.8)]
    pub min_wall_mm: f32,
    /// Smallest part worth printing (largest extent), mm.
    #[arg(long, default_value_t = 1.0)]
    pub min_feature_mm: f32,
    /// Printer build volume XxYxZ in mm, or "none".
    #[arg(long, default_value = "256x256x256")]
    pub build_volume: BuildVolume,
    /// Solidify grid spacing, mm at print scale (default: half the minimum wall, at most 600
    /// cells along the longest side).
    #[arg(long)]
    pub voxel_mm: Option<f32>,
    /// Light repair fills holes up to this perimeter, mm.
    #[arg(long, default_value_t = 20.0)]
    pub max_hole_mm: f32,
    /// Printer profile (TOML, docs/formats.md). A multi-material FDM profile makes the 3MF the
    /// painted one that PrusaSlicer, Bambu Studio and OrcaSlicer open as a painted object; its
    /// object_size_mm must match --scale within 1 %.
    #[arg(long)]
    pub printer: Option<PathBuf>,
    /// Slice the painted 3MF with PrusaSlicer's command line (prusa-slicer) and report tool
    /// changes, purge and print time.
    #[arg(long)]
    pub slice: bool,
}

pub fn run(a: Args) -> Result<()> {
    let mut opts = ExportOptions {
        formats: a.formats,
        scale: a.scale,
        zip_obj: a.zip,
        allow_open: a.allow_open,
        repair: a.repair,
        voxel_mm: a.voxel_mm,
        max_hole_mm: a.max_hole_mm,
        progress: |stage| eprintln!("export: {stage} ..."),
        printer: a.printer.as_deref().map(Profile::load).transpose()?,
        slice: a.slice,
        ..Default::default()
    };
    opts.limits.thin = a.thin;
    opts.limits.min_wall_mm = a.min_wall_mm;
    opts.limits.min_feature_mm = a.min_feature_mm;
    opts.limits.build_volume_mm = a.build_volume.0;
    opts.bake.max_edge_texels = a.max_edge_texels;
    if let Some(mm) = a.max_edge_mm {
        opts.bake.max_edge_mm = mm;
    }
    opts.sheets.paper = a.paper;
    opts.sheets.dpi = a.dpi;
    opts.sheets.max_pages = a.max_sheet_pages;
    print!("{}", export::export(&a.mesh, &a.texture, &a.out, &opts)?);
    Ok(())
}

/// Measure the bake's colour error against triangle count and seconds for several limits.
#[derive(ClapArgs, Debug)]
pub struct BenchArgs {
    #[command(flatten)]
    pub bench: super::flags::export::ExportBenchFlags,
    /// CSV output.
    #[arg(long, default_value = "bench_export.csv")]
    pub csv: PathBuf,
    /// CSV output of the solidify table.
    #[arg(long, default_value = "bench_solid.csv")]
    pub solid_csv: PathBuf,
}

pub fn bench(a: BenchArgs) -> Result<()> {
    let bench = benchmark::ExportBench::from(a.bench);
    let o = bench.run()?;
    let mesh = &o.mesh;
    if let Some(s) = &o.solid {
        println!(
            "solidify {} at 1:{} ({} triangles, {:.1} x {:.1} x {:.1} mm)",
            mesh.name,
            bench.scale.denominator,
            s.input.tris.len(),
            s.input.report.size_mm[0],
            s.input.report.size_mm[1],
            s.input.report.size_mm[2]
        );
        print!("{}", benchmark::solid_markdown(&s.rows));
        cac::io::write_atomic(&a.solid_csv, benchmark::solid_csv(&s.rows).as_bytes())?;
        println!("wrote {}", a.solid_csv.display());
    }
    let Some(rows) = &o.bake else { return Ok(()) };
    println!(
        "object {} at {} ({} triangles), texture {}x{}, {} samples",
        mesh.name,
        bench.scale.denominator,
        mesh.tris.len(),
        o.texture.0,
        o.texture.1,
        bench.samples
    );
    print!("{}", benchmark::markdown(rows));
    cac::io::write_atomic(&a.csv, benchmark::csv(rows).as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}
