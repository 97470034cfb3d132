//! torchvision's region proposal network at inference: the shared `RPNHead` (3×3 conv + ReLU,
//! 1×1 objectness and box-delta convs) on every FPN level, then `filter_proposals` on the host:
//! decode, top-n per level by objectness, sigmoid, clip, small-box and score filters, NMS per
//! level, top-n overall. The proposals carry no gradient (torchvision detaches them too).

use super::anchors;
use super::layers::{Conv, ConvShape};
use super::postprocess::{batched_nms, big_enough, clip, decode};
use super::weights::Loader;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

pub(crate) struct RpnHead {
    conv: Conv,
    cls: Conv,
    bbox: Conv,
}

/// Proposal filtering settings (torchvision's test-time values per model).
#[derive(Clone, Copy, Debug)]
pub struct RpnConfig {
    pub pre_nms_top_n: usize,
    pub post_nms_top_n: usize,
    pub nms_thresh: f64,
    pub score_thresh: f32,
    pub min_size: f32,
}

/// The head's outputs of one level on the host, torchvision's `(h, w, anchor)` order.
pub struct LevelOutput {
    pub grid: (usize, usize),
    /// `[B][H·W·A]` objectness logits.
    pub objectness: Vec<Vec<f32>>,
    /// `[B][H·W·A·4]` box deltas.
    pub deltas: Vec<Vec<f32>>,
}

impl RpnHead {
    pub fn load(l: &mut Loader, p: &str, channels: usize, anchors: usize, dev: &Device) -> Self {
        RpnHead {
            conv: Conv::load(
                l,
                &format!("{p}.conv.0.0"),
                ConvShape::new(channels, channels, 3, 1),
                true,
                dev,
            ),
            cls: Conv::load(
                l,
                &format!("{p}.cls_logits"),
                ConvShape::new(channels, anchors, 1, 1),
                true,
                dev,
            ),
            bbox: Conv::load(
                l,
                &format!("{p}.bbox_pred"),
                ConvShape::new(channels, anchors * 4, 1, 1),
                true,
                dev,
            ),
        }
    }

    /// Runs the head on every level and copies the outputs to the host.
    pub fn forward(&self, features: &[Tensor<4>]) -> anyhow::Result<Vec<LevelOutput>> {
        features
            .iter()
            .map(|f| {
                let t = relu(self.conv.forward(f.clone()));
                let obj = self.cls.forward(t.clone());
                let del = self.bbox.forward(t);
                let [b, a, h, w] = obj.dims();
                let obj = obj.permute([0, 2, 3, 1]);
                let del = del.reshape([b, a, 4, h, w]).permute([0, 3, 4, 1, 2]);
                let (o, d) = (crate::host::to_vec(&obj)?, crate::host::to_vec(&del)?);
                let n = h * w * a;
                Ok(LevelOutput {
                    grid: (h, w),
                    objectness: (0..b).map(|i| o[i * n..(i + 1) * n].to_vec()).collect(),
                    deltas: (0..b)
                        .map(|i| d[i * n * 4..(i + 1) * n * 4].to_vec())
                        .collect(),
                })
            })
            .collect()
    }
}

/// `1 / (1 + exp(−x))` in f32.
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// `filter_proposals` for image `i` of the batch: proposals `[x1, y1, x2, y2]` in resized-image
/// pixels, by decreasing objectness.
pub fn proposals(
    levels: &[LevelOutput],
    cells: &[Vec<[f32; 4]>],
    i: usize,
    resized: (usize, usize),
    padded: (usize, usize),
    cfg: RpnConfig,
) -> Vec<[f32; 4]> {
    let mut boxes = Vec::new();
    let mut scores = Vec::new();
    let mut lvl = Vec::new();
    for (l, (out, cell)) in levels.iter().zip(cells).enumerate() {
        let anchors = anchors::grid_anchors(cell, out.grid, padded);
        let obj = &out.objectness[i];
        // topk: descending, ties to the lower index.
        let mut order: Vec<usize> = (0..obj.len()).collect();
        order.sort_by(|&a, &b| obj[b].total_cmp(&obj[a]));
        order.truncate(cfg.pre_nms_top_n.min(obj.len()));
        for k in order {
            let b = decode(&anchors[k], &out.deltas[i][k * 4..k * 4 + 4], [1.0; 4]);
            let b = clip(b, resized);
            let s = sigmoid(obj[k]);
            if big_enough(&b, cfg.min_size) && s >= cfg.score_thresh {
                boxes.push(b);
                scores.push(s);
                lvl.push(l);
            }
        }
    }
    let mut keep = batched_nms(&boxes, &scores, &lvl, cfg.nms_thresh);
    keep.truncate(cfg.post_nms_top_n);
    keep.into_iter().map(|k| boxes[k]).collect()
}
