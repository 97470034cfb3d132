//! The annotated output: each scored frame drawn once per model side by side (ground-truth box
//! in white on top, detections in a colour per class with label and score, a header with the model, time,
//! frame and hit/miss), written as a PNG folder or encoded by ffmpeg (H.264, yuv420p) into a video.

use super::score::FrameRecord;
use crate::tools::{missing, Tools};
use anyhow::{bail, Context, Result};
use cac_core::report::draw::{class_colour, labelled_box};
use cac_core::report::font::{draw_text, fill_rect};
use image::RgbImage;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Stdio};

/// Draws one panel per model for `rec` over `frame`; panels sit side by side.
pub fn draw(frame: &RgbImage, rec: &FrameRecord, models: &[String], confidence: f32) -> RgbImage {
    let (w, h) = frame.dimensions();
    let px = (w / 320).max(1);
    let t = px as i64;
    let mut out = RgbImage::new(w * models.len() as u32, h);
    for (m, name) in models.iter().enumerate() {
        let mut p = frame.clone();
        let mf = &rec.models[m];
        for d in mf.detections.iter().filter(|d| d.score >= confidence) {
            let label = format!("{} {:.2}", d.label, d.score);
            labelled_box(&mut p, d.bbox, class_colour(d.class_id), px, &label);
        }
        labelled_box(&mut p, rec.gt, [255, 255, 255], px, "");
        let head = format!(
            "{} T {:.2}S #{} {}",
            name,
            rec.pts,
            rec.index,
            if mf.score.hit { "HIT" } else { "MISS" }
        );
        fill_rect(&mut p, 0, 0, w as i64, 9 * t, [0, 0, 0]);
        let c = if mf.score.hit {
            [120, 255, 120]
        } else {
            [255, 120, 120]
        };
        draw_text(&mut p, t, t, &head, px, c);
        image::imageops::replace(&mut out, &p, (m as u32 * w) as i64, 0);
    }
    out
}

/// Where annotated frames go.
pub enum AnnotatedWriter {
    Folder {
        dir: PathBuf,
        written: usize,
    },
    Video {
        path: PathBuf,
        partial: PathBuf,
        child: Child,
        stdin: Option<ChildStdin>,
        size: (u32, u32),
    },
}

impl AnnotatedWriter {
    /// A video when `out` ends in `.mp4`, `.mkv` or `.avi`, else a folder of PNGs. `size` is the
    /// annotated frame size, `fps` the output frame rate.
    pub fn create(tools: &Tools, out: &Path, size: (u32, u32), fps: f64) -> Result<Self> {
        let ext = out
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if !matches!(ext.as_deref(), Some("mp4" | "mkv" | "avi")) {
            std::fs::create_dir_all(out)
                .with_context(|| format!("cannot create frame folder {}", out.display()))?;
            return Ok(AnnotatedWriter::Folder {
                dir: out.to_path_buf(),
                written: 0,
            });
        }
        if !(fps.is_finite() && fps > 0.0) {
            bail!("annotated video frame rate must be positive, got {fps}");
        }
        let dir = match out.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create output folder {}", dir.display()))?;
        let name = out.file_name().unwrap_or_default().to_string_lossy();
        let partial = dir.join(format!(".partial-{name}"));
        let mut cmd = tools.command(&tools.ffmpeg);
        cmd.args(["-y", "-hide_banner", "-nostats", "-loglevel", "error"]);
        cmd.args(["-f", "rawvideo", "-pix_fmt", "rgb24"]);
        cmd.args(["-s", &format!("{}x{}", size.0, size.1)]);
        cmd.args(["-r", &format!("{fps}"), "-i", "pipe:0"]);
        cmd.args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"]);
        cmd.args(["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "18"]);
        cmd.arg(&partial);
        cmd.stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().map_err(|e| missing(&tools.ffmpeg, e))?;
        let stdin = child.stdin.take();
        Ok(AnnotatedWriter::Video {
            path: out.to_path_buf(),
            partial,
            child,
            stdin,
            size,
        })
    }

    /// Adds one annotated frame.
    pub fn write(&mut self, img: &RgbImage, index: u64) -> Result<()> {
        match self {
            AnnotatedWriter::Folder { dir, written } => {
                *written += 1;
                cac_core::io::save_png_atomic(&dir.join(format!("frame_{index:06}.png")), img)
            }
            AnnotatedWriter::Video {
                stdin, size, path, ..
            } => {
                if img.dimensions() != *size {
                    bail!("annotated frame size changed");
                }
                let s = stdin.as_mut().context("annotated video already finished")?;
                s.write_all(img.as_raw())
                    .with_context(|| format!("ffmpeg stopped taking frames for {}", path.display()))
            }
        }
    }

    /// Finishes the output (waits for the encoder and moves the video into place).
    pub fn finish(self) -> Result<PathBuf> {
        match self {
            AnnotatedWriter::Folder { dir, .. } => Ok(dir),
            AnnotatedWriter::Video {
                path,
                partial,
                mut child,
                stdin,
                ..
            } => {
                drop(stdin);
                let mut err = String::new();
                if let Some(mut e) = child.stderr.take() {
                    let _ = e.read_to_string(&mut err);
                }
                let status = child.wait().context("waiting for the ffmpeg encoder")?;
                if !status.success() {
                    let _ = std::fs::remove_file(&partial);
                    bail!(
                        "ffmpeg could not encode {} ({status}): {}",
                        path.display(),
                        err.trim()
                    );
                }
                std::fs::rename(&partial, &path)
                    .with_context(|| format!("cannot move {} into place", path.display()))?;
                Ok(path)
            }
        }
    }
}
