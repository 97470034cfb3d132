//! The evaluation protocol and the experiments judged by it (crate `cac-eval`: `cac::eval`, with
//! [`study`] as `cac::study`).
//!
//! Per image and model, a *hit* is a true-class detection with IoU >= 0.5 against the
//! ground-truth box at confidence >= 0.3; P@0.5 = hits / images. Targeted success is the same
//! test for the target class. Drop = P@0.5(original) − P@0.5(texture). [`Protocol`] holds the
//! thresholds and classes.
//!
//! - Scoring: [`score`] is the one scoring core (detect, score against the box, tally by key)
//!   that the rendered, Blender, capture (`cac-physical`) and video (`cac-video`) evaluations
//!   share; [`evaluate`] scores a texture in a set of views.
//! - The rendered evaluation: [`run`] draws the protocol's views and scores textures in them
//!   (`cac eval`), [`textures`] resolves the texture list, [`cache`] keeps finished textures so an
//!   interrupted evaluation resumes, [`shard`] and [`job`] split an evaluation into shards and
//!   merge them back, [`slurm`] runs them as a Slurm array.
//! - Figures: [`summary`] aggregates the per-image records, [`report`] writes the tables, plots
//!   and HTML, [`compare`] one texture against another (the demo's before and after),
//!   [`gradcam`] where a detector looks.
//! - The second renderer and its checks: [`blender`] (Cycles), [`agreement`] (cac's renderer
//!   against Cycles), [`realism`] (whether the original object is recognised at all).
//! - [`study`]: experiments that train with `cac-attack` and judge with this crate (the studies,
//!   the demo, the training curve's judge). Benchmarks are in `cac-bench`.

pub mod agreement;
pub mod blender;
pub mod cache;
pub mod compare;
pub mod gradcam;
pub mod job;
mod protocol;
pub mod realism;
pub mod report;
pub mod run;
pub mod score;
pub mod shard;
pub mod slurm;
pub mod study;
pub mod summary;
pub mod textures;
mod views;

/// Lives in [`cac_render::environment`]; re-exported for the callers that still name it here.
pub use cac_render::environment::street_views;
pub use protocol::Protocol;
pub use score::{score_image, summarise, Figures, ImageScore, ModelOutcome, Scorer, Summary};
pub use views::{evaluate, ViewResults};
