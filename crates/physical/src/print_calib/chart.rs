//! The calibration chart: an A4 landscape page (297 × 210 mm) laid out in millimetres from its
//! top-left corner (x right, y down). Four fiducial markers sit in the corners: three nested
//! squares each (black 7 units, white 5, black 3; a unit is 2 mm), which the detector tells from
//! anything else on the page by that nesting. Below the title, at the top left, the 24 squares of
//! a ColorChecker Classic are drawn at their published colours with a black surround: a real
//! card is laid on them when the chart is photographed (a printed ColorChecker shows the
//! printer's colours, not the card's, and cannot correct the camera). The rest of the page is a
//! grid of the printed patches (full-colour and paper), or one labelled square per filament
//! (multi-material FDM) where a printed swatch of each filament is laid.
//!
//! The printed patches' colours are seeded and stratified over the sRGB cube: its 8 corners,
//! `max(4, N/16)` greys evenly spaced between black and white, and the rest one point drawn
//! uniformly in each of as many cells of an s×s×s division of the cube (s = ⌈∛rest⌉, the cells
//! picked at random); all quantised to 8 bits, then placed in a random order on the grid, so that
//! uneven light on the page does not follow the colours.

use anyhow::{bail, Context, Result};
use cac_core::colour;
use cac_core::report::font;
use image::RgbImage;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The `format` of a `chart.json`.
pub const FORMAT: &str = "cac-print-chart/1";
/// The page: A4 landscape, mm.
pub const PAGE_MM: [f32; 2] = [297.0, 210.0];
/// Resolution of `chart.png` (print it at 100 %: 297 mm across).
pub const PNG_DPI: f32 = 300.0;
/// Side of a fiducial marker, mm, and its squares' sides in units (black, white, black).
pub const MARKER_MM: f32 = 14.0;
pub const MARKER_RINGS: [u32; 3] = [7, 5, 3];
const MARGIN_MM: f32 = 8.0;
/// Between the marker rows (with the title and the note) and the patch area.
const GAP_MM: f32 = 4.0;
/// A patch's side as a share of its grid pitch (the rest is white gutter).
const PATCH_SHARE: f32 = 0.8;
/// Fewest and most printed patches a chart may have.
pub const MIN_PATCHES: usize = 16;
pub const MAX_PATCHES: usize = 600;

/// The ColorChecker Classic's 24 patches in reading order (rows: natural colours, saturated
/// colours, primaries and secondaries, greys) with their published sRGB (D65) values: X-Rite's,
/// as tabulated in the column "Manufacturer's sRGB color values" of Wikipedia's "ColorChecker"
/// article (McCamy, Marcus & Davidson 1976 define the chart).
pub const COLORCHECKER: [(&str, &str); 24] = [
    ("dark skin", "#735244"),
    ("light skin", "#C29682"),
    ("blue sky", "#627A9D"),
    ("foliage", "#576C43"),
    ("blue flower", "#8580B1"),
    ("bluish green", "#67BDAA"),
    ("orange", "#D67E2C"),
    ("purplish blue", "#505BA6"),
    ("moderate red", "#C15A63"),
    ("purple", "#5E3C6C"),
    ("yellow green", "#9DBC40"),
    ("orange yellow", "#E0A32E"),
    ("blue", "#383D96"),
    ("green", "#469449"),
    ("red", "#AF363C"),
    ("yellow", "#E7C71F"),
    ("magenta", "#BB5695"),
    ("cyan", "#0885A1"),
    ("white 9.5", "#F3F3F2"),
    ("neutral 8", "#C8C8C8"),
    ("neutral 6.5", "#A0A0A0"),
    ("neutral 5", "#7A7A79"),
    ("neutral 3.5", "#555555"),
    ("black 2", "#343434"),
];

/// The ColorChecker's grey row: indices 18..24, white to black.
pub const CHECKER_GREYS: std::ops::Range<usize> = 18..24;

/// The kind of printer a chart (and the profile fitted from it) is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PrinterKind {
    /// Full-colour 3D printing (binder-jet, PolyJet, colour MJF): a fitted response.
    FullColour,
    /// Paper or vinyl (sheets, wraps): a fitted response and the media width.
    Paper,
    /// Multi-material FDM: the filaments' measured colours.
    Fdm,
}

// The names are those of the command line, `chart.json` and `Profile::kind`.
cac_core::choices!(PrinterKind {
    FullColour => "full-colour": "Full-colour 3D printing (binder-jet, PolyJet, colour MJF): a fitted response",
    Paper => "paper": "Paper or vinyl (sheets, wraps): a fitted response and the media width",
    Fdm => "fdm": "Multi-material FDM: the filaments' measured colours",
});

/// What a patch is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// A ColorChecker square: a real card lies there; `srgb` is its published value.
    Checker,
    /// A colour the printer prints; `srgb` is the requested colour.
    Printed,
    /// A filament's square (FDM): a printed swatch lies there; `srgb` is its nominal colour.
    Filament,
}

/// One square of the chart.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Patch {
    pub role: Role,
    /// Centre, mm from the page's top-left corner.
    pub centre_mm: [f32; 2],
    /// Side, mm.
    pub size_mm: f32,
    /// `#RRGGBB`: requested (printed), published (checker) or nominal (filament).
    pub srgb: String,
    /// The ColorChecker patch's or the filament's name.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub name: String,
}

/// The four corner markers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Fiducials {
    /// Centres, mm: top-left, top-right, bottom-right, bottom-left.
    pub centres_mm: [[f32; 2]; 4],
    /// Side of a marker, mm.
    pub size_mm: f32,
    /// Sides of its nested squares (black, white, black) in units of `size_mm / rings[0]`.
    pub rings: [u32; 3],
}

/// A chart as written to `chart.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Chart {
    /// [`FORMAT`].
    pub format: String,
    pub printer: PrinterKind,
    /// Seed of the printed patches' colours and places.
    pub seed: u64,
    /// Page width and height, mm.
    pub page_mm: [f32; 2],
    pub fiducials: Fiducials,
    /// Centre-to-centre spacing of the ColorChecker squares, mm (the card laid there must match).
    pub checker_pitch_mm: f32,
    /// The ColorChecker's 24 (in its reading order), then the printed patches or the filaments.
    pub patches: Vec<Patch>,
}

/// What to put on a chart (`cac print chart`'s flags).
#[derive(Clone, Debug)]
pub struct ChartSpec {
    /// The printer the chart calibrates.
    pub kind: PrinterKind,
    /// Colour patches to print besides the ColorChecker's squares (full-colour and paper).
    pub patches: usize,
    /// Seed of the patches' colours and places.
    pub seed: u64,
    /// Centre-to-centre spacing of your ColorChecker card's patches, mm (its squares are drawn
    /// at this pitch so that the card laid on them covers them).
    pub checker_pitch_mm: f32,
    /// FDM: the filaments, comma separated, each NAME or NAME=#RRGGBB (the nominal colour its
    /// square is drawn in); 2 to 16.
    pub filaments: Vec<String>,
}

/// What a pixel of the drawn page is: the caller says what colour each is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ink {
    /// The page itself.
    Paper,
    /// Markers and text.
    Black,
    /// The surround of the ColorChecker squares (the card's own black border when one lies there).
    CheckerFrame,
    /// Patch `i` of [`Chart::patches`].
    Patch(usize),
}

impl Chart {
    /// Lays out a chart; errors name the flag that is out of range.
    pub fn new(spec: &ChartSpec) -> Result<Chart> {
        let [w, h] = PAGE_MM;
        let p = spec.checker_pitch_mm;
        if !(8.0..=20.0).contains(&p) {
            bail!("--checker-pitch-mm {p}: a ColorChecker's pitch on this page must be 8 to 20 mm");
        }
        let c = MARGIN_MM + MARKER_MM / 2.0;
        let fiducials = Fiducials {
            centres_mm: [[c, c], [w - c, c], [w - c, h - c], [c, h - c]],
            size_mm: MARKER_MM,
            rings: MARKER_RINGS,
        };
        let area = [
            MARGIN_MM,
            MARGIN_MM + MARKER_MM + GAP_MM,
            w - MARGIN_MM,
            h - MARGIN_MM - MARKER_MM - GAP_MM,
        ];
        let frame = checker_frame(area, p);
        let mut patches: Vec<Patch> = COLORCHECKER
            .iter()
            .enumerate()
            .map(|(i, (name, hex))| Patch {
                role: Role::Checker,
                centre_mm: [
                    frame[0] + p * (0.25 + (i % 6) as f32 + 0.5),
                    frame[1] + p * (0.25 + (i / 6) as f32 + 0.5),
                ],
                size_mm: p * PATCH_SHARE,
                srgb: (*hex).into(),
                name: (*name).into(),
            })
            .collect();
        let keep_out = [
            frame[0] - 3.0,
            frame[1] - 3.0,
            frame[2] + 3.0,
            frame[3] + 3.0,
        ];
        match spec.kind {
            PrinterKind::Fdm => {
                let filaments = parse_filaments(&spec.filaments)?;
                let (pitch, cells) = grid(area, keep_out, filaments.len(), 45.0)
                    .context("--filaments: the squares do not fit on the page")?;
                for ((name, c), cell) in filaments.into_iter().zip(cells) {
                    patches.push(Patch {
                        role: Role::Filament,
                        // The square sits in the cell's top part; its label below it.
                        centre_mm: [cell[0], cell[1] - 0.1 * pitch],
                        size_mm: 0.6 * pitch,
                        srgb: colour::to_hex(c.unwrap_or([0.5; 3])),
                        name,
                    });
                }
            }
            _ => {
                if !spec.filaments.is_empty() {
                    bail!("--filaments is for an fdm chart, not a {} one", spec.kind);
                }
                let n = spec.patches;
                if !(MIN_PATCHES..=MAX_PATCHES).contains(&n) {
                    bail!("--patches {n}: a chart has {MIN_PATCHES} to {MAX_PATCHES} patches");
                }
                let (pitch, cells) = grid(area, keep_out, n, 30.0)
                    .with_context(|| format!("--patches {n} do not fit on the page"))?;
                let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
                for (c, cell) in patch_colours(n, &mut rng).into_iter().zip(cells) {
                    patches.push(Patch {
                        role: Role::Printed,
                        centre_mm: cell,
                        size_mm: pitch * PATCH_SHARE,
                        srgb: colour::to_hex(c),
                        name: String::new(),
                    });
                }
            }
        }
        Ok(Chart {
            format: FORMAT.into(),
            printer: spec.kind,
            seed: spec.seed,
            page_mm: PAGE_MM,
            fiducials,
            checker_pitch_mm: p,
            patches,
        })
    }

    /// Reads and checks a `chart.json`; errors name the file and what is wrong.
    pub fn load(path: &Path) -> Result<Chart> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read chart {}", path.display()))?;
        let chart: Chart = serde_json::from_str(&text)
            .with_context(|| format!("chart {} is not a chart.json", path.display()))?;
        chart
            .check()
            .with_context(|| format!("chart {}", path.display()))?;
        Ok(chart)
    }

    fn check(&self) -> Result<()> {
        if self.format != FORMAT {
            bail!("format {:?} is not {FORMAT:?}", self.format);
        }
        let checker = self.of(Role::Checker).count();
        if checker != 24 {
            bail!("it has {checker} ColorChecker patches, not 24");
        }
        for (i, p) in self.patches.iter().enumerate() {
            if colour::from_hex(&p.srgb).is_none() {
                bail!("patch {i}: srgb {:?} is not #RRGGBB", p.srgb);
            }
            if p.size_mm.is_nan() || p.size_mm <= 0.0 {
                bail!("patch {i}: size_mm must be positive");
            }
        }
        let (printed, filaments) = (
            self.of(Role::Printed).count(),
            self.of(Role::Filament).count(),
        );
        match self.printer {
            PrinterKind::Fdm if filaments < 2 || printed > 0 => {
                bail!("an fdm chart has 2 or more filament squares and no printed patches")
            }
            PrinterKind::FullColour | PrinterKind::Paper
                if printed < MIN_PATCHES || filaments > 0 =>
            {
                bail!(
                    "a {} chart has at least {MIN_PATCHES} printed patches and no filament squares",
                    self.printer
                )
            }
            _ => Ok(()),
        }
    }

    /// The patches of one role with their indices.
    pub fn of(&self, role: Role) -> impl Iterator<Item = (usize, &Patch)> {
        self.patches
            .iter()
            .enumerate()
            .filter(move |(_, p)| p.role == role)
    }

    /// A patch's colour (`srgb`) as numbers (checked on load).
    pub fn srgb(&self, i: usize) -> [f32; 3] {
        colour::from_hex(&self.patches[i].srgb).unwrap_or([0.5; 3])
    }

    /// Writes `DIR/chart.json` and `DIR/chart.png` (300 dpi, the colours as requested).
    pub fn write(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let json = serde_json::to_string_pretty(self)?;
        cac_core::io::write_atomic(&dir.join("chart.json"), json.as_bytes())?;
        let px = |mm: f32| (mm / 25.4 * PNG_DPI).round() as u32;
        let img = self.draw(px(self.page_mm[0]), px(self.page_mm[1]), &|ink| {
            colour::to_rgb8(match ink {
                Ink::Paper => [1.0; 3],
                Ink::Black | Ink::CheckerFrame => [0.0; 3],
                Ink::Patch(i) => self.srgb(i),
            })
        });
        cac_core::io::save_png_atomic(&dir.join("chart.png"), &img)
    }

    /// The page drawn at `width` × `height` pixels (the page's scale may differ in x and y, as in
    /// a texture atlas), each part in the colour `ink` gives it.
    pub fn draw(&self, width: u32, height: u32, ink: &dyn Fn(Ink) -> [u8; 3]) -> RgbImage {
        let (sx, sy) = (
            width as f32 / self.page_mm[0],
            height as f32 / self.page_mm[1],
        );
        let mut img = RgbImage::from_pixel(width, height, image::Rgb(ink(Ink::Paper)));
        let rect = |img: &mut RgbImage, c: [f32; 2], half: [f32; 2], what: Ink| {
            let x0 = ((c[0] - half[0]) * sx).round() as i64;
            let y0 = ((c[1] - half[1]) * sy).round() as i64;
            let x1 = ((c[0] + half[0]) * sx).round() as i64;
            let y1 = ((c[1] + half[1]) * sy).round() as i64;
            font::fill_rect(img, x0, y0, x1 - x0, y1 - y0, ink(what));
        };
        let f = &self.fiducials;
        for c in f.centres_mm {
            for (k, side) in f.rings.iter().enumerate() {
                let half = f.size_mm * *side as f32 / f.rings[0] as f32 / 2.0;
                let what = if k % 2 == 0 { Ink::Black } else { Ink::Paper };
                rect(&mut img, c, [half; 2], what);
            }
        }
        let checker: Vec<&Patch> = self.of(Role::Checker).map(|(_, p)| p).collect();
        if let (Some(first), Some(last)) = (checker.first(), checker.last()) {
            let m = self.checker_pitch_mm * 0.75;
            let lo = [first.centre_mm[0] - m, first.centre_mm[1] - m];
            let hi = [last.centre_mm[0] + m, last.centre_mm[1] + m];
            rect(
                &mut img,
                [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0],
                [(hi[0] - lo[0]) / 2.0, (hi[1] - lo[1]) / 2.0],
                Ink::CheckerFrame,
            );
        }
        for (i, p) in self.patches.iter().enumerate() {
            rect(&mut img, p.centre_mm, [p.size_mm / 2.0; 2], Ink::Patch(i));
        }
        // Text: 0.5 mm font pixels (3.5 mm capitals).
        let fpx = (0.5 * sx).round().max(1.0) as u32;
        let black = ink(Ink::Black);
        let text_x = ((MARGIN_MM + MARKER_MM + GAP_MM) * sx) as i64;
        let line = |k: f32| ((MARGIN_MM + 0.5 + 5.0 * k) * sy) as i64;
        let what = match self.printer {
            PrinterKind::Fdm => format!("{} filaments", self.of(Role::Filament).count()),
            _ => format!("{} patches", self.of(Role::Printed).count()),
        };
        let title = match self.printer {
            PrinterKind::Fdm => format!("cac print chart: fdm, {what}"),
            k => format!("cac print chart: {k}, {what}, seed {}", self.seed),
        };
        font::draw_text(&mut img, text_x, line(0.0), &title, fpx, black);
        let how = match self.printer {
            PrinterKind::Fdm => "lay a printed swatch of each filament on its square",
            _ => "print at 100 % (297 mm wide), as the camouflage will be printed",
        };
        font::draw_text(&mut img, text_x, line(1.0), how, fpx, black);
        let note = format!(
            "lay a ColorChecker Classic on the 24 squares (pitch {} mm)",
            self.checker_pitch_mm
        );
        let bottom = ((self.page_mm[1] - MARGIN_MM - MARKER_MM / 2.0 - 2.0) * sy) as i64;
        font::draw_text(&mut img, text_x, bottom, &note, fpx, black);
        for p in self.patches.iter().filter(|p| p.role == Role::Filament) {
            let label: String = p.name.chars().take(20).collect();
            let size = ((p.size_mm * sx) / (6.0 * label.chars().count().max(6) as f32))
                .floor()
                .clamp(1.0, fpx as f32) as u32;
            let tw = font::text_width(&label, size) as i64;
            let x = (p.centre_mm[0] * sx) as i64 - tw / 2;
            let y = ((p.centre_mm[1] + p.size_mm / 2.0 + 1.5) * sy) as i64;
            font::draw_text(&mut img, x, y, &label, size, black);
        }
        img
    }
}

/// The ColorChecker's block (its surround included) at the top left of the patch area.
fn checker_frame(area: [f32; 4], pitch: f32) -> [f32; 4] {
    let (w, h) = (6.5 * pitch, 4.5 * pitch);
    [area[0], area[1], area[0] + w, area[1] + h]
}

/// The largest square grid pitch (≤ `max_pitch`, 0.25 mm steps, ≥ 4 mm) with `n` cells in
/// `area` clear of `keep_out`, and the first `n` such cells' centres in reading order.
fn grid(
    area: [f32; 4],
    keep_out: [f32; 4],
    n: usize,
    max_pitch: f32,
) -> Result<(f32, Vec<[f32; 2]>)> {
    let (aw, ah) = (area[2] - area[0], area[3] - area[1]);
    let mut pitch = max_pitch;
    while pitch >= 4.0 {
        let (cols, rows) = ((aw / pitch).floor() as usize, (ah / pitch).floor() as usize);
        let x0 = area[0] + (aw - cols as f32 * pitch) / 2.0;
        let y0 = area[1] + (ah - rows as f32 * pitch) / 2.0;
        let cells: Vec<[f32; 2]> = (0..rows)
            .flat_map(|r| (0..cols).map(move |c| (r, c)))
            .map(|(r, c)| [x0 + (c as f32 + 0.5) * pitch, y0 + (r as f32 + 0.5) * pitch])
            .filter(|c| {
                let h = pitch / 2.0;
                c[0] + h <= keep_out[0]
                    || c[0] - h >= keep_out[2]
                    || c[1] + h <= keep_out[1]
                    || c[1] - h >= keep_out[3]
            })
            .take(n)
            .collect();
        if cells.len() == n {
            return Ok((pitch, cells));
        }
        pitch -= 0.25;
    }
    bail!("{n} squares of at least 4 mm do not fit on the page")
}

/// `n` requested colours: the cube's corners, greys, stratified points; 8-bit; shuffled.
fn patch_colours(n: usize, rng: &mut ChaCha8Rng) -> Vec<[f32; 3]> {
    let mut out: Vec<[f32; 3]> = (0..8)
        .map(|i| [(i >> 2) & 1, (i >> 1) & 1, i & 1].map(|b| b as f32))
        .collect();
    let greys = (n / 16).max(4);
    out.extend((1..=greys).map(|k| [k as f32 / (greys + 1) as f32; 3]));
    let rest = n.saturating_sub(out.len());
    let s = (1..).find(|s: &usize| s * s * s >= rest).unwrap_or(1);
    let mut cells: Vec<usize> = (0..s * s * s).collect();
    cells.shuffle(rng);
    for &c in cells.iter().take(rest) {
        let cell = [c / (s * s), (c / s) % s, c % s];
        out.push(cell.map(|k| (k as f32 + rng.random::<f32>()) / s as f32));
    }
    out.truncate(n);
    let mut out: Vec<[f32; 3]> = out
        .into_iter()
        .map(|c| colour::to_rgb8(c).map(|v| v as f32 / 255.0))
        .collect();
    out.shuffle(rng);
    out
}

/// `NAME` or `NAME=#RRGGBB`, 2 to 16 of them.
fn parse_filaments(items: &[String]) -> Result<Vec<(String, Option<[f32; 3]>)>> {
    let max = cac_core::printer::MAX_FILAMENTS;
    if !(2..=max).contains(&items.len()) {
        bail!(
            "--filaments: an fdm chart names 2 to {max} filaments (NAME or NAME=#RRGGBB, comma separated), not {}",
            items.len()
        );
    }
    items
        .iter()
        .map(|it| match it.split_once('=') {
            None => Ok((it.trim().to_string(), None)),
            Some((name, hex)) => match colour::from_hex(hex) {
                Some(c) => Ok((name.trim().to_string(), Some(c))),
                None => bail!("--filaments: {it:?}: {hex:?} is not #RRGGBB"),
            },
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(kind: PrinterKind, n: usize) -> ChartSpec {
        ChartSpec {
            kind,
            patches: n,
            seed: 3,
            checker_pitch_mm: 13.0,
            filaments: vec![],
        }
    }

    #[test]
    fn a_chart_has_the_corners_greys_and_the_checker_and_fits_the_page() {
        for n in [16, 24, 96, 192, 600] {
            let c = Chart::new(&spec(PrinterKind::Paper, n)).unwrap();
            c.check().unwrap();
            assert_eq!(c.of(Role::Printed).count(), n);
            let cols: Vec<[f32; 3]> = c.of(Role::Printed).map(|(i, _)| c.srgb(i)).collect();
            for corner in [[0.0; 3], [1.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]] {
                assert!(cols.contains(&corner), "{n}: {corner:?}");
            }
            let greys = cols.iter().filter(|c| c[0] == c[1] && c[1] == c[2]).count();
            assert!(greys >= 6, "{n}: {greys} greys");
            // Patches stay on the page, clear of the markers and of each other.
            for (i, p) in c.patches.iter().enumerate() {
                let h = p.size_mm / 2.0;
                assert!(p.centre_mm[0] - h > 8.0 && p.centre_mm[0] + h < 289.0);
                assert!(
                    p.centre_mm[1] - h > 22.0 && p.centre_mm[1] + h < 188.0,
                    "{i}"
                );
                for q in &c.patches[i + 1..] {
                    let d = (p.centre_mm[0] - q.centre_mm[0])
                        .abs()
                        .max((p.centre_mm[1] - q.centre_mm[1]).abs());
                    assert!(d >= h + q.size_mm / 2.0, "patches overlap");
                }
            }
        }
        assert!(Chart::new(&spec(PrinterKind::Paper, 601)).is_err());
        let a = Chart::new(&spec(PrinterKind::FullColour, 48)).unwrap();
        let b = Chart::new(&spec(PrinterKind::FullColour, 48)).unwrap();
        assert_eq!(a, b, "seeded");
    }

    #[test]
    fn an_fdm_chart_names_its_filaments() {
        let mut s = spec(PrinterKind::Fdm, 0);
        s.filaments = vec!["white=#F2F2F0".into(), "black".into(), "red=#C12E1F".into()];
        let c = Chart::new(&s).unwrap();
        c.check().unwrap();
        let f: Vec<&Patch> = c.of(Role::Filament).map(|(_, p)| p).collect();
        assert_eq!(f.len(), 3);
        assert_eq!(
            (f[0].name.as_str(), f[0].srgb.as_str()),
            ("white", "#F2F2F0")
        );
        s.filaments = vec!["white=#F2F2".into(), "black".into()];
        assert!(format!("{:#}", Chart::new(&s).unwrap_err()).contains("white"));
        s.filaments.truncate(1);
        assert!(format!("{:#}", Chart::new(&s).unwrap_err()).contains("2 to 16"));
    }
}
