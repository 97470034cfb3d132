//! Offline scoring of recorded videos and image sequences (`cac score-video`): decode with the
//! ffmpeg command-line tools as a subprocess ([`probe`], [`decode`]), ground truth from
//! annotation files ([`annotations`]) or a turntable log (both hand-written CSV: [`csv`]) projected through the digital twin
//! ([`log`]; projected by the rig camera model, `physical::rig_camera`: the viewpoint twin or the
//! calibrated rig), frame sampling and P@0.5 per segment ([`score`], an adapter of the scoring
//! core `eval::score`), rendered turntable sequences ([`twin`]), boxes drawn into an
//! annotated video or frame folder ([`annotate`]), and the per-frame CSV, plot and HTML report
//! ([`report`]); [`job`] runs all of it for `cac score-video`. [`encode`] holds the encoding presets of the fixtures and the benchmark ([`bench`]).
//!
//! ffmpeg and ffprobe are found on `PATH`, or where the caller says ([`Tools::locate`]; the
//! command line passes `CAC_FFMPEG` / `CAC_FFPROBE`).

pub mod annotate;
pub mod annotations;
pub mod bench;
pub mod csv;
pub mod decode;
pub mod encode;
pub mod job;
pub mod log;
pub mod probe;
pub mod report;
pub mod score;
pub mod twin;

pub use annotations::{Annotations, GroundTruth, GtBox};
pub use decode::{open, FrameStream, OpenOptions, VideoFrame};
pub use probe::{probe, StreamInfo};
pub use score::{score_stream, FrameRecord, Sampling, ScoreOptions, Segmenting, VideoScores};

use anyhow::{bail, Result};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Where the ffmpeg command-line tools are.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tools {
    pub ffmpeg: PathBuf,
    pub ffprobe: PathBuf,
}

impl Default for Tools {
    fn default() -> Self {
        Tools {
            ffmpeg: "ffmpeg".into(),
            ffprobe: "ffprobe".into(),
        }
    }
}

impl Tools {
    /// The tools at `ffmpeg` and `ffprobe` when given, else `ffmpeg` / `ffprobe` on `PATH`. When
    /// only `ffmpeg` is given as a path with a folder, ffprobe is looked for beside it. (The
    /// command line passes `$CAC_FFMPEG` and `$CAC_FFPROBE`.)
    pub fn locate(ffmpeg: Option<PathBuf>, ffprobe: Option<PathBuf>) -> Tools {
        let ffmpeg = ffmpeg.unwrap_or_else(|| "ffmpeg".into());
        let ffprobe = match ffprobe {
            Some(p) => p,
            None => match ffmpeg.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.join("ffprobe"),
                _ => "ffprobe".into(),
            },
        };
        Tools { ffmpeg, ffprobe }
    }

    /// Runs `-version` of both tools; a clear error when either is missing.
    pub fn check(&self) -> Result<()> {
        for t in [&self.ffmpeg, &self.ffprobe] {
            let out = self.command(t).arg("-version").output();
            match out {
                Ok(o) if o.status.success() => {}
                Ok(o) => bail!(
                    "{} -version failed ({}): {}",
                    t.display(),
                    o.status,
                    String::from_utf8_lossy(&o.stderr).trim()
                ),
                Err(e) => return Err(missing(t, e)),
            }
        }
        Ok(())
    }

    pub(crate) fn command(&self, tool: &Path) -> Command {
        let mut c = Command::new(tool);
        c.stdin(Stdio::null());
        c
    }
}

/// The error for a tool that cannot be started.
pub(crate) fn missing(tool: &Path, e: std::io::Error) -> anyhow::Error {
    if e.kind() == std::io::ErrorKind::NotFound {
        anyhow::anyhow!(
            "{} not found: install ffmpeg (Debian: apt-get install ffmpeg) or point CAC_FFMPEG / \
             CAC_FFPROBE at the binaries",
            tool.display()
        )
    } else {
        anyhow::Error::new(e).context(format!("cannot start {}", tool.display()))
    }
}

/// Runs a tool to completion, returning stdout; errors carry the tool's stderr.
pub(crate) fn run_tool(tools: &Tools, tool: &Path, args: &[&std::ffi::OsStr]) -> Result<Vec<u8>> {
    let out = tools
        .command(tool)
        .args(args)
        .output()
        .map_err(|e| missing(tool, e))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let err = err.trim();
        bail!(
            "{} failed ({}): {}",
            tool.display(),
            out.status,
            if err.is_empty() { "no message" } else { err }
        );
    }
    Ok(out.stdout)
}

/// Is `path` a printf-style image-sequence pattern (`frames/%04d.png`)?
pub(crate) fn is_pattern(path: &Path) -> bool {
    path.to_string_lossy().contains('%')
}

/// Context for errors about one input.
pub(crate) fn ctx_input(path: &Path) -> impl Fn() -> String + '_ {
    move || format!("cannot read video {}", path.display())
}
