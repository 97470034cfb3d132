//! Encoding an image sequence into a video with ffmpeg: the presets the tolerances in
//! docs/video.md were measured with (test fixtures, `cac bench video`).

use crate::tools::{run_tool, Tools};
use anyhow::{Context, Result};
use std::ffi::OsStr;
use std::path::Path;

/// H.264 in MP4 (yuv420p, CRF 18: a phone's quality range).
pub const H264: &[&str] = &["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "18"];
/// HEVC in MP4 (yuv420p, CRF 18, tagged `hvc1` like phone recordings).
pub const HEVC: &[&str] = &[
    "-c:v",
    "libx265",
    "-pix_fmt",
    "yuv420p",
    "-crf",
    "18",
    "-tag:v",
    "hvc1",
    "-x265-params",
    "log-level=error",
];
/// Motion JPEG in AVI (quality 3, full-range yuvj420p like webcams).
pub const MJPEG: &[&str] = &["-c:v", "mjpeg", "-q:v", "3", "-pix_fmt", "yuvj420p"];

/// Encodes the printf-style image pattern `pattern` at `fps` frames/s into `out` with the codec
/// arguments `codec` and any `extra` output arguments (filters, metadata).
pub fn encode_sequence(
    tools: &Tools,
    pattern: &Path,
    fps: f64,
    codec: &[&str],
    extra: &[&str],
    out: &Path,
) -> Result<()> {
    let fps = fps.to_string();
    let mut args: Vec<&OsStr> = ["-y", "-hide_banner", "-loglevel", "error", "-framerate"]
        .iter()
        .map(OsStr::new)
        .collect();
    args.push(OsStr::new(&fps));
    args.push(OsStr::new("-i"));
    args.push(pattern.as_os_str());
    args.extend(codec.iter().chain(extra).map(OsStr::new));
    args.push(out.as_os_str());
    run_tool(tools, &tools.ffmpeg, &args)
        .with_context(|| format!("encoding {} into {}", pattern.display(), out.display()))?;
    Ok(())
}
