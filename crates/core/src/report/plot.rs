//! Plots drawn to RGB images with `plotters`: [`xy`] (lines with markers and optional ± error
//! bars, e.g. P@0.5 ± std against distance ratio) and [`polar`] (a value against azimuth, 0° =
//! front at the top, clockwise as seen from above).
//!
//! Text needs a TrueType font; one is looked up among common system font files ([`font`]) and,
//! when none is found, plots are drawn with their lines and grid but without text (never an error).

use anyhow::{anyhow, Result};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::sync::OnceLock;

/// Series colours, in order (a series may override its own).
pub const PALETTE: [(u8, u8, u8); 8] = [
    (31, 119, 180),
    (214, 39, 40),
    (44, 160, 44),
    (255, 127, 14),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
];

/// Registers a system sans-serif font with plotters once; false when none was found.
pub fn font() -> bool {
    static FONT: OnceLock<bool> = OnceLock::new();
    *FONT.get_or_init(|| {
        const PATHS: [&str; 5] = [
            "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/TTF/DejaVuSans.ttf",
            "/usr/share/fonts/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
            "/System/Library/Fonts/Supplemental/Arial.ttf",
        ];
        PATHS
            .iter()
            .find_map(|p| std::fs::read(p).ok())
            .is_some_and(|bytes| {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok()
            })
    })
}

/// A plot's frame: title, axis labels, ranges (None = fit the data) and size in pixels.
#[derive(Clone, Debug)]
pub struct Plot {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub x_range: Option<(f64, f64)>,
    /// For [`polar`], the radius range (`.1` is the outer ring).
    pub y_range: Option<(f64, f64)>,
    pub width: u32,
    pub height: u32,
}

impl Plot {
    /// A 640 × 400 plot fitted to its data.
    pub fn new(title: &str, x_label: &str, y_label: &str) -> Self {
        Plot {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            x_range: None,
            y_range: None,
            width: 640,
            height: 400,
        }
    }
    pub fn x_range(mut self, lo: f64, hi: f64) -> Self {
        self.x_range = Some((lo, hi));
        self
    }
    pub fn y_range(mut self, lo: f64, hi: f64) -> Self {
        self.y_range = Some((lo, hi));
        self
    }
    pub fn size(mut self, width: u32, height: u32) -> Self {
        (self.width, self.height) = (width.max(16), height.max(16));
        self
    }
}

/// One named curve. `err` (empty = none) holds a ± half-height per point for error bars.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub err: Vec<f64>,
    pub color: Option<(u8, u8, u8)>,
    pub stroke: u32,
    pub markers: bool,
}

impl Series {
    /// A 2-px line with point markers, coloured from [`PALETTE`] by its position.
    pub fn new(label: &str, points: Vec<(f64, f64)>) -> Self {
        Series {
            label: label.into(),
            points,
            err: vec![],
            color: None,
            stroke: 2,
            markers: true,
        }
    }
    pub fn err(mut self, err: Vec<f64>) -> Self {
        self.err = err;
        self
    }
    pub fn color(mut self, rgb: (u8, u8, u8)) -> Self {
        self.color = Some(rgb);
        self
    }
    /// Line width in pixels, without markers (e.g. a thin raw curve under a bold average).
    pub fn line(mut self, stroke: u32) -> Self {
        (self.stroke, self.markers) = (stroke, false);
        self
    }
    fn rgb(&self, k: usize) -> RGBColor {
        let (r, g, b) = self.color.unwrap_or(PALETTE[k % PALETTE.len()]);
        RGBColor(r, g, b)
    }
}

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("cannot draw the plot: {e:?}")
}

fn fit(vals: impl Iterator<Item = f64>, fixed: Option<(f64, f64)>) -> (f64, f64) {
    if let Some(r) = fixed {
        return r;
    }
    let (lo, hi) = vals
        .filter(|v| v.is_finite())
        .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v), b.max(v)));
    if lo > hi {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-6 * hi.abs().max(1.0));
    (lo - pad, hi + pad)
}

fn finish(buf: Vec<u8>, w: u32, h: u32) -> Result<image::RgbImage> {
    image::RgbImage::from_raw(w, h, buf).ok_or_else(|| anyhow!("plot buffer size"))
}

/// The chart both plots draw on: f64 cartesian coordinates on an RGB buffer.
type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// One series' line through `pts` (already in chart coordinates) in colour `c`, its legend
/// entry where there is text and a label, and its markers where asked.
fn draw_line(
    chart: &mut Chart,
    s: &Series,
    c: RGBColor,
    pts: &[(f64, f64)],
    text: bool,
) -> Result<()> {
    let drawn = chart
        .draw_series(LineSeries::new(
            pts.iter().copied(),
            c.stroke_width(s.stroke),
        ))
        .map_err(err)?;
    if text && !s.label.is_empty() {
        let st = c.stroke_width(2);
        drawn
            .label(&s.label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], st));
    }
    if s.markers {
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
            .map_err(err)?;
    }
    Ok(())
}

/// The legend box, where any series has a label (at plotters' default place, or `at`).
fn draw_legend<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    series: &[Series],
    at: Option<SeriesLabelPosition>,
) -> Result<()> {
    if !series.iter().any(|s| !s.label.is_empty()) {
        return Ok(());
    }
    let mut labels = chart.configure_series_labels();
    if let Some(at) = at {
        labels.position(at);
    }
    labels
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(err)
}

/// Lines (with markers and error bars where given) on cartesian axes; a legend when a font is
/// available and any series has a label.
pub fn xy(p: &Plot, series: &[Series]) -> Result<image::RgbImage> {
    let (w, h) = (p.width, p.height);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let all = || series.iter().flat_map(|s| s.points.iter());
        let xr = fit(all().map(|p| p.0), p.x_range);
        let yr = fit(
            series.iter().flat_map(|s| {
                s.points.iter().enumerate().flat_map(|(i, p)| {
                    let e = s.err.get(i).copied().unwrap_or(0.0);
                    [p.1 - e, p.1 + e]
                })
            }),
            p.y_range,
        );
        let text = font();
        let mut b = ChartBuilder::on(&root);
        b.margin(12);
        if text {
            b.caption(&p.title, ("sans-serif", 18))
                .x_label_area_size(36)
                .y_label_area_size(56);
        }
        let mut chart = b.build_cartesian_2d(xr.0..xr.1, yr.0..yr.1).map_err(err)?;
        let mut mesh = chart.configure_mesh();
        if text {
            mesh.x_desc(&p.x_label).y_desc(&p.y_label);
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw().map_err(err)?;
        for (k, s) in series.iter().enumerate() {
            let c = s.rgb(k);
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .copied()
                .filter(|p| p.1.is_finite())
                .collect();
            draw_line(&mut chart, s, c, &pts, text)?;
            let cap = (xr.1 - xr.0) * 0.008;
            for (i, &(x, y)) in s.points.iter().enumerate() {
                let Some(&e) = s.err.get(i) else { break };
                if !(e > 0.0 && y.is_finite()) {
                    continue;
                }
                let st = c.stroke_width(1);
                chart
                    .draw_series([
                        PathElement::new([(x, y - e), (x, y + e)], st),
                        PathElement::new([(x - cap, y - e), (x + cap, y - e)], st),
                        PathElement::new([(x - cap, y + e), (x + cap, y + e)], st),
                    ])
                    .map_err(err)?;
            }
        }
        if text {
            draw_legend(&mut chart, series, None)?;
        }
        root.present().map_err(err)?;
    }
    finish(buf, w, h)
}

/// Pixel-free polar coordinates: azimuth `az` (degrees, 0 at the top, clockwise) and radius `r`.
fn polar_xy(az: f64, r: f64) -> (f64, f64) {
    let t = az.to_radians();
    (r * t.sin(), r * t.cos())
}

/// A value against azimuth: each series' points are `(azimuth °, value)`, drawn as a line
/// through them in order (repeat the first point to close the curve) with markers. Rings show
/// the radius (`p.y_range`, default 0 to the largest value), spokes every 30°.
pub fn polar(p: &Plot, series: &[Series]) -> Result<image::RgbImage> {
    let (w, h) = (p.width, p.height);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let (r0, r1) = p.y_range.unwrap_or_else(|| {
            let m = series
                .iter()
                .flat_map(|s| s.points.iter().map(|p| p.1))
                .filter(|v| v.is_finite())
                .fold(0.0, f64::max);
            (0.0, if m > 0.0 { m } else { 1.0 })
        });
        let span = (r1 - r0).max(1e-9);
        let rad = |v: f64| ((v - r0) / span).clamp(0.0, 1.0);
        let text = font();
        let mut b = ChartBuilder::on(&root);
        b.margin(10);
        if text {
            b.caption(&p.title, ("sans-serif", 18));
        }
        let aspect = w as f64 / h.max(1) as f64;
        let (ex, ey) = if aspect >= 1.0 {
            (1.2 * aspect, 1.2)
        } else {
            (1.2, 1.2 / aspect)
        };
        let mut chart = b.build_cartesian_2d(-ex..ex, -ey..ey).map_err(err)?;
        let grey = RGBColor(200, 200, 200);
        for k in 1..=4 {
            let r = k as f64 / 4.0;
            chart
                .draw_series(LineSeries::new(
                    (0..=120).map(|i| polar_xy(i as f64 * 3.0, r)),
                    grey.stroke_width(1),
                ))
                .map_err(err)?;
            if text {
                let lbl = format!("{:.2}", r0 + span * r);
                chart
                    .draw_series([Text::new(lbl, polar_xy(15.0, r), ("sans-serif", 11))])
                    .map_err(err)?;
            }
        }
        for k in 0..12 {
            let az = k as f64 * 30.0;
            chart
                .draw_series([PathElement::new([(0.0, 0.0), polar_xy(az, 1.0)], grey)])
                .map_err(err)?;
            if text {
                let (x, y) = polar_xy(az, 1.1);
                let style = TextStyle::from(("sans-serif", 12).into_font())
                    .pos(Pos::new(HPos::Center, VPos::Center));
                chart
                    .draw_series([Text::new(format!("{az:.0}°"), (x, y), style)])
                    .map_err(err)?;
            }
        }
        for (k, s) in series.iter().enumerate() {
            let c = s.rgb(k);
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .filter(|p| p.1.is_finite())
                .map(|&(az, v)| polar_xy(az, rad(v)))
                .collect();
            draw_line(&mut chart, s, c, &pts, text)?;
        }
        if text {
            draw_legend(&mut chart, series, Some(SeriesLabelPosition::UpperRight))?;
        }
        if text {
            root.draw(&Text::new(
                p.y_label.clone(),
                (8, h as i32 - 20),
                ("sans-serif", 13),
            ))
            .map_err(err)?;
        }
        root.present().map_err(err)?;
    }
    finish(buf, w, h)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn count(img: &image::RgbImage, c: (u8, u8, u8)) -> usize {
        img.pixels()
            .filter(|p| p[0] == c.0 && p[1] == c.1 && p[2] == c.2)
            .count()
    }

    #[test]
    fn xy_draws_series_and_error_bars_in_their_colours() {
        let red = (230, 0, 0);
        let pts: Vec<(f64, f64)> = (0..6).map(|i| (i as f64, 0.5 + 0.05 * i as f64)).collect();
        let plain = xy(
            &Plot::new("t", "x", "y").y_range(0.0, 1.0),
            &[Series::new("a", pts.clone()).color(red)],
        )
        .unwrap();
        let with_err = xy(
            &Plot::new("t", "x", "y").y_range(0.0, 1.0),
            &[Series::new("a", pts).color(red).err(vec![0.2; 6])],
        )
        .unwrap();
        assert_eq!(plain.dimensions(), (640, 400));
        let (a, b) = (count(&plain, red), count(&with_err, red));
        assert!(a > 300, "the curve is missing ({a} px)");
        // Six bars 0.4 high on a ~330 px tall y axis of range 1: well over 6 * 100 px more.
        assert!(b > a + 500, "the error bars are missing ({a} -> {b} px)");
        assert!(xy(&Plot::new("empty", "x", "y"), &[]).is_ok());
    }

    #[test]
    fn polar_puts_a_value_at_its_azimuth() {
        let blue = (0, 0, 230);
        // One point at azimuth 90 (right of centre) with the full radius.
        let img = polar(
            &Plot::new("p", "", "P@0.5").size(400, 400).y_range(0.0, 1.0),
            &[Series::new("", vec![(90.0, 1.0), (90.0, 1.0)]).color(blue)],
        )
        .unwrap();
        let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
        for (x, y, p) in img.enumerate_pixels() {
            if (p[0], p[1], p[2]) == blue {
                (sx, sy, n) = (sx + x as f64, sy + y as f64, n + 1.0);
            }
        }
        assert!(n > 10.0, "the marker is missing");
        let (cx, cy) = (sx / n, sy / n);
        assert!(
            cx > 300.0 && (cy - 200.0).abs() < 30.0,
            "marker at ({cx}, {cy})"
        );
    }
}
