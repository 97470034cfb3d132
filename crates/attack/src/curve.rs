//! The attack's quality against its run time: the texture as it stands, scored at fixed points
//! of the training clock (`cac train --eval-every SECONDS`).
//!
//! Each [`CurvePoint`] is the figures per model and viewpoint set at one iteration, with the
//! training seconds reached (scoring excluded: the run's clock stops while it scores) and the
//! seconds the scoring took. A [`Judge`] makes them (the protocol's: `study::curve::Curve`, on
//! views the training never draws); the run folder keeps the points in run.json and writes
//! `curve.csv` and `curve.png` ([`write`]). Not here: when to score (the run's loop,
//! [`super::run`]) and how (the evaluation protocol, `eval`).

use anyhow::Result;
use cac_core::report::plot::{self, Plot, Series};
use cac_core::report::Table;
use cac_scene::Texture;
use serde::{Deserialize, Serialize};
use std::path::Path;

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

/// What scores the texture along a run: every [`Judge::every_s`] seconds of training the run
/// hands it the atlas as it stands (the protocol's scorer: `study::curve::Curve`).
pub trait Judge {
    /// Seconds of training between two points.
    fn every_s(&self) -> f64;
    /// The point for `atlas` after `iteration` iterations and `train_s` seconds of training.
    fn score(&self, atlas: &Texture, iteration: usize, train_s: f64) -> Result<CurvePoint>;
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
}
