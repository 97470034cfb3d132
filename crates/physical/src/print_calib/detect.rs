//! Finding the chart in a photograph and reading its patches.
//!
//! The photo is thresholded against its local mean (a pixel is dark below 0.75 × the mean
//! luminance around it, the window an eighth of the short side), dark regions are joined
//! 8-connected and light ones 4-connected (so that every region is enclosed by exactly one
//! other), and each region's parent is the region just above its first pixel in raster order. A
//! marker is a dark region with exactly one hole that itself holds exactly one dark region, with
//! the areas of three nested squares (7, 5, 3 units: the inner two fill about ½ and the centre
//! about ⅕ of the whole) and the centre's centroid at the whole's. Letters, patches and the
//! ColorChecker's surround have no such nesting.
//!
//! The four markers, ordered round their centroid, give the homography from the page (mm) to the
//! photo; of its four rotations the one whose patches' lightness follows the chart's best is
//! taken. With the lens's calibration the homography maps to undistorted pixels and the points
//! are distorted back, so a wide-angle webcam's barrel distortion does not move the patches.
//! Each patch is read as the trimmed mean (a fifth dropped at each end, per channel, in linear
//! light) of a 7×7 grid over the middle 60 % of its side: away from its edges and the blur.

use super::chart::{Chart, Role};
use super::linalg;
use crate::calib::CameraModel;
use anyhow::{bail, Result};
use cac_core::colour;
use glam::DVec2;
use image::RgbImage;

/// A photo's short side must be at least this many pixels.
pub const MIN_SIDE_PX: u32 = 240;
/// Each patch must be at least this many pixels across in the photo.
pub const MIN_PATCH_PX: f64 = 8.0;
/// A patch is clipped when at least this share of its samples has a channel at 255.
pub const CLIPPED_SHARE: f32 = 0.25;

/// A fiducial marker found in a photo: its centre (pixels, centres at half-integers) and area.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Marker {
    pub centre: [f64; 2],
    pub area_px: f64,
}

/// One connected region of the thresholded photo.
struct Region {
    dark: bool,
    area: usize,
    sum: [f64; 2],
    border: bool,
    parent: Option<usize>,
}

/// The fiducial markers in a photo, largest first.
pub fn find_markers(img: &RgbImage) -> Vec<Marker> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w < 3 || h < 3 {
        return vec![];
    }
    let lum: Vec<f64> = img
        .pixels()
        .map(|p| (0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64) / 255.0)
        .collect();
    // Integral image of the luminance, for the local means.
    let mut integ = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            row += lum[y * w + x];
            integ[(y + 1) * (w + 1) + x + 1] = integ[y * (w + 1) + x + 1] + row;
        }
    }
    let r = (w.min(h) / 16).max(7);
    let dark: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
            let s = integ[y1 * (w + 1) + x1] - integ[y0 * (w + 1) + x1] - integ[y1 * (w + 1) + x0]
                + integ[y0 * (w + 1) + x0];
            let mean = s / ((x1 - x0) * (y1 - y0)) as f64;
            lum[i] < 0.75 * mean
        })
        .collect();
    let regions = label(&dark, w, h);
    let mut children: Vec<Vec<usize>> = vec![vec![]; regions.len()];
    for (i, r) in regions.iter().enumerate() {
        if let Some(p) = r.parent {
            children[p].push(i);
        }
    }
    // Specks from noise do not count as holes or contents.
    let kids = |i: usize| -> Vec<usize> {
        let min = (regions[i].area / 50).max(3);
        children[i]
            .iter()
            .copied()
            .filter(|&c| regions[c].area >= min)
            .collect()
    };
    let mut out = vec![];
    for (a, ra) in regions.iter().enumerate() {
        if !ra.dark || ra.border || ra.area < 12 {
            continue;
        }
        let [b] = kids(a)[..] else { continue };
        let [c] = kids(b)[..] else { continue };
        if !kids(c).is_empty() {
            continue;
        }
        let (rb, rc) = (&regions[b], &regions[c]);
        let total = (ra.area + rb.area + rc.area) as f64;
        let inner = (rb.area + rc.area) as f64 / total;
        let centre = rc.area as f64 / total;
        if total < 30.0 || !(0.3..=0.75).contains(&inner) || !(0.07..=0.35).contains(&centre) {
            continue;
        }
        let whole = [0, 1].map(|k| (ra.sum[k] + rb.sum[k] + rc.sum[k]) / total);
        let mid = [0, 1].map(|k| rc.sum[k] / rc.area as f64);
        if (whole[0] - mid[0]).hypot(whole[1] - mid[1]) > 0.15 * total.sqrt() {
            continue;
        }
        out.push(Marker {
            centre: whole.map(|v| v + 0.5),
            area_px: total,
        });
    }
    out.sort_by(|a, b| b.area_px.total_cmp(&a.area_px));
    out
}

/// Connected regions of a binary image: dark 8-connected, light 4-connected; each region's
/// parent is the region of the pixel above its first pixel (the one that encloses it).
fn label(dark: &[bool], w: usize, h: usize) -> Vec<Region> {
    const NONE: u32 = u32::MAX;
    let mut lab = vec![NONE; w * h];
    let mut regions = vec![];
    let mut stack = vec![];
    for start in 0..w * h {
        if lab[start] != NONE {
            continue;
        }
        let id = regions.len();
        let d = dark[start];
        let parent = (start >= w).then(|| lab[start - w] as usize);
        let mut reg = Region {
            dark: d,
            area: 0,
            sum: [0.0; 2],
            border: false,
            parent,
        };
        lab[start] = id as u32;
        stack.push(start);
        while let Some(p) = stack.pop() {
            let (x, y) = ((p % w) as isize, (p / w) as isize);
            reg.area += 1;
            reg.sum[0] += x as f64;
            reg.sum[1] += y as f64;
            if x == 0 || y == 0 || x as usize == w - 1 || y as usize == h - 1 {
                reg.border = true;
            }
            for (dx, dy) in [
                (1, 0),
                (-1, 0),
                (0, 1),
                (0, -1),
                (1, 1),
                (-1, -1),
                (1, -1),
                (-1, 1),
            ]
            .into_iter()
            .take(if d { 8 } else { 4 })
            {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx as usize >= w || ny as usize >= h {
                    continue;
                }
                let q = ny as usize * w + nx as usize;
                if lab[q] == NONE && dark[q] == d {
                    lab[q] = id as u32;
                    stack.push(q);
                }
            }
        }
        regions.push(reg);
    }
    regions
}

/// The chart located in a photo: page millimetres to photo pixels.
#[derive(Clone, Debug)]
pub struct Located {
    /// The markers' centres in the photo (pixels): top-left, top-right, bottom-right,
    /// bottom-left of the page.
    pub markers_px: [[f64; 2]; 4],
    /// Page mm → undistorted pixels.
    h: [f64; 9],
    lens: Option<CameraModel>,
    /// How well the patches' lightness follows the chart's (Pearson's r of L*).
    pub match_r: f64,
}

impl Located {
    /// The photo pixel of a point on the page (mm).
    pub fn to_pixel(&self, mm: [f32; 2]) -> [f64; 2] {
        let p = linalg::apply(&self.h, [mm[0] as f64, mm[1] as f64]);
        match &self.lens {
            None => p,
            Some(l) => {
                let n = DVec2::new((p[0] - l.cx) / l.fx, (p[1] - l.cy) / l.fy);
                let d = l.distort(n);
                [l.fx * d.x + l.cx, l.fy * d.y + l.cy]
            }
        }
    }
}

/// A patch as read from the photo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatchReading {
    /// Trimmed mean, linear light (the camera's sRGB decoded).
    pub linear: [f32; 3],
    /// Share of the samples with a channel at 255.
    pub clipped: f32,
    /// The patch's side in the photo, pixels (the shorter of its two).
    pub size_px: f64,
}

/// Locates the chart from four markers (of `markers`, the four largest), trying the four
/// rotations; `lens` is the camera's calibration at the photo's size.
pub fn locate(
    img: &RgbImage,
    chart: &Chart,
    markers: &[Marker],
    lens: Option<&CameraModel>,
) -> Result<Located> {
    if markers.len() < 4 {
        bail!(
            "fiducials not found: {} of the chart's 4 corner markers (nested black, white and black squares) are in the photo; the whole page must be in the picture, evenly lit and in focus",
            markers.len()
        );
    }
    let ideal = |p: [f64; 2]| match lens {
        None => p,
        Some(l) => {
            let n = l.undistort(DVec2::new((p[0] - l.cx) / l.fx, (p[1] - l.cy) / l.fy));
            [l.fx * n.x + l.cx, l.fy * n.y + l.cy]
        }
    };
    let mut pts: Vec<[f64; 2]> = markers[..4].iter().map(|m| m.centre).collect();
    let c = [0, 1].map(|k| pts.iter().map(|p| p[k]).sum::<f64>() / 4.0);
    pts.sort_by(|a, b| {
        let ang = |p: &[f64; 2]| (p[1] - c[1]).atan2(p[0] - c[0]);
        ang(a).total_cmp(&ang(b))
    });
    let page = chart
        .fiducials
        .centres_mm
        .map(|p| [p[0] as f64, p[1] as f64]);
    let judged: Vec<usize> = chart
        .patches
        .iter()
        .enumerate()
        .filter(|(_, p)| match chart.printer {
            super::PrinterKind::Fdm => p.role == Role::Checker,
            _ => p.role != Role::Filament,
        })
        .map(|(i, _)| i)
        .collect();
    let wanted: Vec<f64> = judged
        .iter()
        .map(|&i| colour::srgb_to_lab(chart.srgb(i))[0] as f64)
        .collect();
    let mut best: Option<Located> = None;
    for k in 0..4 {
        let seen: [[f64; 2]; 4] = std::array::from_fn(|i| pts[(i + k) % 4]);
        let Some(h) = linalg::homography(&page, &seen.map(ideal)) else {
            continue;
        };
        let mut loc = Located {
            markers_px: seen,
            h,
            lens: lens.cloned(),
            match_r: 0.0,
        };
        let got: Vec<f64> = judged
            .iter()
            .map(|&i| {
                let r = read_patch(img, &loc, &chart.patches[i], 3);
                let s = r.linear.map(colour::encode);
                colour::srgb_to_lab(s)[0] as f64
            })
            .collect();
        loc.match_r = pearson(&wanted, &got);
        if best.as_ref().is_none_or(|b| loc.match_r > b.match_r) {
            best = Some(loc);
        }
    }
    match best {
        Some(b) if b.match_r >= 0.6 => Ok(b),
        Some(b) => bail!(
            "the patches in the photo do not follow this chart.json (lightness correlation {:.2}, at least 0.6 expected): is it a photo of this chart (its printer kind and seed), with the ColorChecker on its squares?",
            b.match_r
        ),
        None => bail!("fiducials not found: the four markers found do not span a page"),
    }
}

/// Reads one patch: the trimmed mean of a `g`×`g` grid over the middle 60 % of its side.
pub fn read_patch(
    img: &RgbImage,
    loc: &Located,
    p: &super::chart::Patch,
    g: usize,
) -> PatchReading {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let s = p.size_mm;
    let mut vals: [Vec<f32>; 3] = Default::default();
    let mut clipped = 0usize;
    for j in 0..g {
        for i in 0..g {
            let t = |k: usize| {
                if g == 1 {
                    0.0
                } else {
                    (-0.3 + 0.6 * k as f32 / (g - 1) as f32) * s
                }
            };
            let [x, y] = loc.to_pixel([p.centre_mm[0] + t(i), p.centre_mm[1] + t(j)]);
            // Bilinear, pixel centres at half-integers, clamped at the border.
            let (fx, fy) = (x - 0.5, y - 0.5);
            let (x0, y0) = (fx.floor(), fy.floor());
            let (ax, ay) = ((fx - x0) as f32, (fy - y0) as f32);
            let px = |dx: i64, dy: i64| {
                let xx = (x0 as i64 + dx).clamp(0, w - 1) as u32;
                let yy = (y0 as i64 + dy).clamp(0, h - 1) as u32;
                img.get_pixel(xx, yy).0
            };
            let q = [px(0, 0), px(1, 0), px(0, 1), px(1, 1)];
            let near = q[(ay >= 0.5) as usize * 2 + (ax >= 0.5) as usize];
            if near.contains(&255) {
                clipped += 1;
            }
            for (c, v) in vals.iter_mut().enumerate() {
                let top = q[0][c] as f32 * (1.0 - ax) + q[1][c] as f32 * ax;
                let bot = q[2][c] as f32 * (1.0 - ax) + q[3][c] as f32 * ax;
                v.push(colour::decode((top * (1.0 - ay) + bot * ay) / 255.0));
            }
        }
    }
    let linear = [0, 1, 2].map(|c| trimmed_mean(&mut vals[c]));
    let side = |a: [f32; 2], b: [f32; 2]| {
        let (p, q) = (loc.to_pixel(a), loc.to_pixel(b));
        (p[0] - q[0]).hypot(p[1] - q[1])
    };
    let [cx, cy] = p.centre_mm;
    let size_px = side([cx - s / 2.0, cy], [cx + s / 2.0, cy])
        .min(side([cx, cy - s / 2.0], [cx, cy + s / 2.0]));
    PatchReading {
        linear,
        clipped: clipped as f32 / (g * g) as f32,
        size_px,
    }
}

/// The mean of the values left when a fifth is dropped at each end.
fn trimmed_mean(v: &mut [f32]) -> f32 {
    v.sort_by(f32::total_cmp);
    let k = v.len() / 5;
    let kept = &v[k..v.len() - k];
    kept.iter().sum::<f32>() / kept.len().max(1) as f32
}

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    if saa <= 0.0 || sbb <= 0.0 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::super::chart::{ChartSpec, Ink};
    use super::super::PrinterKind;
    use super::*;

    fn chart() -> Chart {
        Chart::new(&ChartSpec {
            kind: PrinterKind::Paper,
            patches: 96,
            seed: 5,
            checker_pitch_mm: 13.0,
            filaments: vec![],
        })
        .unwrap()
    }

    /// The page drawn flat and straight, as a scanner would see it.
    fn flat(c: &Chart, w: u32, h: u32) -> RgbImage {
        c.draw(w, h, &|ink| match ink {
            Ink::Paper => [235; 3],
            Ink::Black | Ink::CheckerFrame => [20; 3],
            Ink::Patch(i) => colour::to_rgb8(c.srgb(i)),
        })
    }

    #[test]
    fn the_four_markers_and_nothing_else_are_found_on_a_flat_page() {
        let c = chart();
        for (w, h) in [(1188, 840), (594, 420)] {
            let img = flat(&c, w, h);
            let m = find_markers(&img);
            assert_eq!(m.len(), 4, "{w}x{h}: {m:?}");
            let loc = locate(&img, &c, &m, None).unwrap();
            let s = w as f64 / 297.0;
            for (got, want) in loc.markers_px.iter().zip(c.fiducials.centres_mm) {
                let e = (got[0] - want[0] as f64 * s).hypot(got[1] - want[1] as f64 * s);
                assert!(e < 0.6, "{w}: marker off by {e} px");
            }
            assert!(loc.match_r > 0.95, "{}", loc.match_r);
            // Every patch reads as drawn.
            for (i, p) in c.patches.iter().enumerate() {
                let r = read_patch(&img, &loc, p, 7);
                let got = r.linear.map(colour::encode);
                let want = c.srgb(i);
                assert!(
                    (0..3).all(|k| (got[k] - want[k]).abs() < 0.01),
                    "{i}: {got:?} {want:?}"
                );
            }
        }
    }

    #[test]
    fn a_page_upside_down_is_read_the_right_way_round() {
        let c = chart();
        let img = image::imageops::rotate180(&flat(&c, 891, 630));
        let m = find_markers(&img);
        let loc = locate(&img, &c, &m, None).unwrap();
        let s = 891.0 / 297.0;
        let tl = loc.markers_px[0];
        let want = [891.0 - 15.0 * s, 630.0 - 15.0 * s];
        assert!(
            (tl[0] - want[0]).abs() < 1.0 && (tl[1] - want[1]).abs() < 1.0,
            "{tl:?}"
        );
    }

    #[test]
    fn trimmed_mean_ignores_the_outliers() {
        let mut v = vec![0.5; 8];
        v.extend([0.0, 1.0]);
        assert_eq!(trimmed_mean(&mut v), 0.5);
    }
}
