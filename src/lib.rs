//! # cac — coated adversarial camouflage
//!
//! A toolkit that learns, fabricates and physically tests full-coverage adversarial textures for
//! 3D objects. The pipeline is a chain of small stages, each a module with one job; data flows
//! forward only. A module names only modules of an earlier rank (modules joined by `/` share one
//! and do not name each other; `tests/import_graph.rs` checks it against this line):
//!
//! `memory` / `colour` / `choice` → `io` / `report` / `printer` → `scene` → `render` → `environment` → `config` → `detect` → `attack` → `eval` → `export` / `physical` / `study` → `sim` / `video` → `bench`
//!
//! `memory`, `colour`, `choice`, `io`, `report` and `printer` are the shared floor (the memory budget; sRGB,
//! CIELAB and ΔE2000; settings with named values; files, which register their temporaries with the budget's guard; tables,
//! plots, HTML, drawn labels; printer models); `config`
//! holds the scene config and the named presets; `study` holds the experiments that train with
//! `attack` and judge with `eval` (the studies, the demo); `bench` holds the benchmarks; `sim` is the
//! simulated turntable firmware that `physical`'s driver talks to, and the simulated rig around it; `video` scores recordings
//! with the detectors and the protocol.
//!
//! The stages live in the workspace's crates (`crates/`, see `docs/pipeline.md`): `cac-core`
//! (`memory`, `colour`, `choice`, `io`, `report`, `printer`), `cac-scene`, `cac-render` (`render`, `environment`, `config`),
//! `cac-detect`, `cac-export`, `cac-attack` (`attack`), `cac-eval` (`eval`, `study`), `cac-physical`
//! (`physical`, `sim`), `cac-video` and `cac-bench` (`bench`: the benchmarks, after every stage); this crate re-exports each module under the name above
//! and holds the `cac` binary.
//!
//! Library code never names a concrete compute backend: tensors live on a [`burn::tensor::Device`]
//! chosen once at the edge (the `cac` binary, the tests, the benchmarks).

pub use cac_attack as attack;
pub use cac_bench as bench;
pub use cac_core::{choice, colour, io, memory, printer, report};
pub use cac_detect as detect;
pub use cac_eval as eval;
pub use cac_eval::study;
pub use cac_export as export;
pub use cac_physical as physical;
pub use cac_physical::sim;
pub use cac_render as render;
pub use cac_render::{config, environment};
pub use cac_scene as scene;
pub use cac_video as video;
