//! What `cac score-video` writes: the per-frame CSV (one row per frame and model), the segment
//! and summary tables (CSV + Markdown), `scores.json`, the plots over time and per segment, and a
//! self-contained HTML report — on the shared `cac::report` tables, plots and HTML.

use super::annotate;
use super::score::{FrameRecord, VideoScores};
use anyhow::Result;
use cac_core::io::{save_png_atomic, write_atomic};
use cac_core::report::plot::PALETTE;
use cac_core::report::{plot, Html, Plot, Series, Table};
use std::path::Path;

fn f3(v: f64) -> String {
    format!("{v:.3}")
}

/// One row per scored frame and model.
pub(crate) fn frames_table(s: &VideoScores) -> Table {
    let mut t = Table::new([
        "frame",
        "pts_s",
        "segment",
        "angle_deg",
        "model",
        "hit",
        "targeted",
        "best_true_conf",
        "matched_label",
        "matched_score",
        "matched_iou",
        "matched_x1",
        "matched_y1",
        "matched_x2",
        "matched_y2",
        "gt_x1",
        "gt_y1",
        "gt_x2",
        "gt_y2",
        "detections",
        "ms",
    ]);
    for f in &s.frames {
        for (m, mf) in f.models.iter().enumerate() {
            let mut row = vec![
                f.index.to_string(),
                format!("{:.4}", f.pts),
                f.segment.clone(),
                f.angle_deg.map(|a| format!("{a:.2}")).unwrap_or_default(),
                s.summary[m].model.clone(),
                (mf.score.hit as u8).to_string(),
                (mf.score.targeted as u8).to_string(),
                format!("{:.4}", mf.score.best_true_conf),
            ];
            match &mf.matched {
                Some((d, o)) => {
                    row.extend([d.label.to_string(), format!("{:.4}", d.score), f3(*o)]);
                    row.extend(d.bbox.iter().map(|v| format!("{v:.1}")));
                }
                None => row.extend(std::iter::repeat_n(String::new(), 7)),
            }
            row.extend(f.gt.iter().map(|v| format!("{v:.1}")));
            row.push(mf.detections.len().to_string());
            row.push(format!("{:.1}", mf.ms));
            t.row(row);
        }
    }
    t
}

/// P@0.5 per segment and model.
pub(crate) fn segments_table(s: &VideoScores) -> Table {
    let mut t = Table::new([
        "model",
        "segment",
        "frames",
        "t_start_s",
        "t_end_s",
        "P@0.5",
    ]);
    for m in &s.summary {
        for g in &m.segments {
            t.row([
                m.model.clone(),
                g.name.clone(),
                g.frames.to_string(),
                f3(g.t_start),
                f3(g.t_end),
                f3(g.p_at_05),
            ]);
        }
    }
    t
}

/// One row per model: P@0.5 over frames and mean ± std over segments.
pub(crate) fn summary_table(s: &VideoScores) -> Table {
    let mut t = Table::new([
        "model",
        "frames",
        "P@0.5",
        "segments",
        "P@0.5 mean ± std over segments",
        "targeted success",
        "mean best true conf",
        "ms/frame",
    ]);
    for m in &s.summary {
        t.row([
            m.model.clone(),
            m.frames.to_string(),
            f3(m.p_at_05),
            m.segments.len().to_string(),
            format!("{:.3} ± {:.3}", m.segment_mean, m.segment_std),
            f3(m.targeted_success),
            f3(m.mean_best_true_conf),
            format!("{:.1}", m.ms_per_frame),
        ]);
    }
    t
}

/// Best true-class confidence (IoU >= threshold) of each model against time, with the
/// confidence threshold as a grey line.
pub(crate) fn time_plot(s: &VideoScores) -> Result<image::RgbImage> {
    let t0 = s.frames.first().map_or(0.0, |f| f.pts);
    let t1 = s.frames.last().map_or(1.0, |f| f.pts).max(t0 + 1e-3);
    let mut series: Vec<Series> = s
        .summary
        .iter()
        .enumerate()
        .map(|(m, sm)| {
            let pts = s
                .frames
                .iter()
                .map(|f| (f.pts, f.models[m].score.best_true_conf as f64))
                .collect();
            Series::new(&sm.model, pts).color(PALETTE[m % PALETTE.len()])
        })
        .collect();
    let c = s.protocol.confidence as f64;
    series.push(
        Series::new("confidence threshold", vec![(t0, c), (t1, c)])
            .color((200, 40, 40))
            .line(1),
    );
    plot::xy(
        &Plot::new(
            "true-class confidence over time (hit: at or above the threshold)",
            "time (s)",
            "best true-class confidence, IoU >= 0.5",
        )
        .x_range(t0, t1)
        .y_range(0.0, 1.0)
        .size(800, 360),
        &series,
    )
}

/// P@0.5 of each segment against the segment's middle time, per model; the legend gives the
/// mean ± std over segments.
pub(crate) fn segments_plot(s: &VideoScores) -> Result<image::RgbImage> {
    let series: Vec<Series> = s
        .summary
        .iter()
        .enumerate()
        .map(|(m, sm)| {
            let pts = sm
                .segments
                .iter()
                .map(|g| (0.5 * (g.t_start + g.t_end), g.p_at_05))
                .collect();
            let label = format!(
                "{} ({:.2} ± {:.2})",
                sm.model, sm.segment_mean, sm.segment_std
            );
            Series::new(&label, pts).color(PALETTE[m % PALETTE.len()])
        })
        .collect();
    plot::xy(
        &Plot::new("P@0.5 per segment", "segment middle time (s)", "P@0.5")
            .y_range(0.0, 1.05)
            .size(800, 360),
        &series,
    )
}

/// With a turntable log: the best true-class confidence against the turntable angle (polar, 0° at
/// the top, clockwise), one curve per model and revolution-free angle (mod 360).
pub(crate) fn angle_plot(s: &VideoScores) -> Result<Option<image::RgbImage>> {
    if s.frames.iter().all(|f| f.angle_deg.is_none()) {
        return Ok(None);
    }
    let series: Vec<Series> = s
        .summary
        .iter()
        .enumerate()
        .map(|(m, sm)| {
            let mut pts: Vec<(f64, f64)> = s
                .frames
                .iter()
                .filter_map(|f| {
                    let a = f.angle_deg?.rem_euclid(360.0);
                    Some((a, f.models[m].score.best_true_conf as f64))
                })
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            if let Some(&p) = pts.first() {
                pts.push(p);
            }
            Series::new(&sm.model, pts).color(PALETTE[m % PALETTE.len()])
        })
        .collect();
    plot::polar(
        &Plot::new(
            "best true-class confidence against turntable angle",
            "angle (°)",
            "confidence",
        )
        .y_range(0.0, 1.0)
        .size(480, 480),
        &series,
    )
    .map(Some)
}

/// Example frames for the report: the first scored frame of each segment (at most `max`),
/// drawn like the annotated output and scaled to at most 640 pixels wide.
pub struct Examples {
    max: usize,
    seen: Vec<String>,
    pub frames: Vec<(image::RgbImage, String)>,
}

impl Examples {
    pub fn new(max: usize) -> Self {
        Examples {
            max,
            seen: vec![],
            frames: vec![],
        }
    }

    /// Keeps `frame` when it is the first of its segment and there is room.
    pub fn offer(
        &mut self,
        frame: &image::RgbImage,
        rec: &FrameRecord,
        models: &[String],
        confidence: f32,
    ) {
        if self.frames.len() >= self.max || self.seen.contains(&rec.segment) {
            return;
        }
        self.seen.push(rec.segment.clone());
        let img = annotate::draw(frame, rec, models, confidence);
        let img = if img.width() > 640 {
            let h = (img.height() as u64 * 640 / img.width() as u64).max(1) as u32;
            image::imageops::resize(&img, 640, h, image::imageops::FilterType::Triangle)
        } else {
            img
        };
        let outcome: Vec<String> = models
            .iter()
            .zip(&rec.models)
            .map(|(m, f)| format!("{m} {}", if f.score.hit { "hit" } else { "miss" }))
            .collect();
        let caption = format!(
            "frame {} at {:.2} s, {}: {}",
            rec.index,
            rec.pts,
            rec.segment,
            outcome.join(", ")
        );
        self.frames.push((img, caption));
    }
}

/// Writes `frames.csv`, `segments.csv`, `summary.csv`, `summary.md`, `scores.json`,
/// `time.png`, `segments.png`, `angle.png` (with a turntable log) and `report.html` into `out`. `notes` are extra lines for the report
/// (the command, the annotated output); `examples` are drawn frames shown in the report.
pub fn write_all(
    out: &Path,
    s: &VideoScores,
    notes: &[String],
    examples: &[(image::RgbImage, String)],
) -> Result<()> {
    let (frames, segs, summary) = (frames_table(s), segments_table(s), summary_table(s));
    write_atomic(&out.join("frames.csv"), frames.csv().as_bytes())?;
    write_atomic(&out.join("segments.csv"), segs.csv().as_bytes())?;
    write_atomic(&out.join("summary.csv"), summary.csv().as_bytes())?;
    write_atomic(&out.join("summary.md"), summary.markdown().as_bytes())?;
    write_atomic(&out.join("scores.json"), &serde_json::to_vec_pretty(s)?)?;
    let tp = time_plot(s)?;
    let sp = segments_plot(s)?;
    save_png_atomic(&out.join("time.png"), &tp)?;
    save_png_atomic(&out.join("segments.png"), &sp)?;
    let ap = angle_plot(s)?;
    if let Some(ap) = &ap {
        save_png_atomic(&out.join("angle.png"), ap)?;
    }
    let p = &s.protocol;
    let mut h = Html::new("cac score-video");
    h.heading(2, "Input")
        .pre(&format!(
            "source:       {}\nground truth: {}\ndecoded {} frames, scored {}, sampled without ground truth {}{}",
            s.source,
            s.ground_truth,
            s.decoded,
            s.frames.len(),
            s.unannotated,
            if s.missed_times.is_empty() {
                String::new()
            } else {
                format!("\ntimes outside the video: {:?}", s.missed_times)
            }
        ))
        .pre(&format!(
            "protocol: hit = class in {:?} with IoU >= {} and confidence >= {}; P@0.5 = hits / frames; \
             ± is the sample standard deviation (n − 1) over segments",
            p.true_labels(), p.iou, p.confidence
        ));
    for n in notes {
        h.paragraph(n);
    }
    h.heading(2, "Summary").table(&summary);
    h.image(&tp, "best true-class confidence over time")?;
    if let Some(ap) = &ap {
        h.image(ap, "best true-class confidence against turntable angle")?;
    }
    h.heading(2, "Segments").table(&segs);
    h.image(&sp, "P@0.5 per segment")?;
    if !examples.is_empty() {
        h.heading(2, "Example frames (first of each segment)");
        let refs: Vec<(&image::RgbImage, &str)> =
            examples.iter().map(|(i, c)| (i, c.as_str())).collect();
        h.photos(&refs, 640)?;
    }
    write_atomic(&out.join("report.html"), h.finish().as_bytes())
}
