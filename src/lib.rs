//! # cac — coated adversarial camouflage
//!
//! A toolkit that learns, fabricates and physically tests full-coverage adversarial textures for
//! 3D objects. The pipeline is a chain of small stages, each a module with one job; data flows
//! forward only:
//!
//! `scene` → `render` → `environment` → `detect` → `attack` / `eval` → `export` / `physical`.
//!
//! Library code never names a concrete compute backend: tensors live on a [`burn::tensor::Device`]
//! chosen once at the edge (the `cac` binary, the tests, the benchmarks).

pub mod attack;
pub mod config;
pub mod detect;
pub mod environment;
pub mod eval;
pub mod export;
pub mod io;
pub mod physical;
pub mod render;
pub mod report;
pub mod scene;
pub mod sim;
pub mod video;
