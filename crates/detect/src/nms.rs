//! Greedy non-maximum suppression with the exact semantics of TensorFlow.js
//! (`tf.image.nonMaxSuppressionAsync`, `non_max_suppression_impl.js`).
//!
//! Not differentiable and not batched: it works on host `f32` boxes of one image.

/// Indices of the kept boxes, in selection order.
///
/// * `boxes` are `[y1, x1, y2, x2]` (any corner order: min/max are taken per axis, as tfjs does).
/// * A candidate needs `score > score_threshold` (strictly; the f32 score is compared in f64).
/// * Candidates are visited by descending score, ties to the lower index first.
/// * A candidate is dropped when its IoU with any already selected box is `>= iou_threshold`
///   (compared from the latest selection backwards, which does not change the result).
pub fn non_max_suppression(
    boxes: &[[f32; 4]],
    scores: &[f32],
    max_output: usize,
    iou_threshold: f64,
    score_threshold: f64,
) -> Vec<usize> {
    greedy(
        boxes,
        scores,
        max_output,
        iou_threshold,
        score_threshold,
        |_, _| true,
    )
}

/// [`non_max_suppression`] within each class: a box suppresses only boxes of its own class
/// (`classes[i]`), ranked by score over all classes and cut at `max_output`, as ultralytics'
/// class-offset NMS does but without moving the boxes (an offset of class × 1e5 rounds f32
/// coordinates to a quarter pixel by class 28, enough to flip a decision near the threshold).
pub fn class_aware_nms(
    boxes: &[[f32; 4]],
    scores: &[f32],
    classes: &[usize],
    max_output: usize,
    iou_threshold: f64,
    score_threshold: f64,
) -> Vec<usize> {
    assert_eq!(boxes.len(), classes.len(), "one class per box");
    let same_class = |i: usize, j: usize| classes[i] == classes[j];
    greedy(
        boxes,
        scores,
        max_output,
        iou_threshold,
        score_threshold,
        same_class,
    )
}

/// The greedy selection both share: candidates above `score_threshold` by descending score (ties
/// to the lower index), each kept unless a selected box it `competes` with overlaps it by
/// `iou_threshold` or more, until `max_output` are kept.
fn greedy(
    boxes: &[[f32; 4]],
    scores: &[f32],
    max_output: usize,
    iou_threshold: f64,
    score_threshold: f64,
    competes: impl Fn(usize, usize) -> bool,
) -> Vec<usize> {
    assert_eq!(boxes.len(), scores.len(), "one score per box");
    let mut order: Vec<usize> = (0..scores.len())
        .filter(|&i| scores[i] as f64 > score_threshold)
        .collect();
    // Stable sort: equal scores keep ascending index order.
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
    let mut selected: Vec<usize> = Vec::new();
    for i in order {
        if selected.len() >= max_output {
            break;
        }
        let suppressed = (selected.iter().rev())
            .any(|&j| competes(i, j) && iou(&boxes[i], &boxes[j]) >= iou_threshold);
        if !suppressed {
            selected.push(i);
        }
    }
    selected
}

/// Intersection over union as tfjs computes it (f32 inputs, arithmetic in f64 like JS numbers).
pub fn iou(a: &[f32; 4], b: &[f32; 4]) -> f64 {
    let a: [f64; 4] = a.map(f64::from);
    let b: [f64; 4] = b.map(f64::from);
    let (ay1, ax1, ay2, ax2) = (
        a[0].min(a[2]),
        a[1].min(a[3]),
        a[0].max(a[2]),
        a[1].max(a[3]),
    );
    let (by1, bx1, by2, bx2) = (
        b[0].min(b[2]),
        b[1].min(b[3]),
        b[0].max(b[2]),
        b[1].max(b[3]),
    );
    let area_a = (ay2 - ay1) * (ax2 - ax1);
    let area_b = (by2 - by1) * (bx2 - bx1);
    if area_a <= 0.0 || area_b <= 0.0 {
        return 0.0;
    }
    let iy1 = ay1.max(by1);
    let ix1 = ax1.max(bx1);
    let iy2 = ay2.min(by2);
    let ix2 = ax2.min(bx2);
    let inter = (iy2 - iy1).max(0.0) * (ix2 - ix1).max(0.0);
    inter / (area_a + area_b - inter)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suppresses_overlaps_keeps_disjoint_and_respects_threshold() {
        let boxes = [
            [0.0, 0.0, 10.0, 10.0],
            [0.0, 0.0, 10.0, 9.0],
            [20.0, 20.0, 30.0, 30.0],
            [50.0, 50.0, 60.0, 60.0],
        ];
        let scores = [0.9, 0.95, 0.5, 0.19];
        let keep = non_max_suppression(&boxes, &scores, 10, 0.4, 0.2);
        assert_eq!(keep, vec![1, 2]); // 0 overlaps 1; 3 is not > 0.2
                                      // f32 0.2 is 0.200000003 > 0.2 (f64): it passes, as in tfjs.
        assert_eq!(
            non_max_suppression(&boxes[3..], &[0.2], 10, 0.4, 0.2),
            vec![0]
        );
    }

    #[test]
    fn ties_go_to_the_lower_index_and_max_output_stops() {
        let boxes = [
            [0.0, 0.0, 1.0, 1.0],
            [5.0, 5.0, 6.0, 6.0],
            [9.0, 9.0, 10.0, 10.0],
        ];
        let scores = [0.5, 0.5, 0.5];
        assert_eq!(
            non_max_suppression(&boxes, &scores, 2, 0.4, 0.0),
            vec![0, 1]
        );
    }

    #[test]
    fn degenerate_boxes_never_suppress() {
        let boxes = [[0.0, 0.0, 0.0, 10.0], [0.0, 0.0, 0.0, 10.0]];
        assert_eq!(
            non_max_suppression(&boxes, &[0.9, 0.8], 10, 0.4, 0.0),
            vec![0, 1]
        );
    }

    #[test]
    fn class_aware_nms_keeps_classes_apart_without_rounding_their_boxes() {
        // Two boxes of class 28, 10 px wide and 3.82 px apart: IoU 6.18 / 13.82 = 0.447, kept at
        // a 0.45 threshold. Offset by 28 × 1e5 in f32 (a quarter-pixel grid there) they would be
        // 3.75 px apart (IoU 0.4545) and suppressed.
        let a = [0.0, 0.13, 10.0, 10.13];
        let b = [0.0, 3.95, 10.0, 13.95];
        assert!(iou(&a, &b) < 0.45);
        let shift = |x: [f32; 4]| x.map(|v| v + 28.0 * 1e5);
        assert!(
            iou(&shift(a), &shift(b)) >= 0.45,
            "the hazard this guards against"
        );
        let keep = class_aware_nms(&[a, b], &[0.9, 0.8], &[28, 28], 10, 0.45, 0.0);
        assert_eq!(keep, vec![0, 1]);
        // The same box in two classes: both kept; a third of the first class suppressed; the
        // score order across classes decides what max_output keeps.
        let boxes = [a, a, a];
        let keep = class_aware_nms(&boxes, &[0.7, 0.9, 0.6], &[1, 2, 1], 10, 0.45, 0.0);
        assert_eq!(keep, vec![1, 0]);
        let keep = class_aware_nms(&boxes, &[0.7, 0.9, 0.6], &[1, 2, 1], 1, 0.45, 0.0);
        assert_eq!(keep, vec![1]);
    }
}
