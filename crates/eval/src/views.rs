//! Scores a texture in a set of rendered views: render (with the views' environment), detect with
//! each model, compare with the ground-truth boxes from the object mask.

use super::{ImageScore, Protocol, Scorer};
use anyhow::{Context, Result};
use burn::tensor::Device;
use cac_detect::{Detection, Detector};
use cac_render::environment::{self, Condition, Environment};
use cac_render::{self as render, Renderer};
use cac_scene::Texture;

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
    let scorer = Scorer::new(dets, p)?;
    for (i, c) in conds.iter().enumerate() {
        let plan = environment::plan(r, env, c)?;
        let gt = plan
            .object_box
            .with_context(|| format!("view {i}: the object is not visible"))?;
        let a = render::atlas_tensor(atlas, device);
        let img = environment::form_planned(&[plan], a, std::slice::from_ref(c));
        for (m, o) in scorer
            .frame(img.clone(), &gt, None)?
            .into_iter()
            .enumerate()
        {
            out.scores[m].push(o.score);
            out.detections[m].push(o.detections);
        }
        out.images.extend(render::to_images(&img));
    }
    Ok(out)
}
