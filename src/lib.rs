//! # cac — coated adversarial camouflage
//!
//! A toolkit that learns, fabricates and physically tests full-coverage adversarial textures for
//! 3D objects. The pipeline is a chain of small stages, each a module with one job; data flows
//! forward only. A module names only modules of an earlier rank (modules joined by `/` share one
//! and do not name each other; `tests/import_graph.rs` checks it against this line):
//!
//! `io` / `memory` / `report` → `scene` → `render` → `environment` → `config` → `detect` → `attack` / `eval` → `export` / `physical` / `study` → `sim` / `video`
//!
//! `io`, `memory` and `report` are the shared floor (files, the memory budget, tables, plots, HTML,
//! drawn labels); `config`
//! holds the scene config and the named presets; `study` holds the experiments that train with
//! `attack` and judge with `eval` (the studies, the demo, the attack benchmark); `sim` is the
//! simulated turntable firmware that `physical`'s driver talks to, and the simulated rig around it; `video` scores recordings
//! with the detectors and the protocol.
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
pub mod memory;
pub mod physical;
pub mod render;
pub mod report;
pub mod scene;
pub mod sim;
pub mod study;
pub mod video;
