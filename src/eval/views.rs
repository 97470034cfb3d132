//! Scores a texture in a set of rendered views: render (with the views' environment), detect with
//! each model, compare with the ground-truth boxes from the object mask.

use super::{score_image, ImageScore, Protocol};
use crate::detect::{Detection, Detector};
use crate::environment::{self, Brightness, Condition, Environment};
use crate::render::{self, Renderer, Viewpoint};
use crate::scene::Texture;
use anyhow::{Context, Result};
use burn::tensor::Device;

/// Street-level views: `n` azimuths evenly around the object, elevations cycling through
/// 5–15°, at one distance ratio, plain photometrics.
pub fn street_views(n: usize, distance_ratio: f32, brightness: Brightness) -> Vec<Condition> {
    (0..n)
        .map(|k| {
            let az = 360.0 * k as f32 / n as f32 + 7.5;
            let el = 5.0 + 10.0 * ((k * 7) % n) as f32 / (n.max(2) - 1) as f32;
            Condition::plain(Viewpoint::new(az, el, distance_ratio), brightness)
        })
        .collect()
}

/// The outcome of one texture in a set of views.
pub struct ViewResults {
    /// Per model, per view.
    pub scores: Vec<Vec<ImageScore>>,
    pub detections: Vec<Vec<Vec<Detection>>>,
    pub images: Vec<image::RgbImage>,
}

/// Renders `atlas` in every condition and scores each model. Views where the object is not
/// visible at all are an error (the protocol needs a ground-truth box).
pub fn evaluate(
    r: &Renderer,
    env: &Environment,
    conds: &[Condition],
    atlas: &Texture,
    dets: &[&dyn Detector],
    p: &Protocol,
    device: &Device,
) -> Result<ViewResults> {
    let mut out = ViewResults {
        scores: vec![vec![]; dets.len()],
        detections: vec![vec![]; dets.len()],
        images: vec![],
    };
    for (i, c) in conds.iter().enumerate() {
        let plan = r.plan(&c.viewpoint, &env.lighting(c), &env.backdrop(c))?;
        let gt = plan
            .object_box
            .with_context(|| format!("view {i}: the object is not visible"))?;
        let a = render::atlas_tensor(atlas, device);
        let img = environment::photometric(
            render::composite(
                &[plan],
                environment::print_error(a, std::slice::from_ref(c)),
            ),
            std::slice::from_ref(c),
        );
        for (m, d) in dets.iter().enumerate() {
            let found = d
                .detect(img.clone())?
                .into_iter()
                .next()
                .unwrap_or_default();
            out.scores[m].push(score_image(&found, &gt, p));
            out.detections[m].push(found);
        }
        out.images.extend(render::to_images(&img));
    }
    Ok(out)
}
