//! Host-side box arithmetic with torchvision's exact f32 semantics: `BoxCoder.decode`, clipping,
//! `remove_small_boxes`, `nms` (CPU kernel: strict `IoU > threshold`, stable score order) and
//! `batched_nms` (the coordinate-offset trick up to 1000 boxes, per-class NMS above, as
//! torchvision switches), and the box head's `postprocess_detections`.

/// `log(1000 / 16)`, the clamp of decoded log-size deltas.
pub(crate) const BBOX_XFORM_CLIP: f32 = 4.135_166_6;

/// `BoxCoder.decode_single` of one delta `[dx, dy, dw, dh]` on one box, with weights `wts`.
pub fn decode(b: &[f32; 4], d: &[f32], wts: [f32; 4]) -> [f32; 4] {
    let w = b[2] - b[0];
    let h = b[3] - b[1];
    let cx = b[0] + 0.5 * w;
    let cy = b[1] + 0.5 * h;
    let dx = d[0] / wts[0];
    let dy = d[1] / wts[1];
    let dw = (d[2] / wts[2]).min(BBOX_XFORM_CLIP);
    let dh = (d[3] / wts[3]).min(BBOX_XFORM_CLIP);
    let pcx = dx * w + cx;
    let pcy = dy * h + cy;
    let pw = dw.exp() * w;
    let ph = dh.exp() * h;
    let (hw, hh) = (0.5 * pw, 0.5 * ph);
    [pcx - hw, pcy - hh, pcx + hw, pcy + hh]
}

/// `clip_boxes_to_image` for an image of `(h, w)`.
pub fn clip(b: [f32; 4], size: (usize, usize)) -> [f32; 4] {
    let (h, w) = (size.0 as f32, size.1 as f32);
    [
        b[0].clamp(0.0, w),
        b[1].clamp(0.0, h),
        b[2].clamp(0.0, w),
        b[3].clamp(0.0, h),
    ]
}

/// `remove_small_boxes`: both sides `>= min_size`.
pub(crate) fn big_enough(b: &[f32; 4], min_size: f32) -> bool {
    b[2] - b[0] >= min_size && b[3] - b[1] >= min_size
}

/// torchvision's CPU `nms`: indices kept, by decreasing score (ties: lower index first).
pub fn nms(boxes: &[[f32; 4]], scores: &[f32], iou: f64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
    let areas: Vec<f32> = boxes
        .iter()
        .map(|b| (b[2] - b[0]) * (b[3] - b[1]))
        .collect();
    let mut suppressed = vec![false; boxes.len()];
    let mut keep = Vec::new();
    for (oi, &i) in order.iter().enumerate() {
        if suppressed[i] {
            continue;
        }
        keep.push(i);
        let bi = &boxes[i];
        for &j in &order[oi + 1..] {
            if suppressed[j] {
                continue;
            }
            let bj = &boxes[j];
            let w = (bi[2].min(bj[2]) - bi[0].max(bj[0])).max(0.0);
            let h = (bi[3].min(bj[3]) - bi[1].max(bj[1])).max(0.0);
            let inter = w * h;
            let ovr = inter / (areas[i] + areas[j] - inter);
            if ovr as f64 > iou {
                suppressed[j] = true;
            }
        }
    }
    keep
}

/// torchvision's `batched_nms`: NMS within each `class`, kept indices by decreasing score.
pub(crate) fn batched_nms(
    boxes: &[[f32; 4]],
    scores: &[f32],
    class: &[usize],
    iou: f64,
) -> Vec<usize> {
    if boxes.is_empty() {
        return vec![];
    }
    if boxes.len() * 4 <= 4000 {
        // Coordinate trick: offset each class by (max coordinate + 1) · class.
        let max = boxes
            .iter()
            .flatten()
            .copied()
            .fold(f32::NEG_INFINITY, f32::max);
        let shifted: Vec<[f32; 4]> = boxes
            .iter()
            .zip(class)
            .map(|(b, &c)| {
                let o = c as f32 * (max + 1.0);
                b.map(|v| v + o)
            })
            .collect();
        return nms(&shifted, scores, iou);
    }
    let mut keep = Vec::new();
    let mut classes: Vec<usize> = class.to_vec();
    classes.sort_unstable();
    classes.dedup();
    for c in classes {
        let idx: Vec<usize> = (0..boxes.len()).filter(|&i| class[i] == c).collect();
        let b: Vec<[f32; 4]> = idx.iter().map(|&i| boxes[i]).collect();
        let s: Vec<f32> = idx.iter().map(|&i| scores[i]).collect();
        keep.extend(nms(&b, &s, iou).into_iter().map(|k| idx[k]));
    }
    keep.sort_unstable();
    keep.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
    keep
}

/// Softmax of one row as PyTorch's CPU kernel computes it (max shift, sum, times 1 / sum).
pub fn softmax(z: &[f32]) -> Vec<f32> {
    let m = z.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let e: Vec<f32> = z.iter().map(|&v| (v - m).exp()).collect();
    let inv = 1.0 / e.iter().sum::<f32>();
    e.iter().map(|&v| v * inv).collect()
}

/// One final detection in network-input (resized) coordinates: box, score, 1..=90 category.
#[derive(Clone, Debug, PartialEq)]
pub struct RawDetection {
    pub bbox: [f32; 4],
    pub score: f32,
    pub label: usize,
}

/// Thresholds of the box head's post-processing.
#[derive(Clone, Copy, Debug)]
pub struct BoxPost {
    pub score_thresh: f32,
    pub nms_thresh: f64,
    pub detections_per_img: usize,
}

/// `RoIHeads.postprocess_detections` for one image: `logits` `[R, K]`, `regression` `[R, 4K]`.
pub fn detections(
    proposals: &[[f32; 4]],
    logits: &[f32],
    regression: &[f32],
    classes: usize,
    size: (usize, usize),
    cfg: BoxPost,
) -> Vec<RawDetection> {
    let mut boxes = Vec::new();
    let mut scores = Vec::new();
    let mut labels = Vec::new();
    for (r, p) in proposals.iter().enumerate() {
        let s = softmax(&logits[r * classes..(r + 1) * classes]);
        for c in 1..classes {
            let d = &regression[(r * classes + c) * 4..(r * classes + c) * 4 + 4];
            let b = clip(decode(p, d, [10.0, 10.0, 5.0, 5.0]), size);
            if s[c] > cfg.score_thresh && big_enough(&b, 1e-2) {
                boxes.push(b);
                scores.push(s[c]);
                labels.push(c);
            }
        }
    }
    let mut keep = batched_nms(&boxes, &scores, &labels, cfg.nms_thresh);
    keep.truncate(cfg.detections_per_img);
    keep.into_iter()
        .map(|i| RawDetection {
            bbox: boxes[i],
            score: scores[i],
            label: labels[i],
        })
        .collect()
}

/// `resize_boxes`: from the resized `(h, w)` back to the original `(h, w)`.
pub(crate) fn resize_box(
    b: [f32; 4],
    resized: (usize, usize),
    original: (usize, usize),
) -> [f32; 4] {
    let rh = original.0 as f32 / resized.0 as f32;
    let rw = original.1 as f32 / resized.1 as f32;
    [b[0] * rw, b[1] * rh, b[2] * rw, b[3] * rh]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nms_is_strict_and_batched_nms_separates_classes() {
        let b = [
            [0.0, 0.0, 10.0, 10.0],
            [0.0, 0.0, 10.0, 5.0],
            [50.0, 50.0, 60.0, 60.0],
        ];
        // IoU of the first two is exactly 0.5: kept at threshold 0.5 (strict >).
        assert_eq!(nms(&b, &[0.9, 0.8, 0.7], 0.5), vec![0, 1, 2]);
        assert_eq!(nms(&b, &[0.9, 0.8, 0.7], 0.4), vec![0, 2]);
        assert_eq!(
            batched_nms(&b, &[0.9, 0.8, 0.7], &[1, 2, 1], 0.4),
            vec![0, 1, 2]
        );
        assert!(batched_nms(&[], &[], &[], 0.5).is_empty());
    }

    #[test]
    fn decode_clamps_huge_deltas() {
        let b = decode(
            &[0.0, 0.0, 10.0, 10.0],
            &[0.0, 0.0, 1e6, f32::MAX],
            [1.0; 4],
        );
        assert!(b.iter().all(|v| v.is_finite()));
        let s = softmax(&[1e4, -1e4, 0.0]);
        assert!(s.iter().all(|v| v.is_finite()) && (s[0] - 1.0).abs() < 1e-6);
    }
}
