//! The attack's quality against its run time: the texture as it stands, scored under the
//! evaluation protocol at fixed points of the training clock (`cac train --eval-every SECONDS`).
//!
//! A [`CurveSpec`] says how often and on which views: a seeded subset of the protocol's views
//! (FV and RV × bright and dark, `views_per_level` each, drawn with a seed the training never
//! uses), rendered as `cac eval` renders (512², 4 samples per pixel, the protocol's environment,
//! the run's object) and scored by the protocol's models. [`Curve`] binds it to a run; each
//! [`CurvePoint`] is the figures per model and viewpoint set at one iteration, with the training
//! seconds reached (scoring excluded: the run's clock stops while it scores) and the seconds the
//! scoring took. The run folder keeps the points in run.json and writes `curve.csv` and
//! `curve.png` ([`write`]). Not here: when to score (the run's loop, [`super::run`]).

use crate::eval::run::{all_views, evaluate_texture_in, view_groups, ViewGroup, ViewPlan};
use crate::eval::summary::{figures, sel};
use crate::eval::Protocol;
use anyhow::Result;
use burn::tensor::Device;
use cac_core::report::plot::{self, Plot, Series};
use cac_core::report::Table;
use cac_detect::Detector;
use cac_render::config::SceneConfig;
use cac_render::environment::{Environment, ViewpointSet};
use cac_render::{RenderSettings, Renderer};
use cac_scene::Texture;
use serde::{Deserialize, Serialize};
use std::path::Path;
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

/// One model's figures in one viewpoint set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CurveFigures {
    pub model: String,
    /// `FV` or `RV`.
    pub set: String,
    pub p_at_05: f64,
    pub targeted_success: f64,
    pub images: usize,
}

/// The texture scored at one point of the run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    /// Iterations done.
    pub iteration: usize,
    /// Seconds of training reached (the run's clock, scoring excluded).
    pub train_s: f64,
    /// Seconds this scoring took.
    pub score_s: f64,
    pub figures: Vec<CurveFigures>,
}

impl CurvePoint {
    /// The figures of `model` in `set`, if scored.
    pub fn get(&self, model: &str, set: &str) -> Option<&CurveFigures> {
        self.figures
            .iter()
            .find(|f| f.model == model && f.set == set)
    }

    /// A short line for progress: each model's P@0.5 and targeted success, FV / RV.
    pub fn brief(&self) -> String {
        let mut models: Vec<&str> = self.figures.iter().map(|f| f.model.as_str()).collect();
        models.dedup();
        let fv_rv = |m: &str, f: fn(&CurveFigures) -> f64| {
            let v = |s| self.get(m, s).map_or(f64::NAN, f);
            format!("{:.2}/{:.2}", v("FV"), v("RV"))
        };
        let parts: Vec<String> = models
            .iter()
            .map(|m| {
                format!(
                    "{m} P@0.5 {} target {}",
                    fv_rv(m, |f| f.p_at_05),
                    fv_rv(m, |f| f.targeted_success)
                )
            })
            .collect();
        format!(
            "at {:.0} s (iteration {}): {}",
            self.train_s,
            self.iteration,
            parts.join(", ")
        )
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

    /// Scores `atlas` (resized to the run's atlas side where it differs) after `iteration`
    /// iterations and `train_s` seconds of training.
    pub fn score(&self, atlas: &Texture, iteration: usize, train_s: f64) -> Result<CurvePoint> {
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

/// The points as a table: one row per point, model and set.
pub fn table(points: &[CurvePoint]) -> Table {
    let mut t = Table::new([
        "iteration",
        "train_s",
        "score_s",
        "model",
        "set",
        "images",
        "p_at_05",
        "targeted_success",
    ]);
    for p in points {
        for f in &p.figures {
            t.row([
                p.iteration.to_string(),
                format!("{:.1}", p.train_s),
                format!("{:.1}", p.score_s),
                f.model.clone(),
                f.set.clone(),
                f.images.to_string(),
                format!("{:.4}", f.p_at_05),
                format!("{:.4}", f.targeted_success),
            ]);
        }
    }
    t
}

/// P@0.5 (solid colours) and targeted success per model and set against training seconds,
/// `w × h` px.
pub fn plot(points: &[CurvePoint], w: u32, h: u32) -> Result<image::RgbImage> {
    let mut series = vec![];
    let Some(first) = points.first() else {
        return plot::xy(&Plot::new("no points", "s", "").size(w, h), &[]);
    };
    for f in &first.figures {
        let line = |what: &str, v: fn(&CurveFigures) -> f64| {
            let pts = points
                .iter()
                .filter_map(|p| p.get(&f.model, &f.set).map(|g| (p.train_s, v(g))))
                .collect();
            Series::new(&format!("{} {} {what}", f.model, f.set), pts)
        };
        series.push(line("P@0.5", |g| g.p_at_05));
        series.push(line("target", |g| g.targeted_success));
    }
    let x1 = points.last().map_or(1.0, |p| p.train_s).max(1.0);
    plot::xy(
        &Plot::new(
            "the texture under the protocol against training time",
            "training seconds (scoring excluded)",
            "share of views",
        )
        .x_range(0.0, x1)
        .y_range(0.0, 1.0)
        .size(w, h),
        &series,
    )
}

/// Writes `curve.csv` and `curve.png` into the run folder `dir`.
pub fn write(dir: &Path, points: &[CurvePoint]) -> Result<()> {
    cac_core::io::write_atomic(&dir.join("curve.csv"), table(points).csv().as_bytes())?;
    cac_core::io::save_png_atomic(&dir.join("curve.png"), &plot(points, 800, 500)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(i: usize, t: f64, nano_fv: f64) -> CurvePoint {
        let f = |m: &str, s: &str, p| CurveFigures {
            model: m.into(),
            set: s.into(),
            p_at_05: p,
            targeted_success: 1.0 - p,
            images: 32,
        };
        CurvePoint {
            iteration: i,
            train_s: t,
            score_s: 3.0,
            figures: vec![
                f("nanodet", "FV", nano_fv),
                f("nanodet", "RV", 0.5),
                f("centernet", "FV", 0.75),
                f("centernet", "RV", 0.25),
            ],
        }
    }

    #[test]
    fn the_table_has_a_row_per_point_model_and_set_and_the_brief_line_reads_each() {
        let pts = [point(0, 0.0, 0.75), point(120, 60.2, 0.125)];
        let csv = table(&pts).csv();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 1 + 8, "{csv}");
        assert_eq!(
            lines[5], "120,60.2,3.0,nanodet,FV,32,0.1250,0.8750",
            "{csv}"
        );
        let b = pts[1].brief();
        assert!(
            b.contains("iteration 120")
                && b.contains("nanodet P@0.5 0.12/0.50 target 0.88/0.50")
                && b.contains("centernet P@0.5 0.75/0.25"),
            "{b}"
        );
        let img = plot(&pts, 320, 200).unwrap();
        assert_eq!(img.dimensions(), (320, 200));
    }

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
