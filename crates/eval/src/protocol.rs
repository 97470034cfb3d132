//! [`Protocol`]: the evaluation's thresholds and classes, resolved by name against each
//! model's own class list.

use cac_detect::labels;
use serde::{Deserialize, Serialize};

/// The protocol's thresholds and classes (stated in every report).
///
/// Classes are ids into the protocol's class list ([`Protocol::labels`]: COCO-80 unless a named
/// class is not a COCO label). Each model is scored with the protocol's classes resolved by name
/// against its own class list ([`Protocol::for_model`]), so a model trained on its own classes,
/// or an ensemble whose models order their classes differently, is judged on the classes named.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Protocol {
    /// Ids of the classes that count as the true class (default: car, truck).
    pub true_classes: Vec<usize>,
    /// Id of the attack's target class, if any.
    pub target: Option<usize>,
    pub iou: f64,
    pub confidence: f32,
    /// The class list the ids index when it is not COCO-80 (a user's own classes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub classes: Option<Vec<String>>,
}

impl Default for Protocol {
    fn default() -> Self {
        Protocol {
            true_classes: vec![2, 7],
            target: None,
            iou: 0.5,
            confidence: 0.3,
            classes: None,
        }
    }
}

impl Protocol {
    /// The protocol with true classes from a comma-separated list of class names (`none` or an
    /// empty list: no true class, only targeted success is meaningful) and an optional target.
    /// COCO labels keep COCO-80 ids; when a name is not a COCO label (a user's own class) the
    /// protocol's class list is the names given, in order. Whether the models have the classes
    /// is checked when they are known ([`Protocol::for_model`]).
    pub fn from_labels(true_classes: &str, target: Option<&str>) -> anyhow::Result<Protocol> {
        let t = true_classes.trim();
        let mut names: Vec<&str> = if t.is_empty() || t.eq_ignore_ascii_case("none") {
            vec![]
        } else {
            t.split(',').map(str::trim).collect()
        };
        if names.iter().any(|l| l.is_empty()) {
            anyhow::bail!("--true-classes {true_classes:?} has an empty class name");
        }
        let n_true = names.len();
        if let Some(l) = target {
            if l.trim().is_empty() {
                anyhow::bail!("the target class is empty");
            }
            names.push(l.trim());
        }
        let coco = names.iter().all(|l| labels::class_id(l).is_some());
        let mut list: Vec<String> = vec![];
        let mut id = |l: &str| -> usize {
            if coco {
                return labels::class_id(l).expect("checked");
            }
            match list.iter().position(|c| c == l) {
                Some(i) => i,
                None => {
                    list.push(l.to_string());
                    list.len() - 1
                }
            }
        };
        let ids: Vec<usize> = names.iter().map(|l| id(l)).collect();
        Ok(Protocol {
            true_classes: ids[..n_true].to_vec(),
            target: ids.get(n_true).copied(),
            classes: (!coco).then_some(list),
            ..Default::default()
        })
    }

    /// The name of protocol class `id`.
    pub fn label(&self, id: usize) -> &str {
        match &self.classes {
            Some(c) => c.get(id).map(String::as_str).unwrap_or("?"),
            None => labels::COCO80.get(id).copied().unwrap_or("?"),
        }
    }

    /// The names of the true classes.
    pub fn true_labels(&self) -> Vec<&str> {
        self.true_classes.iter().map(|&c| self.label(c)).collect()
    }

    /// The protocol's class names, true classes then target.
    pub fn labels(&self) -> Vec<&str> {
        self.true_classes
            .iter()
            .chain(self.target.as_ref())
            .map(|&c| self.label(c))
            .collect()
    }

    /// This protocol with its classes as ids into `classes`, the class list of model `model`
    /// (resolved by name; an error names the class the model lacks and lists its classes).
    pub(crate) fn for_model(&self, classes: &[&str], model: &str) -> anyhow::Result<Protocol> {
        use anyhow::Context;
        let id = |c: usize, what: &str| {
            labels::resolve(self.label(c), classes, model)
                .with_context(|| format!("the evaluation's {what}"))
        };
        Ok(Protocol {
            true_classes: self
                .true_classes
                .iter()
                .map(|&c| id(c, "true classes (--true-classes)"))
                .collect::<anyhow::Result<_>>()?,
            target: self
                .target
                .map(|c| id(c, "target class (--target)"))
                .transpose()?,
            classes: (!labels::is_coco80(classes))
                .then(|| classes.iter().map(|c| c.to_string()).collect()),
            ..self.clone()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::score::{score_image, summarise};
    use cac_detect::Detection;

    fn det(c: usize, s: f32, b: [f32; 4]) -> Detection {
        Detection {
            class_id: c,
            label: cac_detect::labels::COCO80[c],
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
        // A name that is no COCO label: the protocol's own class list, refused by a COCO model.
        let q = Protocol::from_labels("car,tank", None).unwrap();
        assert_eq!(
            q.classes.as_deref(),
            Some(&["car".to_string(), "tank".into()][..])
        );
        let e = q.for_model(&labels::COCO80, "nanodet").unwrap_err();
        assert!(format!("{e:#}").contains("\"tank\""), "{e:#}");
    }

    #[test]
    fn each_model_is_scored_on_the_classes_named_in_its_own_class_list() {
        let own = ["forklift", "dog", "pallet"];
        let p = Protocol::from_labels("pallet", Some("dog")).unwrap();
        assert_eq!(p.labels(), ["pallet", "dog"]);
        let m = p.for_model(&own, "own.onnx").unwrap();
        assert_eq!((m.true_classes.clone(), m.target), (vec![2], Some(1)));
        // Detections in the model's ids: class 2 is the true class, 1 the target.
        let gt = [0.0, 0.0, 10.0, 10.0];
        let d = |c: usize| Detection {
            class_id: c,
            label: own[c],
            score: 0.9,
            bbox: gt,
        };
        let s = score_image(&[d(2), d(1)], &gt, &m);
        assert!(s.hit && s.targeted);
        let s = score_image(&[d(0)], &gt, &m);
        assert!(!s.hit && !s.targeted, "class 0 (forklift) is neither");
        // A COCO model in the same ensemble lacks "pallet": refused, naming the model.
        let e = format!("{:#}", p.for_model(&labels::COCO80, "nanodet").unwrap_err());
        assert!(
            e.contains("nanodet has no class \"pallet\"") && e.contains("--true-classes"),
            "{e}"
        );
        // The default protocol (car, truck) against the own-class model lists its classes.
        let e = format!(
            "{:#}",
            Protocol::default().for_model(&own, "own.onnx").unwrap_err()
        );
        assert!(e.contains("\"forklift\", \"dog\", \"pallet\""), "{e}");
        // COCO names keep COCO ids (records unchanged) and map by name onto a reordered list.
        let p = Protocol::from_labels("car,truck", Some("person")).unwrap();
        assert_eq!((p.classes.clone(), p.target), (None, Some(0)));
        let m = p.for_model(&["truck", "person", "car"], "three").unwrap();
        assert_eq!((m.true_classes, m.target), (vec![2, 0], Some(1)));
        assert_eq!(p.for_model(&labels::COCO80, "nanodet").unwrap(), p);
    }
}
