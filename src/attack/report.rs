//! What a person wants to look at in a run folder: a contact sheet of rendered views with the
//! learned camouflage (`views.png`) and the loss curve (`loss.png`, drawn with `plotters`).
//!
//! The plot's text needs a TrueType font; one is looked up among common system font files and,
//! when none is found, the curve is drawn with its axes and grid but without labels (never an
//! error). Not here: writing files (the CLI does, atomically).

use super::IterationLog;
use crate::environment::{self, Brightness, Environment};
use crate::eval::street_views;
use crate::render::{self, Renderer};
use crate::scene::Texture;
use anyhow::{anyhow, Result};
use burn::tensor::Device;
use plotters::prelude::*;
use std::sync::OnceLock;

/// Renders `atlas` in `n` street-level views (azimuths evenly around the object, alternating
/// bright and dark, distance ratio 1.5) and lays them out in a grid.
pub fn views_sheet(
    r: &Renderer,
    env: &Environment,
    atlas: &Texture,
    n: usize,
    device: &Device,
) -> Result<image::RgbImage> {
    let n = n.max(1);
    let mut conds = street_views(n, 1.5, Brightness::Bright);
    for (k, c) in conds.iter_mut().enumerate() {
        if k % 2 == 1 {
            c.brightness = Brightness::Dark;
        }
    }
    let plans = conds
        .iter()
        .map(|c| r.plan(&c.viewpoint, &env.lighting(c), &env.backdrop(c)))
        .collect::<Result<Vec<_>>>()?;
    let a = render::atlas_tensor(atlas, device);
    let img = environment::photometric(
        render::composite(&plans, environment::print_error(a, &conds)),
        &conds,
    );
    Ok(render::contact_sheet(&render::to_images(&img)))
}

/// Registers a system sans-serif font with plotters once; false when none was found.
fn font() -> bool {
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

/// The per-iteration loss (thin) and its moving average over 10 iterations (bold), `w × h` px.
pub fn loss_plot(log: &[IterationLog], title: &str, w: u32, h: u32) -> Result<image::RgbImage> {
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let e = |e: DrawingAreaErrorKind<_>| anyhow!("cannot draw the loss plot: {e:?}");
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        let pts: Vec<(f64, f64)> = log
            .iter()
            .filter(|l| l.loss.is_finite())
            .map(|l| (l.iteration as f64, l.loss))
            .collect();
        let (x1, (y0, y1)) = if pts.is_empty() {
            (1.0, (0.0, 1.0))
        } else {
            let lo = pts.iter().map(|p| p.1).fold(f64::MAX, f64::min);
            let hi = pts.iter().map(|p| p.1).fold(f64::MIN, f64::max);
            let pad = ((hi - lo) * 0.05).max(1e-6);
            (
                pts.last().map_or(1.0, |p| p.0).max(1.0),
                (lo - pad, hi + pad),
            )
        };
        let text = font();
        let mut b = ChartBuilder::on(&root);
        b.margin(12);
        if text {
            b.caption(title, ("sans-serif", 18))
                .x_label_area_size(36)
                .y_label_area_size(56);
        }
        let mut chart = b.build_cartesian_2d(0.0..x1, y0..y1).map_err(e)?;
        let mut mesh = chart.configure_mesh();
        if text {
            mesh.x_desc("iteration").y_desc("loss");
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw().map_err(e)?;
        chart
            .draw_series(LineSeries::new(
                pts.iter().copied(),
                RGBColor(150, 170, 220),
            ))
            .map_err(e)?;
        let avg: Vec<(f64, f64)> = (0..pts.len())
            .map(|i| {
                let s = &pts[i.saturating_sub(9)..=i];
                (
                    pts[i].0,
                    s.iter().map(|p| p.1).sum::<f64>() / s.len() as f64,
                )
            })
            .collect();
        chart
            .draw_series(LineSeries::new(avg, BLUE.stroke_width(2)))
            .map_err(e)?;
        root.present().map_err(e)?;
    }
    image::RgbImage::from_raw(w, h, buf).ok_or_else(|| anyhow!("loss plot buffer size"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loss_plot_draws_a_curve() {
        let log: Vec<IterationLog> = (0..30)
            .map(|i| IterationLog {
                iteration: i,
                loss: 5.0 - 0.1 * i as f64,
                grad_norm: 1.0,
                proposals: 1,
                ms_render: 0.0,
                ms_forward: 0.0,
                ms_backward: 0.0,
                ms_optimiser: 0.0,
            })
            .collect();
        let img = loss_plot(&log, "test", 320, 200).unwrap();
        let blue = img
            .pixels()
            .filter(|p| p[2] > 200 && p[0] < 60 && p[1] < 60)
            .count();
        assert!(
            blue > 100,
            "the averaged curve is missing ({blue} blue pixels)"
        );
        assert!(loss_plot(&[], "empty", 100, 80).is_ok());
    }
}
