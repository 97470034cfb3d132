//! torchvision's `TwoMLPHead` (fc6, fc7 with ReLU) and `FastRCNNPredictor` (class logits over
//! the 91 COCO categories, background first, and per-class box deltas).

use super::layers::Linear;
use super::weights::Loader;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

pub(crate) const REPRESENTATION: usize = 1024;

pub(crate) struct BoxHead {
    fc6: Linear,
    fc7: Linear,
    cls: Linear,
    bbox: Linear,
}

impl BoxHead {
    pub fn load(l: &mut Loader, input: usize, classes: usize, dev: &Device) -> Self {
        BoxHead {
            fc6: Linear::load(l, "roi_heads.box_head.fc6", input, REPRESENTATION, dev),
            fc7: Linear::load(
                l,
                "roi_heads.box_head.fc7",
                REPRESENTATION,
                REPRESENTATION,
                dev,
            ),
            cls: Linear::load(
                l,
                "roi_heads.box_predictor.cls_score",
                REPRESENTATION,
                classes,
                dev,
            ),
            bbox: Linear::load(
                l,
                "roi_heads.box_predictor.bbox_pred",
                REPRESENTATION,
                classes * 4,
                dev,
            ),
        }
    }

    /// `(class logits [N, K], box regression [N, 4K])` of pooled features `[N, C·49]`.
    pub fn forward(&self, x: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
        let x = relu(self.fc6.forward(x));
        let x = relu(self.fc7.forward(x));
        (self.cls.forward(x.clone()), self.bbox.forward(x))
    }
}
