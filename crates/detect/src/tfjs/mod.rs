//! A general importer for TensorFlow.js graph models (`model.json` + weight shards) that runs
//! the graph as burn tensor ops: [`model`] reads the files, [`value`] holds the values and
//! resolved nodes, [`graph`] plans and executes, [`ops`] holds the TF op semantics, [`fuse`]
//! rewrites elementwise chains into fewer ops. `graph` uses `ops` and `fuse`; they use only
//! `value` and `model` (no circle).
//!
//! It supports the ops used by common MobileNet/CSP-style detectors (see `ops.rs`); any other
//! op is reported with the node's name when a requested output depends on it.

pub mod fuse;
pub mod graph;
pub mod model;
pub mod ops;
pub mod value;

pub use graph::Graph;
pub use model::{GraphModel, HostData, HostTensor};
pub use value::{FloatValue, Value};

use anyhow::Result;
use burn::tensor::Device;
use std::path::Path;

/// Loads `json_path` (and its weights) and prepares it to run on `device`.
pub fn load_graph(json_path: &Path, device: &Device) -> Result<Graph> {
    Graph::new(GraphModel::load(json_path)?, device)
}
