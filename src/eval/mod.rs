//! Evaluation metrics: per image and model, a *hit* is a true-class detection with IoU >= 0.5
//! against the ground-truth box at confidence >= 0.3; P@0.5 = hits / images. Targeted success is
//! the same test for the target class. Drop = P@0.5(original) − P@0.5(texture).
//!
//! [`score`] is the one scoring core (detect, score against the box, tally by key) that the
//! rendered, Blender, capture and video evaluations share. [`run`] draws the protocol's views and
//! scores textures in them, [`summary`] aggregates the
//! per-image records, [`report`] writes the tables, plots and HTML, [`textures`] resolves the
//! texture list, [`cache`] keeps finished textures so an interrupted evaluation resumes, [`shard`]
//! splits an evaluation into shards and merges them back. [`realism`] measures whether the
//! original object is recognised at all (`cac bench realism`), [`bench`] the images scored per
//! second (`cac bench eval`), [`compare`] one texture against another (the demo's before and
//! after).

pub mod bench;
pub mod blender;
pub mod cache;
pub mod compare;
pub mod gradcam;
pub mod job;
pub mod realism;
pub mod report;
pub mod run;
pub mod score;
pub mod shard;
pub mod slurm;
pub mod study;
pub mod summary;
pub mod textures;
mod views;
/// Lives in [`crate::environment`]; re-exported for the callers that still name it here.
pub use crate::environment::street_views;
pub use views::{evaluate, ViewResults};

pub use score::{score_image, Figures, ImageScore, ModelOutcome, Scorer};
use serde::{Deserialize, Serialize};

/// The protocol's thresholds and classes (stated in every report).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Protocol {
    /// COCO-80 ids that count as the true class (default: car, truck).
    pub true_classes: Vec<usize>,
    /// COCO-80 id of the attack's target class, if any.
    pub target: Option<usize>,
    pub iou: f64,
    pub confidence: f32,
}

impl Default for Protocol {
    fn default() -> Self {
        Protocol {
            true_classes: vec![2, 7],
            target: None,
            iou: 0.5,
            confidence: 0.3,
        }
    }
}

impl Protocol {
    /// The protocol with true classes from a comma-separated list of COCO labels (`none` or an
    /// empty list: no true class, only targeted success is meaningful) and an optional target.
    pub fn from_labels(true_classes: &str, target: Option<&str>) -> anyhow::Result<Protocol> {
        let id = |l: &str| {
            crate::detect::labels::class_id(l).ok_or_else(|| {
                anyhow::anyhow!(
                    "unknown COCO class {l:?} (use COCO-80 labels such as \"car\", \"truck\", \"stop sign\")"
                )
            })
        };
        let t = true_classes.trim();
        let true_classes = if t.is_empty() || t.eq_ignore_ascii_case("none") {
            vec![]
        } else {
            t.split(',')
                .map(|l| id(l.trim()))
                .collect::<anyhow::Result<_>>()?
        };
        Ok(Protocol {
            true_classes,
            target: target.map(id).transpose()?,
            ..Default::default()
        })
    }
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
    use crate::detect::Detection;

    fn det(c: usize, s: f32, b: [f32; 4]) -> Detection {
        Detection {
            class_id: c,
            label: crate::detect::labels::COCO80[c],
            score: s,
            bbox: b,
        }
    }

    #[test]
    fn hit_needs_true_class_iou_and_confidence() {
        let gt = [10.0, 10.0, 110.0, 60.0];
        let p = Protocol {
            target: Some(0),
            ..Default::default()
        };
        assert!(score_image(&[det(7, 0.31, [12.0, 11.0, 108.0, 62.0])], &gt, &p).hit);
        assert!(
            !score_image(&[det(7, 0.29, [12.0, 11.0, 108.0, 62.0])], &gt, &p).hit,
            "confidence"
        );
        assert!(
            !score_image(&[det(7, 0.9, [60.0, 10.0, 160.0, 60.0])], &gt, &p).hit,
            "IoU 1/3"
        );
        assert!(
            !score_image(&[det(5, 0.9, gt)], &gt, &p).hit,
            "bus is not a true class by default"
        );
        let s = score_image(&[det(0, 0.5, gt), det(2, 0.2, gt)], &gt, &p);
        assert!(s.targeted && !s.hit && (s.best_true_conf - 0.2).abs() < 1e-6);
        assert_eq!(summarise(&[]).p_at_05, 0.0, "no images: no NaN");
        let q = Protocol::from_labels("car, bus", Some("stop sign")).unwrap();
        assert_eq!((q.true_classes, q.target), (vec![2, 5], Some(11)));
        assert!(Protocol::from_labels("none", None)
            .unwrap()
            .true_classes
            .is_empty());
        let e = Protocol::from_labels("car,tank", None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("\"tank\""), "{e}");
    }
}
