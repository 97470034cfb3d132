//! Scores a capture session (an adapter of the scoring core, `eval::score`): every frame of the
//! manifest through each detector, against the
//! ground-truth box projected through the calibrated lens at the planned angle and distance
//! ([`super::truth`]); P@0.5 per distance ratio as mean ± standard deviation over the repeats
//! (the paper's Figure 6), and per table angle (a polar plot). [`write`] saves JSON, CSV, the
//! plots and an HTML report.

use super::manifest;
use super::rig::Rig;
use super::session::SessionInfo;
use super::truth::ground_truth_box;
use anyhow::{Context, Result};
use burn::tensor::Device;
use cac_core::report::{plot, Html, Plot, Series, Table};
use cac_detect::{preprocess::image_to_tensor, Detector};
use cac_eval::score::{figures_by, mean_std, ImageScore, Scorer};
use cac_eval::Protocol;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One frame's outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameScore {
    pub frame: String,
    pub ratio: f64,
    pub angle: f64,
    pub repeat: usize,
    /// Projected ground-truth box; `None` when the object is out of view (frame not scored).
    pub gt: Option<[f32; 4]>,
    /// Per model: hit (true class, IoU ≥ 0.5, confidence ≥ 0.3).
    pub hit: Vec<bool>,
    /// Per model: best true-class confidence among boxes with IoU ≥ 0.5.
    pub best_conf: Vec<f32>,
}

/// P@0.5 at one distance ratio for one model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RatioScore {
    pub model: String,
    pub ratio: f64,
    /// P@0.5 of each repeat (over the angles).
    pub per_repeat: Vec<f64>,
    pub mean: f64,
    /// Sample standard deviation over the repeats (0 with one repeat).
    pub std: f64,
}

/// P@0.5 at one table angle (over ratios and repeats) for one model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AngleScore {
    pub model: String,
    pub angle: f64,
    pub p_at_05: f64,
    pub frames: usize,
}

/// A scored session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionScore {
    pub protocol: Protocol,
    pub models: Vec<String>,
    pub frames: Vec<FrameScore>,
    pub by_ratio: Vec<RatioScore>,
    pub by_angle: Vec<AngleScore>,
}

/// Scores every frame of the session in `dir` with each detector (a progress bar on stderr with
/// `progress`).
pub fn score(
    dir: &Path,
    detectors: &[&dyn Detector],
    protocol: &Protocol,
    device: &Device,
    progress: bool,
) -> Result<SessionScore> {
    let info = SessionInfo::load(dir)?;
    let entries = manifest::read(&dir.join("manifest.jsonl"))?;
    let rig = Rig::new(info.rig.clone(), info.lens.clone())
        .with_context(|| format!("the rig of session {}", dir.display()))?;
    let scorer = Scorer::new(detectors, protocol)?;
    let mut frames = Vec::with_capacity(entries.len());
    let bar = if progress {
        indicatif::ProgressBar::new(entries.len() as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    for e in &entries {
        bar.inc(1);
        let gt = ground_truth_box(&rig, e.angle, rig.horizontal_distance(e.ratio)?)?;
        let mut f = FrameScore {
            frame: e.frame.clone(),
            ratio: e.ratio,
            angle: e.angle,
            repeat: e.repeat,
            gt,
            hit: vec![],
            best_conf: vec![],
        };
        if let Some(gt) = gt {
            let img = cac_core::io::load_rgb(&dir.join(&e.frame))?;
            let x = image_to_tensor(&img, device);
            for o in scorer.frame(x, &gt, Some(&|| e.frame.clone()))? {
                f.hit.push(o.score.hit);
                f.best_conf.push(o.score.best_true_conf);
            }
        }
        frames.push(f);
    }
    bar.finish_and_clear();
    let models = scorer.models();
    let (by_ratio, by_angle) = aggregate(
        &models,
        &info.plan.ratios,
        &info.plan.angles,
        info.plan.repeats,
        &frames,
    );
    Ok(SessionScore {
        protocol: protocol.clone(),
        models,
        frames,
        by_ratio,
        by_angle,
    })
}

/// Per-ratio (mean ± std over repeats) and per-angle P@0.5 from frame scores (frames without a
/// ground-truth box are not scored; a ratio and repeat, or an angle, without scored frames is
/// left out).
pub(crate) fn aggregate(
    models: &[String],
    ratios: &[f64],
    angles: &[f64],
    repeats: usize,
    frames: &[FrameScore],
) -> (Vec<RatioScore>, Vec<AngleScore>) {
    let scored: Vec<&FrameScore> = frames.iter().filter(|f| f.gt.is_some()).collect();
    let mut by_ratio = Vec::new();
    let mut by_angle = Vec::new();
    for (m, name) in models.iter().enumerate() {
        let scores: Vec<(&FrameScore, ImageScore)> =
            scored.iter().map(|f| (*f, f.image_score(m))).collect();
        let per_run = figures_by(&scores, |x| (x.0.ratio, x.0.repeat), |x| &x.1);
        let per_angle = figures_by(&scores, |x| x.0.angle, |x| &x.1);
        for &r in ratios {
            let per_repeat: Vec<f64> = (0..repeats)
                .filter_map(|k| {
                    per_run
                        .iter()
                        .find(|(key, _)| *key == (r, k))
                        .map(|(_, f)| f.p_at_05)
                })
                .collect();
            let (mean, std) = mean_std(&per_repeat);
            by_ratio.push(RatioScore {
                model: name.clone(),
                ratio: r,
                per_repeat,
                mean,
                std,
            });
        }
        for &a in angles {
            if let Some((_, f)) = per_angle.iter().find(|(key, _)| *key == a) {
                by_angle.push(AngleScore {
                    model: name.clone(),
                    angle: a,
                    p_at_05: f.p_at_05,
                    frames: f.images,
                });
            }
        }
    }
    (by_ratio, by_angle)
}

impl FrameScore {
    /// Model `m`'s score on this frame (the capture scorer keeps no targeted outcome).
    fn image_score(&self, m: usize) -> ImageScore {
        ImageScore {
            hit: self.hit[m],
            targeted: false,
            best_true_conf: self.best_conf[m],
        }
    }
}

/// Writes `scores.json`, `frames.csv`, `by_ratio.csv`, `by_angle.csv`, `p_vs_ratio.png`,
/// `polar.png` and `report.html` into `out`.
pub fn write(out: &Path, s: &SessionScore, session: &str) -> Result<()> {
    let io = cac_core::io::write_atomic;
    io(
        &out.join("scores.json"),
        serde_json::to_string_pretty(s)?.as_bytes(),
    )?;
    io(&out.join("frames.csv"), frames_table(s).csv().as_bytes())?;
    let ratio_t = ratio_table(s);
    io(&out.join("by_ratio.csv"), ratio_t.csv().as_bytes())?;
    let angle_t = angle_table(s);
    io(&out.join("by_angle.csv"), angle_t.csv().as_bytes())?;
    let (fig6, polar) = plots(s)?;
    cac_core::io::save_png_atomic(&out.join("p_vs_ratio.png"), &fig6)?;
    cac_core::io::save_png_atomic(&out.join("polar.png"), &polar)?;
    let h = report_html(s, session, &fig6, &polar, &ratio_t, &angle_t)?;
    io(&out.join("report.html"), h.as_bytes())?;
    Ok(())
}

/// `frames.csv`: every frame with its ground-truth box and each model's hit and confidence.
fn frames_table(s: &SessionScore) -> Table {
    let mut frames = Table::new(
        [
            "frame", "ratio", "angle", "repeat", "gt_x1", "gt_y1", "gt_x2", "gt_y2",
        ]
        .map(String::from)
        .into_iter()
        .chain(
            s.models
                .iter()
                .flat_map(|m| [format!("{m}_hit"), format!("{m}_conf")]),
        ),
    );
    for f in &s.frames {
        let gt = f.gt.map_or(
            [String::new(), String::new(), String::new(), String::new()],
            |b| b.map(|v| format!("{v:.2}")),
        );
        let mut row = vec![
            f.frame.clone(),
            f.ratio.to_string(),
            f.angle.to_string(),
            f.repeat.to_string(),
        ];
        row.extend(gt);
        for (h, c) in f.hit.iter().zip(&f.best_conf) {
            row.push((*h as u8).to_string());
            row.push(format!("{c:.4}"));
        }
        frames.row(row);
    }
    frames
}

/// `by_ratio.csv`: P@0.5 per model and distance ratio, mean and std over the repeats.
fn ratio_table(s: &SessionScore) -> Table {
    let mut ratio_t = Table::new([
        "model",
        "distance ratio",
        "P@0.5 mean",
        "P@0.5 std",
        "repeats",
    ]);
    for r in &s.by_ratio {
        ratio_t.row([
            r.model.clone(),
            r.ratio.to_string(),
            format!("{:.3}", r.mean),
            format!("{:.3}", r.std),
            r.per_repeat.len().to_string(),
        ]);
    }
    ratio_t
}

/// `by_angle.csv`: P@0.5 per model and table angle.
fn angle_table(s: &SessionScore) -> Table {
    let mut angle_t = Table::new(["model", "angle", "P@0.5", "frames"]);
    for a in &s.by_angle {
        angle_t.row([
            a.model.clone(),
            a.angle.to_string(),
            format!("{:.3}", a.p_at_05),
            a.frames.to_string(),
        ]);
    }
    angle_t
}

/// The plots: P@0.5 against distance ratio with error bars (Figure 6), and against table angle
/// (polar, each model's curve closed).
fn plots(s: &SessionScore) -> Result<(image::RgbImage, image::RgbImage)> {
    let ratio_series: Vec<Series> = s
        .models
        .iter()
        .map(|m| {
            let rs: Vec<_> = s
                .by_ratio
                .iter()
                .filter(|r| &r.model == m && !r.per_repeat.is_empty())
                .collect();
            Series::new(m, rs.iter().map(|r| (r.ratio, r.mean)).collect())
                .err(rs.iter().map(|r| r.std).collect())
        })
        .collect();
    let fig6 = plot::xy(
        &Plot::new("P@0.5 against distance ratio", "distance ratio", "P@0.5").y_range(0.0, 1.0),
        &ratio_series,
    )?;
    let polar_series: Vec<Series> = s
        .models
        .iter()
        .map(|m| {
            let mut pts: Vec<_> = s
                .by_angle
                .iter()
                .filter(|a| &a.model == m)
                .map(|a| (a.angle, a.p_at_05))
                .collect();
            if let Some(&first) = pts.first() {
                pts.push(first);
            }
            Series::new(m, pts)
        })
        .collect();
    let polar = plot::polar(
        &Plot::new("P@0.5 against table angle", "", "P@0.5")
            .y_range(0.0, 1.0)
            .size(480, 480),
        &polar_series,
    )?;
    Ok((fig6, polar))
}

/// `report.html`: the session, the protocol, the plots and the tables.
fn report_html(
    s: &SessionScore,
    session: &str,
    fig6: &image::RgbImage,
    polar: &image::RgbImage,
    ratio_t: &Table,
    angle_t: &Table,
) -> Result<String> {
    let skipped = s.frames.iter().filter(|f| f.gt.is_none()).count();
    let mut h = Html::new("Physical test: P@0.5");
    h.paragraph(&format!(
        "Session {session}: {} frames, {skipped} with the object out of view (not scored).",
        s.frames.len()
    ));
    h.pre(&format!(
        "protocol: a frame is a hit when a detection of class {:?} has IoU >= {} with the ground-truth box (the object's silhouette projected through the calibrated lens) at confidence >= {}; P@0.5 = hits / frames; ± is the standard deviation over repeats",
        s.protocol.true_labels(), s.protocol.iou, s.protocol.confidence
    ));
    h.figures(
        &[
            (
                fig6,
                "P@0.5 against distance ratio (mean ± std over repeats)",
            ),
            (polar, "P@0.5 against table angle"),
        ],
        480,
    )?;
    h.heading(2, "By distance ratio").table(ratio_t);
    h.heading(2, "By table angle").table(angle_t);
    Ok(h.finish())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(ratio: f64, angle: f64, repeat: usize, hits: Option<[bool; 2]>) -> FrameScore {
        FrameScore {
            frame: format!("{ratio}-{angle}-{repeat}.png"),
            ratio,
            angle,
            repeat,
            gt: hits.map(|_| [0.0, 0.0, 1.0, 1.0]),
            hit: hits.map_or(vec![], |h| h.to_vec()),
            best_conf: hits.map_or(vec![], |h| h.map(|x| if x { 0.9 } else { 0.1 }).to_vec()),
        }
    }

    #[test]
    fn per_ratio_over_repeats_and_per_angle_skip_unscored_frames() {
        let models = ["a".to_string(), "b".to_string()];
        let frames = [
            frame(2.0, 0.0, 0, Some([true, false])),
            frame(2.0, 90.0, 0, Some([false, false])),
            frame(2.0, 0.0, 1, Some([true, true])),
            frame(2.0, 90.0, 1, Some([true, false])),
            frame(3.0, 0.0, 0, Some([false, true])),
            // Out of view: not scored, so ratio 3 has no repeat 1 and angle 180 no frames.
            frame(3.0, 90.0, 0, None),
            frame(3.0, 180.0, 1, None),
        ];
        let (by_ratio, by_angle) = aggregate(&models, &[2.0, 3.0], &[0.0, 90.0, 180.0], 2, &frames);
        let r: Vec<(&str, f64, Vec<f64>, f64)> = by_ratio
            .iter()
            .map(|r| (r.model.as_str(), r.ratio, r.per_repeat.clone(), r.mean))
            .collect();
        assert_eq!(
            r,
            vec![
                ("a", 2.0, vec![0.5, 1.0], 0.75),
                ("a", 3.0, vec![0.0], 0.0),
                ("b", 2.0, vec![0.0, 0.5], 0.25),
                ("b", 3.0, vec![1.0], 1.0),
            ]
        );
        assert!((by_ratio[0].std - 0.125f64.sqrt()).abs() < 1e-12);
        assert_eq!(by_ratio[1].std, 0.0, "one repeat: no spread");
        let a: Vec<(&str, f64, f64, usize)> = by_angle
            .iter()
            .map(|a| (a.model.as_str(), a.angle, a.p_at_05, a.frames))
            .collect();
        assert_eq!(
            a,
            vec![
                ("a", 0.0, 2.0 / 3.0, 3),
                ("a", 90.0, 0.5, 2),
                ("b", 0.0, 2.0 / 3.0, 3),
                ("b", 90.0, 0.0, 2),
            ]
        );
    }
}
