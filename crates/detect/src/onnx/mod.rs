//! Users' own detectors as ONNX files (YOLOv3/v5/v8/11 exports, torchvision's and mmdeploy's
//! dense exports), run by cac's own differentiable executor: [`proto`] declares the ONNX protobuf
//! schema for `prost`, [`model`] reads a file into plain values, [`value`] holds the edge values,
//! [`args`] is what an op reads, [`ops`] dispatches to [`elementwise`], [`shape`], [`nn`] and
//! [`transformer`] (the op semantics as burn ops), [`graph`] plans and runs, [`config`] is the
//! TOML config and the `onnx:` spec, and [`detector`] the [`crate::detector::Detector`] with its heads.
//! Where the edge enabled it, [`runtime`] runs the forward passes that need no gradient in
//! onnxruntime instead.
//!
//! The TFJS importer ([`crate::tfjs`]) is the other executor, of the same design; both
//! lower their graphs to burn tensor ops on the caller's device and share pre-processing, NMS,
//! labels, `detect::kernels` and Grad-CAM's `CamGraph`. They keep separate op tables because the
//! two formats disagree on layout (TF's NHWC, ONNX's NCHW) and on op semantics (padding, resize
//! coordinates, split forms). Not here: training graphs, control flow (If/Loop/Scan), quantised ops, sequence types.

pub mod args;
pub mod config;
pub mod detector;
pub mod elementwise;
pub mod graph;
pub mod model;
pub mod nn;
pub mod ops;
pub mod proto;
pub mod runtime;
pub mod shape;
pub mod transformer;
pub mod value;

pub use config::{parse_spec, OnnxConfig};
pub use detector::{Engine, OnnxDetector};
pub use graph::OnnxGraph;
pub use model::Model;
pub use value::{Dev, Host, Val};

use anyhow::Result;
use burn::tensor::Device;
use std::path::Path;

/// Loads `path` and prepares it to run on `device`.
pub fn load_graph(path: &Path, device: &Device) -> Result<OnnxGraph> {
    OnnxGraph::new(Model::load(path)?, device)
}
