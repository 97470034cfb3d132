//! Cameras of the physical rig: the [`FrameSource`] trait, a folder-of-images source (replays
//! recorded or rendered frames in name order), and — behind the `v4l2` cargo feature — a V4L2
//! webcam source on the `v4l` crate. The pixel decoders (MJPEG with missing Huffman tables,
//! YUYV) live in [`decode`].

pub mod decode;
#[cfg(all(feature = "v4l2", target_os = "linux"))]
pub mod v4l2;

use image::RgbImage;
use std::path::{Path, PathBuf};

/// Camera errors.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// A file or device could not be read.
    #[error("{path}: {source}")]
    Io {
        /// What was being read.
        path: PathBuf,
        /// Why it failed.
        source: std::io::Error,
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
}

/// Anything that yields frames on request: a webcam, a folder of images, a renderer.
pub trait FrameSource {
    /// Capture (or load) the next frame.
    fn capture(&mut self) -> Result<Frame, CameraError>;
    /// A one-line description for logs and manifests.
    fn describe(&self) -> String;
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
        let io = |source| CameraError::Io {
            path: dir.to_path_buf(),
            source,
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
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no .png/.jpg images"),
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
        let bytes = std::fs::read(&path).map_err(|source| CameraError::Io {
            path: path.clone(),
            source,
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
