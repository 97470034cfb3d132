//! Paste-on sheets: the camouflage laid out at true physical size for the object scale, part by
//! part (UV islands of the painted surface), on A4 or Letter pages at a stated DPI.
//!
//! Each part is scaled by its own measured texel size (`sqrt(3D area / UV area)`, mm per texel),
//! drawn with a bleed margin around a dark cut line, labelled `P<k>` (tiles `P<k> R<r>C<c>` when a
//! part is larger than the printable area), and every page has a 100 mm scale bar with cm ticks.
//! Outputs: `page_NN.png`, `sheets.pdf` (the same page images, one per PDF page at exact paper
//! size) and `sheets.json` (physical sizes and placements).

use crate::mesh::{PrintMesh, Scale};
use anyhow::{bail, ensure, Context, Result};
use cac_core::memory::MemoryBudget;
use cac_core::report::font::{draw_text, fill_rect, text_width};
use cac_scene::Texture;
use glam::Vec2;
use image::RgbImage;
use serde::Serialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// Paper size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub enum Paper {
    A4,
    Letter,
}

impl Paper {
    /// Portrait (width, height) in mm.
    pub fn size_mm(&self) -> (f32, f32) {
        match self {
            Paper::A4 => (210.0, 297.0),
            Paper::Letter => (215.9, 279.4),
        }
    }
}

impl FromStr for Paper {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Paper> {
        match s.to_lowercase().as_str() {
            "a4" => Ok(Paper::A4),
            "letter" => Ok(Paper::Letter),
            o => bail!("unknown paper '{o}' (expected a4 or letter)"),
        }
    }
}

/// The default `--max-sheet-pages`: the full-size pickup (1:1) takes 960 A4 pages.
pub const DEFAULT_MAX_PAGES: usize = 2000;

/// Page settings.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SheetOptions {
    pub paper: Paper,
    pub dpi: u32,
    pub margin_mm: f32,
    /// Texture printed beyond each part's cut line.
    pub bleed_mm: f32,
    /// Layouts of more pages are refused before any page is drawn (`--max-sheet-pages`).
    pub max_pages: usize,
}

impl Default for SheetOptions {
    fn default() -> Self {
        SheetOptions {
            paper: Paper::A4,
            dpi: 300,
            margin_mm: 10.0,
            bleed_mm: 2.0,
            max_pages: DEFAULT_MAX_PAGES,
        }
    }
}

/// One piece placed on a page (all lengths in mm from the page's top-left corner).
#[derive(Clone, Debug, Serialize)]
pub(crate) struct Placement {
    pub label: String,
    pub page: usize,
    pub x_mm: f32,
    pub y_mm: f32,
    pub width_mm: f32,
    pub height_mm: f32,
    /// The texel rectangle drawn, `[x0, y0, x1, y1]` (texel units, y down from the top row).
    pub texels: [f32; 4],
}

/// One part (UV island) of the painted surface.
#[derive(Clone, Debug, Serialize)]
pub(crate) struct PartSheet {
    pub id: usize,
    pub material: String,
    pub triangles: usize,
    pub area_mm2: f64,
    pub mm_per_texel: f64,
    /// Size of the part's bounding box on paper (without bleed).
    pub width_mm: f32,
    pub height_mm: f32,
    pub pieces: Vec<Placement>,
}

/// The JSON sidecar.
#[derive(Clone, Debug, Serialize)]
pub(crate) struct SheetLayout {
    pub object: String,
    pub scale: String,
    pub paper: Paper,
    pub dpi: u32,
    pub page_size_mm: [f32; 2],
    pub pages: usize,
    pub texture_size: [usize; 2],
    pub parts: Vec<PartSheet>,
}

/// Groups painted triangles into UV islands (connected through edges whose two corners have the
/// same UVs on both sides).
fn islands(mesh: &PrintMesh) -> Vec<Vec<usize>> {
    let painted: Vec<usize> = (0..mesh.tris.len())
        .filter(|&i| mesh.camo_uv(&mesh.tris[i]).is_some())
        .collect();
    let mut parent: Vec<usize> = (0..mesh.tris.len()).collect();
    fn find(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let mut edges: HashMap<(u32, u32, [u32; 4]), usize> = HashMap::new();
    for &ti in &painted {
        let t = &mesh.tris[ti];
        let uv = mesh.camo_uv(t).unwrap();
        for k in 0..3 {
            let (a, b, ua, ub) = (t.v[k], t.v[(k + 1) % 3], uv[k], uv[(k + 1) % 3]);
            let (a, b, ua, ub) = if a < b {
                (a, b, ua, ub)
            } else {
                (b, a, ub, ua)
            };
            let key = (a, b, [ua.x, ua.y, ub.x, ub.y].map(f32::to_bits));
            if let Some(&o) = edges.get(&key) {
                let (x, y) = (find(&mut parent, ti), find(&mut parent, o));
                parent[x] = y;
            } else {
                edges.insert(key, ti);
            }
        }
    }
    let mut groups: HashMap<usize, Vec<usize>> = HashMap::new();
    for &ti in &painted {
        let r = find(&mut parent, ti);
        groups.entry(r).or_default().push(ti);
    }
    let mut out: Vec<Vec<usize>> = groups.into_values().collect();
    out.sort_by_key(|g| g[0]);
    out
}

/// Lays out the sheets and writes them into `dir` page by page (each page drawn, written as PNG
/// and appended to the PDF, then freed), within `budget`; returns the files written. `progress`
/// is told how many pieces and pages it is about to make.
pub fn write_sheets(
    mesh: &PrintMesh,
    scale: Scale,
    opts: &SheetOptions,
    dir: &Path,
    budget: &MemoryBudget,
    progress: fn(&str),
) -> Result<Vec<PathBuf>> {
    cac_core::memory::stage_with("paste-on sheets", "lower --dpi");
    let page = Page::new(opts)?;
    let scale_txt = format!("1:{}", scale.denominator);
    let what = |w: &str| format!("the paste-on sheets of {} at {scale_txt}: {w}", mesh.name);
    let painted = mesh
        .tris
        .iter()
        .filter(|t| mesh.camo_uv(t).is_some())
        .count();
    let before = plan_bytes(painted as u64, 0) + page.draw_bytes(opts);
    budget.check(
        &what(&format!(
            "{painted} painted triangles, pages of {}",
            page.px_text(opts)
        )),
        before,
        &format!(
            "lower --dpi (now {}), or use the textured 3MF for this mesh",
            opts.dpi
        ),
    )?;
    let (parts, pieces, left_out) = cut_pieces(mesh, &page, opts, &what)?;
    let (placed, n_pages) = pack(&pieces, &page, opts);
    check_pages(n_pages, "", pieces.len(), opts, &what)?;
    budget.check(
        &what(&format!("{} pieces on {n_pages} pages", pieces.len())),
        plan_bytes(painted as u64, pieces.len() as u64) + page.draw_bytes(opts),
        &format!(
            "lower --dpi (now {}), or print at a smaller scale",
            opts.dpi
        ),
    )?;
    let small = match left_out {
        0 => String::new(),
        n => format!("; {n} parts under {MIN_PART_MM} mm left out"),
    };
    progress(&format!(
        "paste-on sheets: {} parts cut into {} pieces on {n_pages} pages ({:?}, {} dpi){small}",
        parts.len(),
        pieces.len(),
        opts.paper,
        opts.dpi
    ));
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create sheet folder {}", dir.display()))?;
    let plan = Plan {
        mesh,
        scale_txt: &scale_txt,
        parts: &parts,
        pieces: &pieces,
        n_pages,
        page: &page,
        opts,
    };
    let mut files = write_pages(&plan, &placed, dir)?;
    let mut parts_out: Vec<PartSheet> = parts.into_iter().map(|(p, _)| p).collect();
    for (i, pl) in placed {
        parts_out[pieces[i].part].pieces.push(pl);
    }
    let tex = &mesh.textures[0];
    let layout = SheetLayout {
        object: mesh.name.clone(),
        scale: scale_txt,
        paper: opts.paper,
        dpi: opts.dpi,
        page_size_mm: [page.w, page.h],
        pages: n_pages,
        texture_size: [tex.width, tex.height],
        parts: parts_out,
    };
    let json = dir.join("sheets.json");
    cac_core::io::write_atomic(&json, serde_json::to_string_pretty(&layout)?.as_bytes())?;
    files.push(json);
    Ok(files)
}

/// Bytes the layout holds: the UV islands' edge map and groups (about 256 bytes per painted
/// triangle) and the pieces with their placements and labels (about 512 bytes each).
pub(crate) fn plan_bytes(painted_tris: u64, pieces: u64) -> u64 {
    painted_tris * 256 + pieces * 512
}

/// More pages than `opts.max_pages` are refused before any is drawn.
/// `at_least` qualifies a lower bound of the pages ("at least ").
fn check_pages(
    n_pages: usize,
    at_least: &str,
    n_pieces: usize,
    opts: &SheetOptions,
    what: &dyn Fn(&str) -> String,
) -> Result<()> {
    ensure!(
        n_pages <= opts.max_pages,
        "{} would take {at_least}{n_pages} pages ({n_pieces} pieces), over the limit of {} \
         pages: print \
         at a smaller scale, or use the textured 3MF (--formats 3mf-texture) for this mesh (or \
         raise --max-sheet-pages)",
        what("the layout"),
        opts.max_pages
    );
    Ok(())
}

/// What drawing the pages needs besides the layout.
struct Plan<'a> {
    mesh: &'a PrintMesh,
    scale_txt: &'a str,
    parts: &'a [(PartSheet, Vec<usize>)],
    pieces: &'a [Piece],
    n_pages: usize,
    page: &'a Page,
    opts: &'a SheetOptions,
}

/// Draws, writes and frees one page at a time: `page_NN.png` each, and `sheets.pdf` streamed
/// to disk as the pages come. `placed` is in page order (as [`pack`] makes it).
fn write_pages(plan: &Plan, placed: &[(usize, Placement)], dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files = vec![];
    let pdf_path = dir.join("sheets.pdf");
    let title = format!("cac paste-on sheets: {}", plan.mesh.name);
    cac_core::io::write_atomic_with(&pdf_path, |w| {
        let mut pdf = crate::pdf::PdfStream::start(w, &title, plan.n_pages)?;
        let mut rest = placed;
        for k in 0..plan.n_pages {
            let n = rest.iter().take_while(|(_, pl)| pl.page == k).count();
            let img = draw_page(plan, k, &rest[..n]);
            rest = &rest[n..];
            let mut png = Vec::new();
            img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
                .context("cannot encode a sheet page as PNG")?;
            drop(img);
            let p = dir.join(format!("page_{:02}.png", k + 1));
            cac_core::io::write_atomic(&p, &png)?;
            files.push(p);
            pdf.page(&png, (plan.page.w, plan.page.h))?;
        }
        pdf.finish()
    })?;
    files.push(pdf_path);
    Ok(files)
}

/// Room for a page's header text, a piece's label, and the gap between pieces (mm).
const HEADER_MM: f32 = 24.0;
const LABEL_MM: f32 = 5.0;
const GAP_MM: f32 = 4.0;

/// The page: its size, the area inside the margins and below the header, and the largest piece
/// that fits there with its bleed and label (mm).
struct Page {
    w: f32,
    h: f32,
    avail: (f32, f32),
    max_piece: (f32, f32),
}

impl Page {
    fn new(opts: &SheetOptions) -> Result<Page> {
        ensure!(
            (72..=1200).contains(&opts.dpi),
            "sheet resolution {} dpi is outside 72..1200",
            opts.dpi
        );
        let (w, h) = opts.paper.size_mm();
        let avail = (
            w - 2.0 * opts.margin_mm,
            h - 2.0 * opts.margin_mm - HEADER_MM,
        );
        let max_piece = (
            avail.0 - 2.0 * opts.bleed_mm,
            avail.1 - LABEL_MM - 2.0 * opts.bleed_mm,
        );
        ensure!(
            max_piece.0 > 10.0 && max_piece.1 > 10.0,
            "margins leave no room on the page"
        );
        Ok(Page {
            w,
            h,
            avail,
            max_piece,
        })
    }

    /// The page's size in pixels at `opts.dpi`.
    fn px(&self, opts: &SheetOptions) -> (u32, u32) {
        let px_per_mm = opts.dpi as f32 / 25.4;
        (
            (self.w * px_per_mm).round() as u32,
            (self.h * px_per_mm).round() as u32,
        )
    }

    /// `2480x3508 px`.
    fn px_text(&self, opts: &SheetOptions) -> String {
        let (w, h) = self.px(opts);
        format!("{w}x{h} px")
    }

    /// Bytes held while one page is drawn and written: the page (3 bytes per pixel), a piece's
    /// masks (at most a page, 3 bytes per pixel), the encoded PNG and the PDF's copy of its data
    /// (at most the raw size each, plus the encoder's rows: 6 bytes per pixel), plus 16 MB.
    fn draw_bytes(&self, opts: &SheetOptions) -> u64 {
        let (w, h) = self.px(opts);
        w as u64 * h as u64 * 12 + 16 * (1 << 20)
    }
}

/// One rectangle of a part's texture to print: its part, label, texel rectangle and size (mm).
struct Piece {
    part: usize,
    label: String,
    texels: [f32; 4],
    w: f32,
    h: f32,
}

/// One part measured: its triangles, 3D area (mm²), texel bounds and mm per texel.
struct Measured {
    tris: Vec<usize>,
    area_mm2: f64,
    lo: Vec2,
    hi: Vec2,
    mm_per_texel: f32,
}

/// The painted parts (UV islands) at print scale; a part with collapsed UVs shows no texture
/// and is left out.
fn measure_parts(mesh: &PrintMesh) -> Vec<Measured> {
    let tex = &mesh.textures[0];
    let (tw, th) = (tex.width as f32, tex.height as f32);
    let mut out = vec![];
    for g in islands(mesh) {
        let (mut a3, mut auv) = (0.0f64, 0.0f64);
        let (mut lo, mut hi) = (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN));
        for &ti in &g {
            let t = &mesh.tris[ti];
            let [p, q, r] = t.v.map(|i| mesh.positions[i as usize]);
            a3 += 0.5 * (q - p).cross(r - p).length() as f64;
            let uv = mesh
                .camo_uv(t)
                .unwrap()
                .map(|u| Vec2::new(u.x * tw, (1.0 - u.y) * th));
            auv += 0.5 * ((uv[1] - uv[0]).perp_dot(uv[2] - uv[0])).abs() as f64;
            for u in uv {
                lo = lo.min(u);
                hi = hi.max(u);
            }
        }
        if auv > 1e-9 {
            out.push(Measured {
                tris: g,
                area_mm2: a3,
                lo,
                hi,
                mm_per_texel: (a3 / auv).sqrt() as f32,
            });
        }
    }
    out
}

/// Parts smaller than this on paper (largest extent, mm) cannot be cut out and pasted: they are
/// left out of the sheets (and said), like printability's minimum feature.
pub const MIN_PART_MM: f32 = 1.0;

impl Measured {
    /// The part's largest extent on paper, mm.
    fn extent_mm(&self) -> f32 {
        ((self.hi - self.lo) * self.mm_per_texel).max_element()
    }
}

/// A part's tiles across and down (each at most the largest piece).
fn tiles(m: &Measured, max_piece: (f32, f32)) -> (f64, f64) {
    let (w, h) = ((m.hi - m.lo) * m.mm_per_texel).into();
    (
        (w as f64 / max_piece.0 as f64).ceil().max(1.0),
        (h as f64 / max_piece.1 as f64).ceil().max(1.0),
    )
}

/// Fewest pages the parts can take: the paper each piece needs (with bleed, label and gap),
/// summed over the pieces, over a page's printable area. Checked before the pieces are made,
/// so that a kilometre-long object at 1:1 is refused before millions of tiles are listed.
fn min_pages(parts: &[Measured], page: &Page, opts: &SheetOptions) -> f64 {
    let paper: f64 = parts
        .iter()
        .map(|m| {
            let (nx, ny) = tiles(m, page.max_piece);
            let (w, h) = ((m.hi - m.lo) * m.mm_per_texel).into();
            let pw = (w / nx as f32 + 2.0 * opts.bleed_mm + GAP_MM).max(30.0) as f64;
            let ph = (h / ny as f32 + 2.0 * opts.bleed_mm + LABEL_MM + GAP_MM) as f64;
            nx * ny * pw * ph
        })
        .sum();
    (paper / (page.avail.0 as f64 * page.avail.1 as f64)).ceil()
}

/// The painted parts at print scale, each cut into pieces no larger than the page's largest
/// piece, parts under [`MIN_PART_MM`] left out (the number left out is returned); refused
/// (naming `what`) when none is left or they cannot fit `opts.max_pages` pages.
#[allow(clippy::type_complexity)]
fn cut_pieces(
    mesh: &PrintMesh,
    page: &Page,
    opts: &SheetOptions,
    what: &dyn Fn(&str) -> String,
) -> Result<(Vec<(PartSheet, Vec<usize>)>, Vec<Piece>, usize)> {
    let measured = measure_parts(mesh);
    ensure!(
        !measured.is_empty(),
        "no painted part has texture coordinates to lay out"
    );
    let all = measured.len();
    let measured: Vec<Measured> = measured
        .into_iter()
        .filter(|m| m.extent_mm() >= MIN_PART_MM)
        .collect();
    ensure!(
        !measured.is_empty(),
        "{} has no painted part of at least {MIN_PART_MM} mm on paper (all {all} are smaller): \
         print at a larger scale, or use the textured 3MF (--formats 3mf-texture)",
        what("the layout")
    );
    let left = measured.len();
    let least = min_pages(&measured, page, opts);
    if least > opts.max_pages as f64 {
        let n: f64 = measured
            .iter()
            .map(|m| tiles(m, page.max_piece))
            .map(|(x, y)| x * y)
            .sum();
        let (least, n) = (least.min(1e15) as usize, n.min(1e15) as usize);
        check_pages(least, "at least ", n, opts, what)?;
    }
    let mut parts = vec![];
    let mut pieces = vec![];
    for (id, m) in measured.into_iter().enumerate() {
        let (nx, ny) = tiles(&m, page.max_piece);
        let s = m.mm_per_texel;
        let (sx, sy) = ((m.hi.x - m.lo.x) / nx as f32, (m.hi.y - m.lo.y) / ny as f32);
        for r in 0..ny as usize {
            for c in 0..nx as usize {
                let t = [
                    m.lo.x + c as f32 * sx,
                    m.lo.y + r as f32 * sy,
                    m.lo.x + (c + 1) as f32 * sx,
                    m.lo.y + (r + 1) as f32 * sy,
                ];
                let label = if nx * ny > 1.0 {
                    format!("P{} R{}C{}", id + 1, r + 1, c + 1)
                } else {
                    format!("P{}", id + 1)
                };
                pieces.push(Piece {
                    part: parts.len(),
                    label,
                    texels: t,
                    w: sx * s,
                    h: sy * s,
                });
            }
        }
        let mat = mesh.parts[mesh.tris[m.tris[0]].part as usize].clone();
        parts.push((
            PartSheet {
                id: id + 1,
                material: mat,
                triangles: m.tris.len(),
                area_mm2: m.area_mm2,
                mm_per_texel: s as f64,
                width_mm: (m.hi.x - m.lo.x) * s,
                height_mm: (m.hi.y - m.lo.y) * s,
                pieces: vec![],
            },
            m.tris,
        ));
    }
    Ok((parts, pieces, all - left))
}

/// Shelf packing, tallest first: each piece's placement (by index into `pieces`) and the
/// number of pages.
fn pack(pieces: &[Piece], page: &Page, opts: &SheetOptions) -> (Vec<(usize, Placement)>, usize) {
    let mut order: Vec<usize> = (0..pieces.len()).collect();
    order.sort_by(|&a, &b| pieces[b].h.total_cmp(&pieces[a].h));
    let (mut n, mut x, mut y, mut shelf_h) = (0usize, 0.0f32, 0.0f32, 0.0f32);
    let mut placed: Vec<(usize, Placement)> = vec![];
    for i in order {
        let p = &pieces[i];
        // The label ("P12 R1C2 180X75 MM", 2.6 mm capitals) must fit above the piece.
        let label_w = (p.label.len() + 12) as f32 * 6.0 * 2.6 / 7.0;
        let bw = (p.w + 2.0 * opts.bleed_mm).max(label_w);
        let bh = p.h + 2.0 * opts.bleed_mm + LABEL_MM;
        if x > 0.0 && x + bw > page.avail.0 {
            x = 0.0;
            y += shelf_h + GAP_MM;
            shelf_h = 0.0;
        }
        if y > 0.0 && y + bh > page.avail.1 {
            n += 1;
            x = 0.0;
            y = 0.0;
            shelf_h = 0.0;
        }
        placed.push((
            i,
            Placement {
                label: p.label.clone(),
                page: n,
                x_mm: opts.margin_mm + x + opts.bleed_mm,
                y_mm: opts.margin_mm + HEADER_MM + y + LABEL_MM + opts.bleed_mm,
                width_mm: p.w,
                height_mm: p.h,
                texels: p.texels,
            },
        ));
        x += bw + GAP_MM;
        shelf_h = shelf_h.max(bh);
    }
    (placed, n + 1)
}

/// Page `k` as an image: its pieces (`items`) rendered with their labels, the page's header and
/// scale bar.
fn draw_page(plan: &Plan, k: usize, items: &[(usize, Placement)]) -> RgbImage {
    let (opts, mesh) = (plan.opts, plan.mesh);
    let px_per_mm = opts.dpi as f32 / 25.4;
    let (wpx, hpx) = plan.page.px(opts);
    let mut img = RgbImage::from_pixel(wpx, hpx, image::Rgb([255, 255, 255]));
    let font_px = ((2.6 * px_per_mm) / 7.0).round().max(1.0) as u32; // 2.6 mm capitals
    for (i, pl) in items {
        let pc = &plan.pieces[*i];
        let (ps, tris) = &plan.parts[pc.part];
        let scale = (ps.mm_per_texel as f32, px_per_mm);
        render_piece(&mut img, mesh, tris, scale, pl, opts);
        let label = format!("{} {:.0}X{:.0} MM", pl.label, pl.width_mm, pl.height_mm);
        let lx = ((pl.x_mm - opts.bleed_mm) * px_per_mm) as i64;
        let ly = ((pl.y_mm - opts.bleed_mm - LABEL_MM + 1.0) * px_per_mm) as i64;
        draw_text(&mut img, lx, ly, &label, font_px, [0, 0, 0]);
    }
    let x0 = (opts.margin_mm * px_per_mm) as i64;
    let y0 = (opts.margin_mm * px_per_mm) as i64;
    let line = (7 * font_px + font_px * 4) as i64;
    let head = format!(
        "CAC PASTE-ON SHEET  {}  SCALE {}  PAGE {}/{}",
        mesh.name,
        plan.scale_txt,
        k + 1,
        plan.n_pages
    );
    draw_text(&mut img, x0, y0, &head, font_px, [0, 0, 0]);
    let print = format!(
        "PRINT AT 100% (ACTUAL SIZE, NO FIT TO PAGE)  {} DPI  {:?}",
        opts.dpi, opts.paper
    );
    draw_text(&mut img, x0, y0 + line, &print, font_px, [0, 0, 0]);
    let bar_y = y0 + 2 * line + font_px as i64;
    scale_bar(&mut img, x0, bar_y, px_per_mm, font_px);
    img
}

/// A 100 mm bar with 10 mm ticks and labels at 0, 50 and 100 mm.
fn scale_bar(img: &mut RgbImage, x0: i64, y0: i64, px_per_mm: f32, font_px: u32) {
    let t = (0.3 * px_per_mm).max(1.0) as i64;
    let len = (100.0 * px_per_mm) as i64;
    let tick = (2.5 * px_per_mm) as i64;
    fill_rect(img, x0, y0 + tick, len + t, t, [0, 0, 0]);
    for k in 0..=10 {
        let x = x0 + (k as f32 * 10.0 * px_per_mm) as i64;
        let h = if k % 5 == 0 { tick * 2 } else { tick };
        fill_rect(img, x, y0 + tick - h / 2, t, h, [0, 0, 0]);
    }
    let ty = y0 + tick * 2;
    for (mm, s) in [(0.0, "0"), (50.0, "50"), (100.0, "100 MM")] {
        let x = x0 + (mm * px_per_mm) as i64 - text_width(&s[..1], font_px) as i64 / 2;
        draw_text(img, x, ty, s, font_px, [0, 0, 0]);
    }
}

/// Draws one piece: texture inside the part (plus bleed), and the cut line. `scale` is the
/// part's (mm per texel, pixels per mm).
fn render_piece(
    img: &mut RgbImage,
    mesh: &PrintMesh,
    tris: &[usize],
    (mm_per_texel, px_per_mm): (f32, f32),
    pl: &Placement,
    opts: &SheetOptions,
) {
    let tex = &mesh.textures[0];
    let win = PieceWindow::new(pl, tex, mm_per_texel, px_per_mm, opts.bleed_mm);
    let mask = win.coverage(mesh, tris);
    // Bleed: square dilation by bleed_px (two separable passes, sliding-window counts).
    let bled = win.dilate(&win.dilate(&mask, true), false);
    let line = (px_per_mm * 0.25).max(1.0) as i64;
    win.paint(img, tex, &mask, &bled, line);
}

/// A piece's pixels on the page: where they start, how many (the piece, its bleed and one more
/// per side) and the texels they show.
struct PieceWindow {
    /// The page pixel of the window's top-left corner.
    x0: i64,
    y0: i64,
    /// The window's size (pixels).
    w: i64,
    h: i64,
    bleed_px: i64,
    texel_per_px: f32,
    /// The texel at the piece's top-left corner (after the bleed).
    origin: [f32; 2],
    /// The texture's size (texels).
    tw: f32,
    th: f32,
}

impl PieceWindow {
    /// The window of placement `pl` at `mm_per_texel` and `px_per_mm`, with `bleed_mm` around.
    fn new(
        pl: &Placement,
        tex: &Texture,
        mm_per_texel: f32,
        px_per_mm: f32,
        bleed_mm: f32,
    ) -> PieceWindow {
        let (tw, th) = (tex.width as f32, tex.height as f32);
        let bleed_px = (bleed_mm * px_per_mm).ceil() as i64;
        let x0 = (pl.x_mm * px_per_mm).round() as i64 - bleed_px;
        let y0 = (pl.y_mm * px_per_mm).round() as i64 - bleed_px;
        let w = (pl.width_mm * px_per_mm).ceil() as i64 + 2 * bleed_px + 1;
        let h = (pl.height_mm * px_per_mm).ceil() as i64 + 2 * bleed_px + 1;
        // Piece pixel (local) <-> texel.
        let texel_per_px = 1.0 / (mm_per_texel * px_per_mm);
        PieceWindow {
            x0,
            y0,
            w,
            h,
            bleed_px,
            texel_per_px,
            origin: [pl.texels[0], pl.texels[1]],
            tw,
            th,
        }
    }

    /// The window pixel (local) of texel position `t`.
    fn to_px(&self, t: Vec2) -> Vec2 {
        Vec2::new(
            (t.x - self.origin[0]) / self.texel_per_px + self.bleed_px as f32,
            (t.y - self.origin[1]) / self.texel_per_px + self.bleed_px as f32,
        )
    }

    /// Which window pixels' centres the part's triangles `tris` cover (in UV space).
    fn coverage(&self, mesh: &PrintMesh, tris: &[usize]) -> Vec<bool> {
        let (w, h) = (self.w, self.h);
        let mut mask = vec![false; (w * h) as usize];
        for &ti in tris {
            let uv = mesh.camo_uv(&mesh.tris[ti]).unwrap();
            let p = uv.map(|u| self.to_px(Vec2::new(u.x * self.tw, (1.0 - u.y) * self.th)));
            let area = (p[1] - p[0]).perp_dot(p[2] - p[0]);
            if area.abs() < 1e-9 {
                continue;
            }
            let lo = p[0].min(p[1]).min(p[2]).floor().max(Vec2::ZERO);
            let hi = p[0]
                .max(p[1])
                .max(p[2])
                .ceil()
                .min(Vec2::new((w - 1) as f32, (h - 1) as f32));
            for yy in lo.y as i64..=hi.y as i64 {
                for xx in lo.x as i64..=hi.x as i64 {
                    let q = Vec2::new(xx as f32 + 0.5, yy as f32 + 0.5);
                    let e = |a: Vec2, b: Vec2| (b - a).perp_dot(q - a) / area;
                    if e(p[0], p[1]) >= 0.0 && e(p[1], p[2]) >= 0.0 && e(p[2], p[0]) >= 0.0 {
                        mask[(yy * w + xx) as usize] = true;
                    }
                }
            }
        }
        mask
    }

    /// `m` dilated by `bleed_px` along rows (`horizontal`) or columns, by sliding-window counts.
    fn dilate(&self, m: &[bool], horizontal: bool) -> Vec<bool> {
        let (w, h, bleed_px) = (self.w, self.h, self.bleed_px);
        let mut out = vec![false; m.len()];
        let (lines, len) = if horizontal { (h, w) } else { (w, h) };
        let idx = |line: i64, k: i64| {
            if horizontal {
                (line * w + k) as usize
            } else {
                (k * w + line) as usize
            }
        };
        let mut prefix = vec![0u32; len as usize + 1];
        for line in 0..lines {
            for k in 0..len {
                prefix[k as usize + 1] = prefix[k as usize] + m[idx(line, k)] as u32;
            }
            for k in 0..len {
                let (a, b) = ((k - bleed_px).max(0), (k + bleed_px + 1).min(len));
                out[idx(line, k)] = prefix[b as usize] > prefix[a as usize];
            }
        }
        out
    }

    /// Draws the window's `bled` pixels onto the page: the texture, and a cut line `line`
    /// pixels wide inside the edge of `mask`.
    fn paint(&self, img: &mut RgbImage, tex: &Texture, mask: &[bool], bled: &[bool], line: i64) {
        let (w, h, bleed_px, texel_per_px) = (self.w, self.h, self.bleed_px, self.texel_per_px);
        let (tw, th) = (self.tw, self.th);
        for yy in 0..h {
            for xx in 0..w {
                let (gx, gy) = (self.x0 + xx, self.y0 + yy);
                if gx < 0 || gy < 0 || gx >= img.width() as i64 || gy >= img.height() as i64 {
                    continue;
                }
                let i = (yy * w + xx) as usize;
                if !bled[i] {
                    continue;
                }
                let inside = mask[i];
                let near_edge = (-line..=line).any(|d| {
                    let (ax, ay) = (xx + d, yy);
                    let (bx, by) = (xx, yy + d);
                    let m = |x: i64, y: i64| {
                        x >= 0 && y >= 0 && x < w && y < h && mask[(y * w + x) as usize]
                    };
                    m(ax, ay) != inside || m(bx, by) != inside
                });
                let c = if inside && near_edge {
                    [40, 40, 40]
                } else {
                    let tx =
                        self.origin[0] + (xx - bleed_px) as f32 * texel_per_px + 0.5 * texel_per_px;
                    let ty =
                        self.origin[1] + (yy - bleed_px) as f32 * texel_per_px + 0.5 * texel_per_px;
                    cac_core::colour::to_rgb8(tex.sample(Vec2::new(tx / tw, 1.0 - ty / th)))
                };
                img.put_pixel(gx as u32, gy as u32, image::Rgb(c));
            }
        }
    }
}
