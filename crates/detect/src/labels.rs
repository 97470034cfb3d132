//! The 80 COCO class names in the standard detector order (0 = person … 79 = toothbrush).
//!
//! Identical to the `LABELS` of the TFJS reference runner and to `@vladmandic/human`'s labels.
//! A user's own detector names its own classes ([`crate::detector::Detector::classes`]): every
//! class a user names (target, hidden classes, true classes, the class to explain) is resolved
//! against the model's list by [`resolve`], by name, so the models of an ensemble may order or
//! name their classes differently.

use anyhow::{bail, Result};

/// COCO-80 labels, indexed by the 0-based class id both detectors output.
pub const COCO80: [&str; 80] = [
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "airplane",
    "bus",
    "train",
    "truck",
    "boat",
    "traffic light",
    "fire hydrant",
    "stop sign",
    "parking meter",
    "bench",
    "bird",
    "cat",
    "dog",
    "horse",
    "sheep",
    "cow",
    "elephant",
    "bear",
    "zebra",
    "giraffe",
    "backpack",
    "umbrella",
    "handbag",
    "tie",
    "suitcase",
    "frisbee",
    "skis",
    "snowboard",
    "sports ball",
    "kite",
    "baseball bat",
    "baseball glove",
    "skateboard",
    "surfboard",
    "tennis racket",
    "bottle",
    "wine glass",
    "cup",
    "fork",
    "knife",
    "spoon",
    "bowl",
    "banana",
    "apple",
    "sandwich",
    "orange",
    "broccoli",
    "carrot",
    "hot dog",
    "pizza",
    "donut",
    "cake",
    "chair",
    "couch",
    "potted plant",
    "bed",
    "dining table",
    "toilet",
    "tv",
    "laptop",
    "mouse",
    "remote",
    "keyboard",
    "cell phone",
    "microwave",
    "oven",
    "toaster",
    "sink",
    "refrigerator",
    "book",
    "clock",
    "vase",
    "scissors",
    "teddy bear",
    "hair drier",
    "toothbrush",
];

/// The 0-based id of a COCO label, if it is one.
pub fn class_id(label: &str) -> Option<usize> {
    COCO80.iter().position(|l| *l == label)
}

/// The index of class `label` in a model's class list `classes`; the error names `model`, the
/// label and the classes it has (COCO-80 models: a few examples of the 80 labels).
pub fn resolve(label: &str, classes: &[&str], model: &str) -> Result<usize> {
    if let Some(i) = classes.iter().position(|c| *c == label) {
        return Ok(i);
    }
    // The same name in another case, when only one class matches it ("Forklift", "PERSON").
    let folded: Vec<usize> = (0..classes.len())
        .filter(|&i| classes[i].eq_ignore_ascii_case(label))
        .collect();
    if let [i] = folded[..] {
        return Ok(i);
    }
    if is_coco80(classes) {
        bail!(
            "{model} has no class {label:?}: it detects the 80 COCO classes (labels such as \"person\", \"car\", \"stop sign\")"
        );
    }
    bail!(
        "{model} has no class {label:?}: its {} classes are {}",
        classes.len(),
        classes
            .iter()
            .map(|c| format!("{c:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// Whether `classes` is the COCO-80 list in its standard order.
pub fn is_coco80(classes: &[&str]) -> bool {
    classes.len() == 80 && classes.iter().zip(COCO80).all(|(a, b)| *a == b)
}

/// torchvision's 91 COCO category names (`_COCO_CATEGORIES`): index = category id as the
/// Faster R-CNN models output it, 0 = background, "N/A" for the ids COCO never used.
pub(crate) const COCO91: [&str; 91] = [
    "__background__",
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "airplane",
    "bus",
    "train",
    "truck",
    "boat",
    "traffic light",
    "fire hydrant",
    "N/A",
    "stop sign",
    "parking meter",
    "bench",
    "bird",
    "cat",
    "dog",
    "horse",
    "sheep",
    "cow",
    "elephant",
    "bear",
    "zebra",
    "giraffe",
    "N/A",
    "backpack",
    "umbrella",
    "N/A",
    "N/A",
    "handbag",
    "tie",
    "suitcase",
    "frisbee",
    "skis",
    "snowboard",
    "sports ball",
    "kite",
    "baseball bat",
    "baseball glove",
    "skateboard",
    "surfboard",
    "tennis racket",
    "bottle",
    "N/A",
    "wine glass",
    "cup",
    "fork",
    "knife",
    "spoon",
    "bowl",
    "banana",
    "apple",
    "sandwich",
    "orange",
    "broccoli",
    "carrot",
    "hot dog",
    "pizza",
    "donut",
    "cake",
    "chair",
    "couch",
    "potted plant",
    "bed",
    "N/A",
    "dining table",
    "N/A",
    "N/A",
    "toilet",
    "N/A",
    "tv",
    "laptop",
    "mouse",
    "remote",
    "keyboard",
    "cell phone",
    "microwave",
    "oven",
    "toaster",
    "sink",
    "refrigerator",
    "N/A",
    "book",
    "clock",
    "vase",
    "scissors",
    "teddy bear",
    "hair drier",
    "toothbrush",
];

/// The COCO-80 id of a 91-category id (None for background and "N/A").
pub(crate) fn coco91_to_80(category: usize) -> Option<usize> {
    COCO91.get(category).and_then(|l| class_id(l))
}

/// The 91-category id of each COCO-80 id.
pub fn coco80_to_91() -> [usize; 80] {
    let mut out = [0usize; 80];
    for (c91, l) in COCO91.iter().enumerate() {
        if let Some(c80) = class_id(l) {
            out[c80] = c91;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coco91_covers_the_80_classes_in_order() {
        let m = coco80_to_91();
        assert!(m.windows(2).all(|w| w[0] < w[1]));
        assert_eq!((m[0], m[79]), (1, 90));
        assert_eq!(coco91_to_80(12), None);
        assert_eq!(coco91_to_80(13), Some(11)); // stop sign
    }

    #[test]
    fn a_class_is_resolved_by_name_and_a_missing_one_lists_the_model_s_classes() {
        let own = ["forklift", "dog", "pallet"];
        assert_eq!(resolve("dog", &own, "m").unwrap(), 1);
        assert_eq!(resolve("Pallet", &own, "m").unwrap(), 2);
        let e = resolve("person", &own, "yolo.onnx")
            .unwrap_err()
            .to_string();
        assert!(e.contains("yolo.onnx") && e.contains("\"person\""), "{e}");
        assert!(e.contains("\"forklift\", \"dog\", \"pallet\""), "{e}");
        assert_eq!(resolve("stop sign", &COCO80, "m").unwrap(), 11);
        let e = resolve("forklift", &COCO80, "nanodet")
            .unwrap_err()
            .to_string();
        assert!(e.contains("80 COCO classes"), "{e}");
        // Two classes differing only in case: the exact name only.
        assert!(resolve("A", &["a", "A"], "m").unwrap() == 1);
        assert!(resolve("B", &["a", "b"], "m").unwrap() == 1);
        assert!(resolve("x", &["X", "x2", "X"], "m").is_err());
    }
}
