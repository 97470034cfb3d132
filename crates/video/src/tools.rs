//! The ffmpeg command-line tools: where they are ([`Tools`]), running one with a clear error
//! when it is missing or fails, and the naming of an input in those errors.

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
