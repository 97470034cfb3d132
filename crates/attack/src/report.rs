//! What a person wants to look at in a run folder: a contact sheet of rendered views with the
//! learned camouflage (`views.png`) and the loss curve (`loss.png`, drawn with `plotters`).
//!
//! Plots are drawn by `cac::report::plot` (text only when a system font is found). Not here:
//! writing files (the run folder does, atomically: [`super::run`]).

use crate::iteration::IterationLog;
use anyhow::Result;
use burn::tensor::Device;
use cac_core::report::plot::{self, Plot, Series};
use cac_render::environment::street_views;
use cac_render::environment::{self, Brightness, Environment};
use cac_render::{self as render, Renderer};
use cac_scene::Texture;

/// Renders `atlas` in `n` street-level views (azimuths evenly around the object, alternating
/// bright and dark, distance ratio 1.5) and lays them out in a grid.
pub(crate) fn views_sheet(
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
    let (img, _) = environment::form(r, env, &conds, render::atlas_tensor(atlas, device))?;
    Ok(render::contact_sheet(&render::to_images(&img)))
}

/// The per-iteration loss (thin) and its moving average over 10 iterations (bold), `w × h` px.
pub(crate) fn loss_plot(
    log: &[IterationLog],
    title: &str,
    w: u32,
    h: u32,
) -> Result<image::RgbImage> {
    let pts: Vec<(f64, f64)> = log
        .iter()
        .filter(|l| l.loss.is_finite())
        .map(|l| (l.iteration as f64, l.loss))
        .collect();
    let avg: Vec<(f64, f64)> = (0..pts.len())
        .map(|i| {
            let s = &pts[i.saturating_sub(9)..=i];
            (
                pts[i].0,
                s.iter().map(|p| p.1).sum::<f64>() / s.len() as f64,
            )
        })
        .collect();
    let x1 = pts.last().map_or(1.0, |p| p.0).max(1.0);
    plot::xy(
        &Plot::new(title, "iteration", "loss")
            .x_range(0.0, x1)
            .size(w, h),
        &[
            Series::new("", pts).color((150, 170, 220)).line(1),
            Series::new("", avg).color((0, 0, 255)).line(2),
        ],
    )
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
                atlas_min: 0.0,
                atlas_max: 1.0,
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
