//! The evaluation protocol's views and its per-image records.
//!
//! Views come in groups, one per viewpoint set (free FV, restricted RV) and brightness level
//! (bright L_b, dark L_d): `views_per_level` conditions per group drawn from the environment with
//! a seed derived from the run seed and the group, so every texture is seen in exactly the same
//! views (a paired comparison) and a rerun reproduces them. Each image is rendered once and scored
//! by every model (the scoring core, [`super::score`]); the result is one [`ImageRecord`] per image and model.

use super::{ImageScore, Protocol, Scorer};
use anyhow::Result;
use burn::tensor::Device;
use cac_detect::{Detection, Detector};
use cac_render::environment::{self, Brightness, Condition, Environment, ViewpointSet};
use cac_render::{self as render, Renderer};
use cac_scene::Texture;
use serde::{Deserialize, Serialize};

/// How many views, which groups, which seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewPlan {
    /// Views per brightness level in each viewpoint set (the paper: 200).
    pub views_per_level: usize,
    pub seed: u64,
    pub sets: Vec<ViewpointSet>,
    pub levels: Vec<Brightness>,
}

impl Default for ViewPlan {
    fn default() -> Self {
        ViewPlan {
            views_per_level: 200,
            seed: 0,
            sets: vec![ViewpointSet::Free, ViewpointSet::Restricted],
            levels: vec![Brightness::Bright, Brightness::Dark],
        }
    }
}

/// Short names used in tables and files: FV/RV, L_b/L_d.
pub(crate) fn set_name(s: ViewpointSet) -> &'static str {
    match s {
        ViewpointSet::Free => "FV",
        ViewpointSet::Restricted => "RV",
    }
}
pub(crate) fn level_name(b: Brightness) -> &'static str {
    match b {
        Brightness::Bright => "L_b",
        Brightness::Dark => "L_d",
    }
}

/// One group of views: a viewpoint set at one brightness level.
#[derive(Clone, Debug)]
pub struct ViewGroup {
    pub set: ViewpointSet,
    pub brightness: Brightness,
    pub conditions: Vec<Condition>,
}

/// The plan's view groups, drawn from `env` (same plan and environment, same views).
pub(crate) fn view_groups(env: &Environment, plan: &ViewPlan) -> Vec<ViewGroup> {
    let mut out = vec![];
    for &set in &plan.sets {
        for &b in &plan.levels {
            let salt = match (set, b) {
                (ViewpointSet::Free, Brightness::Bright) => 0x11,
                (ViewpointSet::Free, Brightness::Dark) => 0x12,
                (ViewpointSet::Restricted, Brightness::Bright) => 0x21,
                (ViewpointSet::Restricted, Brightness::Dark) => 0x22,
            };
            let seed = plan.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ salt;
            out.push(ViewGroup {
                set,
                brightness: b,
                conditions: env.sample_n(plan.views_per_level, set, b, seed),
            });
        }
    }
    out
}

/// One image scored by one model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageRecord {
    pub texture: String,
    pub model: String,
    pub set: ViewpointSet,
    pub brightness: Brightness,
    /// Index of the view within its group.
    pub view: usize,
    pub azimuth_deg: f32,
    pub elevation_deg: f32,
    pub distance_ratio: f32,
    /// Ground-truth box (`x1, y1, x2, y2`, from the object mask).
    pub gt: [f32; 4],
    #[serde(flatten)]
    pub score: ImageScore,
}

/// An image kept for the report, with each model's detections.
pub struct Example {
    pub set: ViewpointSet,
    pub brightness: Brightness,
    pub view: usize,
    pub image: image::RgbImage,
    pub gt: [f32; 4],
    /// Per model, in the order of the detectors.
    pub detections: Vec<Vec<Detection>>,
}

/// One texture's outcome in all groups.
pub struct TextureResult {
    pub records: Vec<ImageRecord>,
    /// Views skipped because the object was not visible at all (no ground-truth box).
    pub skipped: usize,
    pub examples: Vec<Example>,
}

/// Every view of the plan as `(group index, view index)`, group by group: the seeded view list
/// that shards split (see [`super::shard`]).
pub(crate) fn all_views(groups: &[ViewGroup]) -> Vec<(usize, usize)> {
    groups
        .iter()
        .enumerate()
        .flat_map(|(g, grp)| (0..grp.conditions.len()).map(move |i| (g, i)))
        .collect()
}

/// Renders `atlas` in `views` (`(group index, view index)`, in that order; [`all_views`] for a
/// whole run), scores it with each detector, and keeps the first `examples_per_group` images of
/// each group. The records and examples of a part of the views are those a whole run has for
/// them. `progress` is called once per image.
#[allow(clippy::too_many_arguments)]
pub(crate) fn evaluate_texture_in(
    r: &Renderer,
    env: &Environment,
    groups: &[ViewGroup],
    views: &[(usize, usize)],
    texture: &str,
    atlas: &Texture,
    dets: &[&dyn Detector],
    p: &Protocol,
    examples_per_group: usize,
    device: &Device,
    progress: &mut dyn FnMut(),
) -> Result<TextureResult> {
    let mut out = TextureResult {
        records: vec![],
        skipped: 0,
        examples: vec![],
    };
    let a = render::atlas_tensor(atlas, device);
    let scorer = Scorer::new(dets, p)?;
    for &(gi, i) in views {
        let g = &groups[gi];
        let c = &g.conditions[i];
        {
            progress();
            let plan = environment::plan(r, env, c)?;
            let Some(gt) = plan.object_box else {
                out.skipped += 1;
                continue;
            };
            let img = environment::form_planned(&[plan], a.clone(), std::slice::from_ref(c));
            let v = &c.viewpoint;
            let mut per_model = vec![];
            for (d, o) in dets.iter().zip(scorer.frame(img.clone(), &gt, None)?) {
                out.records.push(ImageRecord {
                    texture: texture.to_string(),
                    model: d.name().to_string(),
                    set: g.set,
                    brightness: g.brightness,
                    view: i,
                    azimuth_deg: v.azimuth_deg.rem_euclid(360.0),
                    elevation_deg: v.elevation_deg,
                    distance_ratio: v.distance_ratio,
                    gt,
                    score: o.score,
                });
                per_model.push(o.detections);
            }
            if i < examples_per_group {
                out.examples.push(Example {
                    set: g.set,
                    brightness: g.brightness,
                    view: i,
                    image: render::to_images(&img).remove(0),
                    gt,
                    detections: per_model,
                });
            }
        }
    }
    Ok(out)
}
