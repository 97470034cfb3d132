//! The one image-formation call: a condition's geometry and lighting go to the renderer (one
//! [`RenderPlan`] per view, ray-cast once), its photometric part acts on tensors so gradients
//! pass: print error on the atlas, composite, then lighten/darken and sensor noise on the images.
//!
//! Training, evaluation, the run folder's views, the digital twins and `cac render` all form
//! their images here, so they see the same pictures of the same texture. Not here: the
//! transforms themselves ([`super::print_error`], [`super::photometric`]) or the renderer.

use super::{photometric, print_error, Condition, Environment};
use crate::composite as render;
use crate::renderer::Renderer;
use crate::shade::RenderPlan;
use anyhow::Result;
use burn::tensor::Tensor;

/// The render plan of one condition (its viewpoint, lighting and backdrop).
pub fn plan(r: &Renderer, env: &Environment, c: &Condition) -> Result<RenderPlan> {
    r.plan(&c.viewpoint, &env.lighting(c), &env.backdrop(c))
}

/// The render plans of `conds`, in order.
pub fn plans(r: &Renderer, env: &Environment, conds: &[Condition]) -> Result<Vec<RenderPlan>> {
    conds.iter().map(|c| plan(r, env, c)).collect()
}

/// The images `[V, 3, H, W]` of `atlas` (`[1, R, R, 3]`) under `conds`, one plan per condition:
/// `photometric(composite(plans, print_error(atlas)))`, differentiable in the atlas.
pub fn form_planned(plans: &[RenderPlan], atlas: Tensor<4>, conds: &[Condition]) -> Tensor<4> {
    photometric(render::composite(plans, print_error(atlas, conds)), conds)
}

/// Plans `conds` and forms their images of `atlas`; returns the images and the plans (whose
/// `object_box` is each image's ground truth).
pub fn form(
    r: &Renderer,
    env: &Environment,
    conds: &[Condition],
    atlas: Tensor<4>,
) -> Result<(Tensor<4>, Vec<RenderPlan>)> {
    let plans = plans(r, env, conds)?;
    Ok((form_planned(&plans, atlas, conds), plans))
}

/// The 8-bit images of `atlas` under each of `conds`, formed one view at a time (`cac render`'s
/// single views and contact sheets).
pub fn form_images(
    r: &Renderer,
    env: &Environment,
    conds: &[Condition],
    atlas: &cac_scene::Texture,
    dev: &burn::tensor::Device,
) -> Result<Vec<image::RgbImage>> {
    let mut out = Vec::new();
    for c in conds {
        let t = render::atlas_tensor(atlas, dev);
        let (img, _) = form(r, env, std::slice::from_ref(c), t)?;
        out.extend(render::to_images(&img));
    }
    Ok(out)
}
