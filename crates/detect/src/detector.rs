//! The interface the attack and the evaluation use: a [`Detector`] gives dense pre-NMS
//! [`Candidates`] (differentiable) and final [`Detection`]s for a `[B, 3, H, W]` image batch;
//! [`CamGraph`] and [`CamIo`] open a graph detector's feature maps to Grad-CAM.

use crate::{labels, raw};
use anyhow::Result;
use burn::tensor::{Device, Tensor};

/// Dense pre-NMS candidates: one row per anchor location (all classes scored).
#[derive(Clone, Debug)]
pub struct Candidates {
    /// `[B, N, 4]` boxes `x1, y1, x2, y2` in input-image pixels.
    pub boxes: Tensor<3>,
    /// `[B, N, C]` per-class probabilities (independent sigmoids, not a softmax); C = 80 for
    /// COCO models, the model's own class count otherwise ([`Detector::classes`]).
    pub scores: Tensor<3>,
    /// `[B, N, C]` the pre-sigmoid logits of `scores` (use log-sigmoid for stable losses).
    pub logits: Tensor<3>,
}

/// One final detection.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Detection {
    /// 0-based class id in the model's class list ([`Detector::classes`]; COCO-80 for the
    /// built-in detectors).
    pub class_id: usize,
    pub label: &'static str,
    pub score: f32,
    /// `x1, y1, x2, y2` in input-image pixels.
    pub bbox: [f32; 4],
}

impl Detection {
    /// `cac detect`'s line for this detection in `image`: `image: label score [x1, y1, x2, y2]`,
    /// or with `json` one object `{image, label, class_id, score, box}`.
    pub fn line(&self, image: &str, json: bool) -> String {
        let [x1, y1, x2, y2] = self.bbox;
        if json {
            let (label, class_id, score) = (self.label, self.class_id, self.score);
            serde_json::json!({"image": image, "label": label, "class_id": class_id,
                "score": score, "box": self.bbox})
            .to_string()
        } else {
            let (label, score) = (self.label, self.score);
            format!("{image}: {label} {score:.3} [{x1:.1}, {y1:.1}, {x2:.1}, {y2:.1}]")
        }
    }
}

/// A detector's graph as attention maps (Grad-CAM) need it: the graph, its inputs for one image
/// batch, the outputs holding the pre-sigmoid class logits, and a default layer.
pub struct CamIo<'a> {
    pub graph: &'a dyn CamGraph,
    /// Graph inputs (placeholder name, pre-processed network input).
    pub feeds: Vec<(String, Tensor<4>)>,
    /// Graph values of class logits, each with the logical axis of its classes and the index
    /// of class 0 on that axis (0, or 5 where box and objectness come first: YOLOv5's head).
    pub logits: Vec<(String, usize, usize)>,
    /// The default layer: a late feature map of good spatial resolution.
    pub default_layer: String,
}

/// What Grad-CAM needs of a graph, whichever format it came from (TFJS, ONNX): its layers, a
/// run that returns float values, and a run with one layer's output replaced (an autodiff leaf,
/// so the gradient of the class score with respect to that layer can be taken).
pub trait CamGraph {
    /// The device the graph's constants live on.
    fn device(&self) -> Device;
    /// `(name, op type)` of the nodes `outputs` depend on whose output can be a feature map
    /// (convolutions, activations, sums, products, concatenations), in graph order.
    fn feature_layers(&self, outputs: &[&str]) -> Result<Vec<(String, String)>>;
    /// Runs the graph on `feeds` (graph input name, value), `inject` replacing the output of one
    /// layer (name, value in that layer's logical layout and shape), and returns `outputs` as
    /// float tensors padded to rank 4 with their logical shapes (rank <= 4).
    fn run_cam(
        &self,
        feeds: &[(&str, Tensor<4>)],
        inject: Option<(&str, Tensor<4>, &[usize])>,
        outputs: &[&str],
    ) -> Result<Vec<(Tensor<4>, Vec<usize>)>>;
    /// The channel axis of a `[1, a, b, c]` feature map, None when it is not one (a square grid
    /// is expected: NHWC when `a == b`, NCHW when `b == c`).
    fn channel_axis(&self, shape: &[usize]) -> Option<usize> {
        match shape {
            [1, a, b, _] if a == b => Some(3),
            [1, _, b, c] if b == c => Some(1),
            _ => None,
        }
    }
}

/// A differentiable object detector. Object-safe.
pub trait Detector {
    fn name(&self) -> &str;
    /// The names of the classes, indexed by the class axis of [`Candidates`] and by
    /// [`Detection::class_id`]: COCO-80 for the built-in detectors, a user's own for an ONNX
    /// model trained on them. Classes are named by the user and matched by name
    /// ([`labels::resolve`]).
    fn classes(&self) -> &[&'static str] {
        &labels::COCO80
    }
    /// `(width, height)` of the network input.
    fn input_size(&self) -> (usize, usize);
    /// Dense pre-NMS candidates of `images` (`[B, 3, H, W]` in [0, 1], any H, W).
    /// Differentiable with respect to `images` when it is an autodiff tensor.
    fn candidates(&self, images: Tensor<4>) -> Result<Candidates>;
    /// Final detections per image, in the input image's pixel coordinates.
    fn detect(&self, images: Tensor<4>) -> Result<Vec<Vec<Detection>>>;
    /// The raw graph outputs for one image, in the TFJS reference runner's `--raw` schema.
    fn raw(&self, image: Tensor<4>) -> Result<raw::RawDump>;
    /// The graph view for attention maps of `images`; `None` when the detector has none.
    fn cam_io(&self, _images: Tensor<4>) -> Result<Option<CamIo<'_>>> {
        Ok(None)
    }
}

/// Checks an image batch is `[B, 3, H, W]` with B, H, W > 0.
pub(crate) fn check_images(images: &Tensor<4>) -> Result<[usize; 4]> {
    let d = images.dims();
    if d[1] != 3 || d[0] == 0 || d[2] == 0 || d[3] == 0 {
        anyhow::bail!(
            "images must be [B, 3, H, W] with B, H, W > 0 (RGB in [0, 1]); got {:?}",
            d
        );
    }
    Ok(d)
}
