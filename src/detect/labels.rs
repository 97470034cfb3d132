//! The 80 COCO class names in the standard detector order (0 = person … 79 = toothbrush).
//!
//! Identical to the `LABELS` of the TFJS reference runner and to `@vladmandic/human`'s labels.

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

/// torchvision's 91 COCO category names (`_COCO_CATEGORIES`): index = category id as the
/// Faster R-CNN models output it, 0 = background, "N/A" for the ids COCO never used.
pub const COCO91: [&str; 91] = [
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
pub fn coco91_to_80(category: usize) -> Option<usize> {
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
}
