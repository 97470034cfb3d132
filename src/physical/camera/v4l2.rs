//! V4L2 webcam source (feature `v4l2`, Linux): negotiates MJPEG or YUYV, reads the format the
//! driver actually chose back from it, optionally fixes exposure and focus (auto modes off), and
//! streams through memory-mapped buffers.

use super::decode::{decode_mjpeg, yuyv_to_rgb};
use super::{CameraError, Frame, FrameSource};
use std::path::PathBuf;
use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, Format, FourCC};

const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
const CID_FOCUS_ABSOLUTE: u32 = 0x009a_090a;
const CID_FOCUS_AUTO: u32 = 0x009a_090c;
const EXPOSURE_MANUAL: i64 = 1;

/// Pixel formats this source decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// Motion-JPEG (`MJPG`), Huffman tables optional.
    Mjpeg,
    /// Packed YUV 4:2:2 (`YUYV`).
    Yuyv,
}

impl PixelFormat {
    fn fourcc(self) -> FourCC {
        match self {
            PixelFormat::Mjpeg => FourCC::new(b"MJPG"),
            PixelFormat::Yuyv => FourCC::new(b"YUYV"),
        }
    }
}

/// What to ask the camera for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct V4l2Config {
    /// Device node, e.g. `/dev/video0`.
    pub path: PathBuf,
    /// Requested size (the driver may pick the nearest it supports).
    pub width: u32,
    /// Requested height.
    pub height: u32,
    /// Format to try first; the other one is the fallback.
    pub prefer: PixelFormat,
    /// Manual exposure in the driver's units (100 µs for UVC cameras); `None` keeps auto.
    pub exposure: Option<i64>,
    /// Manual focus position; `None` keeps autofocus.
    pub focus: Option<i64>,
    /// Frames to discard after starting (exposure settling).
    pub warmup_frames: u32,
}

impl Default for V4l2Config {
    fn default() -> Self {
        Self {
            path: "/dev/video0".into(),
            width: 1280,
            height: 720,
            prefer: PixelFormat::Mjpeg,
            exposure: None,
            focus: None,
            warmup_frames: 5,
        }
    }
}

/// A streaming V4L2 camera.
pub struct V4l2Source {
    path: PathBuf,
    // Declared before `_device` so the stream is dropped (buffers unmapped) first.
    stream: Stream<'static>,
    _device: Device,
    format: Format,
    pixel: PixelFormat,
    index: u64,
}

fn dev_err(path: &std::path::Path, what: &str, e: std::io::Error) -> CameraError {
    CameraError::Device(format!("{}: {what}: {e}", path.display()))
}

impl V4l2Source {
    /// Open and configure the camera, start streaming and discard the warm-up frames.
    pub fn open(cfg: &V4l2Config) -> Result<Self, CameraError> {
        let path = &cfg.path;
        let dev = Device::with_path(path).map_err(|source| CameraError::Io {
            path: path.clone(),
            source,
        })?;
        let offered: Vec<FourCC> = dev
            .enum_formats()
            .map_err(|e| dev_err(path, "listing formats", e))?
            .into_iter()
            .map(|d| d.fourcc)
            .collect();
        let other = match cfg.prefer {
            PixelFormat::Mjpeg => PixelFormat::Yuyv,
            PixelFormat::Yuyv => PixelFormat::Mjpeg,
        };
        let want = [cfg.prefer, other]
            .into_iter()
            .find(|p| offered.contains(&p.fourcc()))
            .ok_or_else(|| {
                let names: Vec<String> = offered.iter().map(|f| f.to_string()).collect();
                CameraError::Device(format!(
                    "{}: offers {} but neither MJPG nor YUYV",
                    path.display(),
                    names.join(", ")
                ))
            })?;
        let mut fmt = dev
            .format()
            .map_err(|e| dev_err(path, "reading format", e))?;
        fmt.width = cfg.width;
        fmt.height = cfg.height;
        fmt.fourcc = want.fourcc();
        dev.set_format(&fmt)
            .map_err(|e| dev_err(path, "setting format", e))?;
        // What the driver actually chose.
        let format = dev
            .format()
            .map_err(|e| dev_err(path, "reading format back", e))?;
        let pixel = if format.fourcc == PixelFormat::Mjpeg.fourcc() {
            PixelFormat::Mjpeg
        } else if format.fourcc == PixelFormat::Yuyv.fourcc() {
            PixelFormat::Yuyv
        } else {
            return Err(CameraError::Device(format!(
                "{}: driver switched to unsupported format {}",
                path.display(),
                format.fourcc
            )));
        };
        if let Some(exposure) = cfg.exposure {
            set(
                &dev,
                path,
                "exposure mode",
                CID_EXPOSURE_AUTO,
                Value::Integer(EXPOSURE_MANUAL),
            )?;
            set(
                &dev,
                path,
                "exposure",
                CID_EXPOSURE_ABSOLUTE,
                Value::Integer(exposure),
            )?;
        }
        if let Some(focus) = cfg.focus {
            set(
                &dev,
                path,
                "autofocus",
                CID_FOCUS_AUTO,
                Value::Boolean(false),
            )?;
            set(
                &dev,
                path,
                "focus",
                CID_FOCUS_ABSOLUTE,
                Value::Integer(focus),
            )?;
        }
        let stream = Stream::with_buffers(&dev, Type::VideoCapture, 4)
            .map_err(|e| dev_err(path, "mapping buffers", e))?;
        let mut src = Self {
            path: path.clone(),
            stream,
            _device: dev,
            format,
            pixel,
            index: 0,
        };
        for _ in 0..cfg.warmup_frames {
            src.stream
                .next()
                .map_err(|e| dev_err(path, "warm-up frame", e))?;
        }
        Ok(src)
    }

    /// The negotiated format: width, height and pixel format.
    pub fn format(&self) -> (u32, u32, PixelFormat) {
        (self.format.width, self.format.height, self.pixel)
    }
}

fn set(
    dev: &Device,
    path: &std::path::Path,
    what: &str,
    id: u32,
    value: Value,
) -> Result<(), CameraError> {
    dev.set_control(Control { id, value })
        .map_err(|e| dev_err(path, &format!("setting {what}"), e))
}

impl FrameSource for V4l2Source {
    fn capture(&mut self) -> Result<Frame, CameraError> {
        let (w, h, stride) = (
            self.format.width,
            self.format.height,
            self.format.stride as usize,
        );
        let (buf, meta) = self
            .stream
            .next()
            .map_err(|e| dev_err(&self.path, "capturing", e))?;
        let data = &buf[..(meta.bytesused as usize).min(buf.len())];
        let image = match self.pixel {
            PixelFormat::Mjpeg => decode_mjpeg(data)?,
            PixelFormat::Yuyv => yuyv_to_rgb(data, w, h, stride.max(2 * w as usize))?,
        };
        let index = self.index;
        self.index += 1;
        Ok(Frame {
            image,
            index,
            origin: format!("{} frame {}", self.path.display(), meta.sequence),
        })
    }

    fn describe(&self) -> String {
        format!(
            "V4L2 {} {}x{} {:?}",
            self.path.display(),
            self.format.width,
            self.format.height,
            self.pixel
        )
    }
}
