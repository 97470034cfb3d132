//! Offline scoring of recorded videos and image sequences (`cac score-video`): decode with the
//! ffmpeg command-line tools as a subprocess ([`probe`], [`decode`]), ground truth from
//! annotation files ([`annotations`]) or a turntable log (both hand-written CSV: [`csv`]) projected through the digital twin
//! ([`log`]; projected by the rig camera model, `physical::rig_camera`: the viewpoint twin or the
//! calibrated rig), frame sampling and P@0.5 per segment ([`score`], an adapter of the scoring
//! core `eval::score`), rendered turntable sequences ([`twin`]), boxes drawn into an
//! annotated video or frame folder ([`annotate`]), and the per-frame CSV, plot and HTML report
//! ([`report`]); [`job`] runs all of it for `cac score-video`. [`encode`] holds the encoding presets of the fixtures and the benchmark (`cac-bench`).
//!
//! ffmpeg and ffprobe are found on `PATH`, or where the caller says ([`Tools::locate`]; the
//! command line passes `CAC_FFMPEG` / `CAC_FFPROBE`).

pub mod annotate;
pub mod annotations;
pub mod csv;
pub mod decode;
pub mod encode;
pub mod job;
pub mod log;
pub mod probe;
pub mod report;
pub mod score;
mod tools;
pub mod twin;

pub use annotations::{Annotations, GroundTruth, GtBox};
pub use decode::{open, FrameStream, OpenOptions, VideoFrame};
pub use probe::{probe, StreamInfo};
pub use score::{score_stream, FrameRecord, Sampling, ScoreOptions, Segmenting, VideoScores};
pub use tools::Tools;
