//! The anti-aliasing half of `cac bench render`: the error against time of 1, 4, 16 samples per
//! pixel against 64, on a 256² jeep under one plain bright condition (the other half, ray
//! throughput, is [`crate::render`]).

use crate::render::best_of;
use anyhow::Result;
use cac_core::report::Table;
use cac_render::camera::Viewpoint;
use cac_render::environment::{plan, Brightness, Condition, EnvConfig, Environment};
use cac_render::{RenderSettings, Renderer};

/// Anti-aliasing error against time on a 256² jeep: `(samples, seconds per frame, PSNR dB
/// against 64 samples)` for 1, 4, 16 and 64 samples, fastest of `repeats` (at most 3).
pub fn anti_aliasing(repeats: usize) -> Result<Vec<(usize, f64, f64)>> {
    let mut jeep = cac_scene::generate::jeep();
    jeep.normalise(0.0, None);
    let env = Environment::new(EnvConfig::default())?;
    let cond = Condition::plain(Viewpoint::new(35.0, 12.0, 1.6), Brightness::Bright);
    let render_at = |spp: usize| -> Result<(f64, Vec<[f32; 3]>)> {
        let r = Renderer::new(
            jeep.clone(),
            RenderSettings {
                width: 256,
                height: 256,
                samples: spp,
                ..Default::default()
            },
        )?;
        let atlas = r.scene.initial_atlas(r.settings.atlas_res);
        let (secs, img) = best_of(repeats.min(3), || {
            let plan = plan(&r, &env, &cond).expect("plan");
            plan.render_cpu(&atlas)
        });
        Ok((secs, img))
    };
    let (_, reference) = render_at(64)?;
    let mut out = vec![];
    for spp in [1usize, 4, 16, 64] {
        let (secs, img) = render_at(spp)?;
        out.push((spp, secs, psnr(&img, &reference)));
    }
    Ok(out)
}

/// The rows of `render_aa.csv`.
pub fn aa_table(rows: &[(usize, f64, f64)]) -> Table {
    let mut aa = Table::new(["samples", "ms_per_frame", "psnr_db_vs_64"]);
    for (spp, secs, psnr) in rows {
        aa.row([
            spp.to_string(),
            format!("{:.2}", secs * 1e3),
            format!("{psnr:.3}"),
        ]);
    }
    aa
}

/// Peak signal-to-noise ratio (dB) of `img` against `reference`, values in [0, 1].
fn psnr(img: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let mse: f64 = img
        .iter()
        .zip(reference)
        .flat_map(|(a, b)| (0..3).map(move |c| ((a[c] - b[c]) as f64).powi(2)))
        .sum::<f64>()
        / (img.len() * 3) as f64;
    if mse > 0.0 {
        10.0 * (1.0 / mse).log10()
    } else {
        f64::INFINITY
    }
}
