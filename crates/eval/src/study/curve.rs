//! The protocol's judge of a training run (`cac train --eval-every`): the texture as it stands,
//! scored as `cac eval` scores it on a seeded subset of the protocol's views.
//!
//! A [`CurveSpec`] says how often and on which views: FV and RV × bright and dark,
//! `views_per_level` each, drawn with a seed the training never uses, rendered as `cac eval`
//! renders (512², 4 samples per pixel, the protocol's environment, the run's object) and scored
//! by the protocol's models. [`Curve`] binds it to a run and makes the points
//! ([`cac_attack::curve::Judge`]).

use crate::run::{all_views, evaluate_texture_in, view_groups, ViewGroup, ViewPlan};
use crate::summary::{figures, sel};
use crate::Protocol;
use anyhow::Result;
use burn::tensor::Device;
use cac_attack::curve::{CurveFigures, CurvePoint, Judge};
use cac_detect::Detector;
use cac_render::config::SceneConfig;
use cac_render::environment::{Environment, ViewpointSet};
use cac_render::{RenderSettings, Renderer};
use cac_scene::Texture;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// How the curve is taken.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CurveSpec {
    /// Score every this many seconds of training (the first point at 0 s, the last at the end).
    pub every_s: f64,
    /// Protocol views per brightness level and viewpoint set (four groups).
    pub views_per_level: usize,
    /// Seed of the views: 7, the development seed (the protocol's judging seeds are 31 and
    /// 1234; the training draws its own views from the run seed).
    pub seed: u64,
    /// The protocol's models: the source and an unseen one.
    pub models: Vec<String>,
}

impl Default for CurveSpec {
    fn default() -> Self {
        CurveSpec {
            every_s: 60.0,
            views_per_level: 16,
            seed: 7,
            models: vec!["nanodet".into(), "centernet".into()],
        }
    }
}

/// A curve bound to a run: the protocol's renderer, views, models and classes.
pub struct Curve<'a> {
    pub spec: CurveSpec,
    renderer: Renderer,
    env: Environment,
    groups: Vec<ViewGroup>,
    detectors: Vec<&'a dyn Detector>,
    protocol: Protocol,
    device: Device,
}

impl<'a> Curve<'a> {
    /// The curve of a run on `scene` (its object and atlas side; rendered and lit as the
    /// protocol's, [`SceneConfig::default`]) against `detectors` (the spec's models, loaded on
    /// the inference `device`), for the attack's `target` (none: hide mode).
    pub fn new(
        spec: CurveSpec,
        scene: &SceneConfig,
        detectors: Vec<&'a dyn Detector>,
        target: Option<&str>,
        device: Device,
    ) -> Result<Self> {
        anyhow::ensure!(
            spec.every_s > 0.0 && spec.every_s.is_finite(),
            "--eval-every must be a positive number of seconds, got {}",
            spec.every_s
        );
        anyhow::ensure!(
            (1..=1000).contains(&spec.views_per_level),
            "--eval-views must be 1..=1000, got {}",
            spec.views_per_level
        );
        let protocol_scene = SceneConfig {
            object: scene.object.clone(),
            render: RenderSettings {
                atlas_res: scene.render.atlas_res,
                ..SceneConfig::default().render
            },
            ..SceneConfig::default()
        };
        let stage = protocol_scene.stage()?;
        let plan = ViewPlan {
            views_per_level: spec.views_per_level,
            seed: spec.seed,
            ..Default::default()
        };
        Ok(Curve {
            groups: view_groups(&stage.env, &plan),
            spec,
            renderer: stage.renderer,
            env: stage.env,
            detectors,
            protocol: Protocol::from_labels("car,truck", target)?,
            device,
        })
    }
}

impl Judge for Curve<'_> {
    fn every_s(&self) -> f64 {
        self.spec.every_s
    }

    /// Scores `atlas` (resized to the run's atlas side where it differs) after `iteration`
    /// iterations and `train_s` seconds of training.
    fn score(&self, atlas: &Texture, iteration: usize, train_s: f64) -> Result<CurvePoint> {
        let t = Instant::now();
        let res = self.renderer.settings.atlas_res;
        let resized;
        let atlas = if (atlas.width, atlas.height) == (res, res) {
            atlas
        } else {
            resized = atlas.resized(res, res);
            &resized
        };
        let views = all_views(&self.groups);
        let result = evaluate_texture_in(
            &self.renderer,
            &self.env,
            &self.groups,
            &views,
            "texture",
            atlas,
            &self.detectors,
            &self.protocol,
            0,
            &self.device,
            &mut || {},
        )?;
        let mut out = vec![];
        for d in &self.detectors {
            for (set, name) in [(ViewpointSet::Free, "FV"), (ViewpointSet::Restricted, "RV")] {
                let f = figures(&result.records, sel("texture", d.name(), Some(set), None));
                out.push(CurveFigures {
                    model: d.name().to_string(),
                    set: name.into(),
                    p_at_05: f.p_at_05,
                    targeted_success: f.targeted_success,
                    images: f.images,
                });
            }
        }
        Ok(CurvePoint {
            iteration,
            train_s,
            score_s: t.elapsed().as_secs_f64(),
            figures: out,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_interval_or_view_count_is_refused() {
        let scene = SceneConfig::training();
        for (every_s, views) in [(0.0, 16), (f64::NAN, 16), (60.0, 0)] {
            let spec = CurveSpec {
                every_s,
                views_per_level: views,
                ..Default::default()
            };
            let dev = Device::from(burn::backend::FlexDevice);
            let e = Curve::new(spec, &scene, vec![], Some("person"), dev)
                .err()
                .expect("refused");
            assert!(e.to_string().contains("--eval-"), "{e}");
        }
    }
}
