//! Cameras of the physical rig: the [`FrameSource`] trait, what a camera was locked to for a
//! session ([`CameraSettings`]), a folder-of-images source (replays recorded or rendered frames
//! in name order), and on Linux a V4L2 webcam source ([`v4l2`]). The pixel decoders (MJPEG with
//! missing Huffman tables, YUYV) live in [`decode`].

pub mod decode;
#[cfg(target_os = "linux")]
pub mod v4l2;

use image::RgbImage;
use std::path::{Path, PathBuf};

/// Camera errors.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// A file or device could not be read.
    // `reason`, not `source`: the message already says why, so an error chain does not
    // repeat it.
    #[error("{path}: {reason}")]
    Io {
        /// What was being read.
        path: PathBuf,
        /// Why it failed.
        reason: std::io::Error,
    },
    /// Frame bytes that do not decode.
    #[error("cannot decode {what}: {detail}")]
    Decode {
        /// Which frame / format.
        what: String,
        /// Why.
        detail: String,
    },
    /// A folder source ran out of images.
    #[error("{0}: no more frames")]
    Exhausted(PathBuf),
    /// The device refused a format or control.
    #[error("camera device: {0}")]
    Device(String),
}

/// One captured frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The pixels.
    pub image: RgbImage,
    /// Running number of frames from this source, from 0.
    pub index: u64,
    /// Where it came from (file name, device and format), for manifests.
    pub origin: String,
    /// What went wrong on the way to this frame and was recovered (a corrupt frame dropped, a
    /// stalled stream restarted, a camera reopened), for the manifest.
    pub events: Vec<String>,
}

/// What a camera ran at for a session, read back from it: recorded in `session.json`, held
/// again on `--resume`, so frames of one session are comparable.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraSettings {
    /// Device node.
    pub device: String,
    /// Driver, card and bus as the device names them.
    pub driver: String,
    pub card: String,
    pub bus: String,
    /// Pixel format streamed (`MJPG`, `YUYV`).
    pub format: String,
    /// Frame size delivered.
    pub width: u32,
    pub height: u32,
    /// Frame rate asked, the one the driver reports, and the one measured over the warm-up
    /// frames (a camera may accept a rate and not keep it).
    pub fps_asked: Option<f64>,
    pub fps_reported: Option<f64>,
    pub fps_measured: Option<f64>,
    /// Exposure, white balance and focus as locked.
    pub controls: Vec<LockedControl>,
}

/// One control held for a session.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LockedControl {
    /// `exposure` (driver units, 100 µs on UVC), `white_balance_k`, `focus`.
    pub name: String,
    /// The V4L2 control id of the value.
    pub id: u32,
    /// The value read back after locking; `None`: the camera has no such control.
    pub value: Option<i32>,
    /// Whether an automatic mode was switched off for it.
    pub auto_off: bool,
}

/// Anything that yields frames on request: a webcam, a folder of images, a renderer.
pub trait FrameSource {
    /// Capture (or load) the next frame.
    fn capture(&mut self) -> Result<Frame, CameraError>;
    /// A one-line description for logs and manifests.
    fn describe(&self) -> String;
    /// What the camera is locked to, for cameras that have settings.
    fn settings(&self) -> Option<CameraSettings> {
        None
    }
}

/// Image files of a folder (`.png`, `.jpg`, `.jpeg`, any case), in file-name order.
#[derive(Debug, Clone)]
pub struct FolderSource {
    dir: PathBuf,
    files: Vec<PathBuf>,
    next: usize,
    looping: bool,
}

impl FolderSource {
    /// List the images of `dir`; fails when there are none. With `looping`, it starts over after
    /// the last one instead of reporting [`CameraError::Exhausted`].
    pub fn open(dir: &Path, looping: bool) -> Result<Self, CameraError> {
        let io = |reason| CameraError::Io {
            path: dir.to_path_buf(),
            reason,
        };
        let mut files = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(io)? {
            let path = entry.map_err(io)?.path();
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase);
            if path.is_file() && matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg")) {
                files.push(path);
            }
        }
        files.sort();
        if files.is_empty() {
            return Err(CameraError::Io {
                path: dir.to_path_buf(),
                reason: std::io::Error::new(std::io::ErrorKind::NotFound, "no .png/.jpg images"),
            });
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            files,
            next: 0,
            looping,
        })
    }

    /// Number of images.
    pub fn len(&self) -> usize {
        self.files.len()
    }

    /// Always false (an empty folder is refused by `open`).
    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }
}

impl FrameSource for FolderSource {
    fn capture(&mut self) -> Result<Frame, CameraError> {
        let i = self.next;
        let path = match self.files.get(i % self.files.len()) {
            Some(p) if self.looping || i < self.files.len() => p.clone(),
            _ => return Err(CameraError::Exhausted(self.dir.clone())),
        };
        let bytes = std::fs::read(&path).map_err(|reason| CameraError::Io {
            path: path.clone(),
            reason,
        })?;
        let image = image::load_from_memory(&bytes)
            .map_err(|e| CameraError::Decode {
                what: path.display().to_string(),
                detail: e.to_string(),
            })?
            .to_rgb8();
        self.next += 1;
        Ok(Frame {
            image,
            index: i as u64,
            origin: path.display().to_string(),
            events: Vec::new(),
        })
    }

    fn describe(&self) -> String {
        format!(
            "folder {} ({} images)",
            self.dir.display(),
            self.files.len()
        )
    }
}
