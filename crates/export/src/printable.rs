//! Making the mesh printable at its scale (`--repair` other than off): light repair, the thin
//! walls, the rebuild as one closed solid, the tiny parts and the build volume.

use crate::mesh::{PrintMesh, PrintTri};
use crate::options::{ExportOptions, RepairMode};
use crate::printability::{self, PrintLimits, Printability, ThinPolicy};
use crate::printcheck;
use crate::repair;
use crate::solidify::{self, SolidifyReport};
use anyhow::{bail, ensure, Context, Result};
use std::path::Path;

/// The solidify grid spacing for a print of `size_mm`: half the minimum wall (so walls are
/// resolved), but no finer than 1/600 of the longest side (bounded time and memory).
pub(crate) fn auto_voxel(size_mm: [f32; 3], limits: &PrintLimits) -> f32 {
    let longest = size_mm.iter().copied().fold(0.0f32, f32::max);
    (limits.min_wall_mm * 0.5).max(longest / 600.0).max(1e-3)
}

/// Above this share of the surface thinner than the minimum wall, thickening would change the
/// object too much: the scale is refused instead (the jeep at 1:1000 has 18 %).
pub(crate) const MAX_THIN_SHARE: f64 = 0.15;

/// Light repair, solidification and the printability check at scale (`--repair` other than
/// off): the mesh to write, the solidify report when rebuilt, the printability report, and the
/// original's triangle classification (for the fidelity measure).
pub(crate) fn make_printable(
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
pub(crate) fn format_scale(n: f32) -> String {
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
    let tris: Vec<PrintTri> = m
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
    printcheck::rewelded(m, &m.positions, tris)
}
