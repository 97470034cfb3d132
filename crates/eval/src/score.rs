//! The one scoring core that every evaluation shares — rendered views (`eval`), Blender views,
//! capture sessions (`physical::score`) and recorded videos (`video::score`): an image and its
//! ground-truth box go through each detector ([`Scorer::frame`]), each model's detections are
//! scored against the box by the protocol ([`score_image`]: a *hit* is a true-class detection with
//! IoU ≥ 0.5 at confidence ≥ 0.3), and scored images are tallied into [`Figures`] — over all
//! images, or per key with [`group_by`] (a texture and model, a distance ratio and repeat, a table
//! angle, a video segment). The callers keep only what differs: where the frames and their boxes
//! come from, what a record keeps, and which keys they report.

use crate::Protocol;
use anyhow::{Context, Result};
use burn::tensor::Tensor;
use cac_detect::{nms::iou, Detection, Detector};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// One image's outcome for one model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageScore {
    pub hit: bool,
    pub targeted: bool,
    /// Highest true-class confidence among detections with IoU >= the threshold (0 if none).
    pub best_true_conf: f32,
}

/// Scores one image's detections against its ground-truth box.
pub fn score_image(dets: &[Detection], gt: &[f32; 4], p: &Protocol) -> ImageScore {
    let mut s = ImageScore {
        hit: false,
        targeted: false,
        best_true_conf: 0.0,
    };
    for d in dets {
        // nms::iou takes [y1, x1, y2, x2]; IoU is symmetric in the axes, so xyxy works as well.
        let o = iou(&d.bbox, gt);
        if o < p.iou {
            continue;
        }
        if p.true_classes.contains(&d.class_id) {
            s.best_true_conf = s.best_true_conf.max(d.score);
            if d.score >= p.confidence {
                s.hit = true;
            }
        }
        if Some(d.class_id) == p.target && d.score >= p.confidence {
            s.targeted = true;
        }
    }
    s
}

/// One model's outcome on one frame: its detections, their score, and how long it took.
#[derive(Clone, Debug, Serialize)]
pub struct ModelOutcome {
    pub detections: Vec<Detection>,
    pub score: ImageScore,
    /// Detection time (pre-processing, network, NMS), milliseconds.
    pub ms: f64,
}

/// The detectors and the protocol that score frames.
#[derive(Clone)]
pub struct Scorer<'a> {
    pub detectors: &'a [&'a dyn Detector],
    pub protocol: &'a Protocol,
    /// The protocol's classes in each detector's own class ids ([`Protocol::for_model`]).
    per_model: Vec<Protocol>,
}

impl<'a> Scorer<'a> {
    /// The scorer of `detectors` under `protocol`; an error when a detector lacks a class the
    /// protocol names (it lists that detector's classes).
    pub fn new(detectors: &'a [&'a dyn Detector], protocol: &'a Protocol) -> Result<Self> {
        let per_model = detectors
            .iter()
            .map(|d| protocol.for_model(d.classes(), d.name()))
            .collect::<Result<_>>()?;
        Ok(Scorer {
            detectors,
            protocol,
            per_model,
        })
    }

    /// The models' names, in the order of the detectors.
    pub fn models(&self) -> Vec<String> {
        self.detectors
            .iter()
            .map(|d| d.name().to_string())
            .collect()
    }

    /// Detects with each model in `image` (`[1, 3, H, W]`) and scores against `gt`; one outcome
    /// per model, in the order of the detectors. `label` names the frame in errors
    /// (`"<model> on <label>"`).
    pub fn frame(
        &self,
        image: Tensor<4>,
        gt: &[f32; 4],
        label: Option<&dyn Fn() -> String>,
    ) -> Result<Vec<ModelOutcome>> {
        let mut out = Vec::with_capacity(self.detectors.len());
        for (d, p) in self.detectors.iter().zip(&self.per_model) {
            let t0 = Instant::now();
            let found = d.detect(image.clone());
            let found = match label {
                Some(l) => found.with_context(|| format!("{} on {}", d.name(), l()))?,
                None => found?,
            };
            let detections = found.into_iter().next().unwrap_or_default();
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            out.push(ModelOutcome {
                score: score_image(&detections, gt, p),
                detections,
                ms,
            });
        }
        Ok(out)
    }
}

/// The figures of a set of scored images.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Figures {
    pub images: usize,
    pub p_at_05: f64,
    /// Standard error of P@0.5 as a binomial proportion, `sqrt(p (1 - p) / images)`.
    pub p_stderr: f64,
    pub targeted_success: f64,
    pub mean_best_true_conf: f64,
}

impl Figures {
    /// Tallies `scores` (no images: all zero, no NaN).
    pub fn of_scores<'s>(scores: impl IntoIterator<Item = &'s ImageScore>) -> Figures {
        let (mut n, mut hits, mut tg, mut conf) = (0usize, 0usize, 0usize, 0.0f64);
        for s in scores {
            n += 1;
            hits += s.hit as usize;
            tg += s.targeted as usize;
            conf += s.best_true_conf as f64;
        }
        let d = n.max(1) as f64;
        let p = hits as f64 / d;
        Figures {
            images: n,
            p_at_05: p,
            p_stderr: (p * (1.0 - p) / d).sqrt(),
            targeted_success: tg as f64 / d,
            mean_best_true_conf: conf / d,
        }
    }
}

/// `records` grouped by `key`, the groups in the order their keys first appear and the records
/// of each in their order.
pub fn group_by<'r, R, K: PartialEq>(
    records: impl IntoIterator<Item = &'r R>,
    key: impl Fn(&R) -> K,
) -> Vec<(K, Vec<&'r R>)> {
    let mut out: Vec<(K, Vec<&R>)> = vec![];
    for r in records {
        let k = key(r);
        match out.iter_mut().find(|(g, _)| *g == k) {
            Some((_, v)) => v.push(r),
            None => out.push((k, vec![r])),
        }
    }
    out
}

/// The [`Figures`] of `records` per `key` (keys in the order they first appear), each record's
/// score read by `score`.
pub fn figures_by<'r, R: 'r, K: PartialEq>(
    records: impl IntoIterator<Item = &'r R>,
    key: impl Fn(&R) -> K,
    score: impl Fn(&'r R) -> &'r ImageScore,
) -> Vec<(K, Figures)> {
    group_by(records, key)
        .into_iter()
        .map(|(k, rs)| (k, Figures::of_scores(rs.into_iter().map(&score))))
        .collect()
}

/// Mean and sample standard deviation (n − 1; 0 with fewer than two values; both 0 for none).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = if v.len() > 1 {
        v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    (m, var.sqrt())
}

/// P@0.5, targeted success and mean best true-class confidence over images.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub images: usize,
    pub p_at_05: f64,
    pub targeted_success: f64,
    pub mean_best_true_conf: f64,
}

pub fn summarise(scores: &[ImageScore]) -> Summary {
    let f = Figures::of_scores(scores);
    Summary {
        images: f.images,
        p_at_05: f.p_at_05,
        targeted_success: f.targeted_success,
        mean_best_true_conf: f.mean_best_true_conf,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(hit: bool, targeted: bool, c: f32) -> ImageScore {
        ImageScore {
            hit,
            targeted,
            best_true_conf: c,
        }
    }

    #[test]
    fn figures_and_groups() {
        let v = [
            s(true, false, 0.5),
            s(false, true, 0.25),
            s(true, true, 1.0),
        ];
        let f = Figures::of_scores(&v);
        assert_eq!(f.images, 3);
        assert!((f.p_at_05 - 2.0 / 3.0).abs() < 1e-12);
        assert!((f.targeted_success - 2.0 / 3.0).abs() < 1e-12);
        assert!((f.mean_best_true_conf - 1.75 / 3.0).abs() < 1e-12);
        assert!((f.p_stderr - (2.0f64 / 9.0 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(Figures::of_scores(&[]), Figures::default());
        let recs = [(2, 'a'), (1, 'b'), (2, 'c'), (3, 'd'), (1, 'e')];
        let g = group_by(&recs, |r| r.0);
        let got: Vec<(i32, String)> = g
            .into_iter()
            .map(|(k, rs)| (k, rs.iter().map(|r| r.1).collect()))
            .collect();
        assert_eq!(
            got,
            vec![(2, "ac".into()), (1, "be".into()), (3, "d".into())]
        );
        let f = figures_by(&v, |s| s.targeted, |s| s);
        assert_eq!(f.len(), 2);
        assert_eq!((f[0].0, f[0].1.images, f[0].1.p_at_05), (false, 1, 1.0));
        assert_eq!((f[1].0, f[1].1.images, f[1].1.p_at_05), (true, 2, 0.5));
        assert_eq!(mean_std(&[]), (0.0, 0.0));
        assert_eq!(mean_std(&[0.5]), (0.5, 0.0));
        let (m, sd) = mean_std(&[0.0, 1.0]);
        assert!((m - 0.5).abs() < 1e-12 && (sd - 0.5f64.sqrt()).abs() < 1e-12);
    }
}
