//! V4L2 webcam source (Linux, on the `linuxvideo` crate): negotiates MJPEG or YUYV at the lens's
//! size (a camera that offers another size is refused, naming what it offers), asks a frame rate,
//! locks exposure, white balance and focus (auto modes off, at the rig file's values or where the
//! auto modes settled during a warm-up) and records what the camera actually runs at
//! ([`CameraSettings`]). Each capture drains the frames the camera filled before it was asked (the
//! table was still turning), waits for a fresh one with a time limit, and survives what webcams
//! do: a corrupt frame is dropped and the next taken, a stalled stream is restarted, an unplugged
//! camera is reopened with the same settings when it comes back; every such event is returned
//! with the frame for the manifest.

mod setup;

use super::decode::{decode_mjpeg, yuyv_to_rgb};
use super::{CameraError, CameraSettings, Frame, FrameSource};
use linuxvideo::format::PixelFormat as Fourcc;
use linuxvideo::stream::ReadStream;
use linuxvideo::Device;
use setup::{choose_format, lock_controls, start};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Pixel formats this source decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PixelFormat {
    /// Motion-JPEG (`MJPG`), Huffman tables optional.
    Mjpeg,
    /// Packed YUV 4:2:2 (`YUYV`).
    Yuyv,
}

impl PixelFormat {
    fn fourcc(self) -> Fourcc {
        match self {
            PixelFormat::Mjpeg => Fourcc::MJPG,
            PixelFormat::Yuyv => Fourcc::YUYV,
        }
    }

    fn name(self) -> &'static str {
        match self {
            PixelFormat::Mjpeg => "MJPG",
            PixelFormat::Yuyv => "YUYV",
        }
    }
}

/// What to ask the camera for.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct V4l2Config {
    /// Device node, e.g. `/dev/video0`.
    pub path: PathBuf,
    /// Frame size: the calibrated lens's; a camera that cannot deliver it is refused.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Format to try first; the other one is the fallback.
    pub prefer: PixelFormat,
    /// Frame rate to ask (frames per second); `None` keeps the camera's.
    pub fps: Option<f64>,
    /// Manual exposure in the driver's units (100 µs for UVC cameras); `None` locks it where
    /// auto exposure settled during the warm-up.
    pub exposure: Option<i32>,
    /// Manual white balance (kelvin); `None` locks it where auto white balance settled.
    pub white_balance_k: Option<i32>,
    /// Manual focus position; `None` locks it where autofocus settled.
    pub focus: Option<i32>,
    /// Frames streamed with the auto modes on before they are locked, and discarded again after.
    pub warmup_frames: u32,
    /// Longest wait for a frame before the stream counts as stalled.
    pub frame_timeout: Duration,
    /// How long an unplugged camera may take to come back.
    pub reconnect_deadline: Duration,
    /// Corrupt frames, stalls and reconnects tolerated for one capture.
    pub max_faults: u32,
}

impl Default for V4l2Config {
    fn default() -> Self {
        Self {
            path: "/dev/video0".into(),
            width: 1280,
            height: 720,
            prefer: PixelFormat::Mjpeg,
            fps: None,
            exposure: None,
            white_balance_k: None,
            focus: None,
            warmup_frames: 5,
            frame_timeout: Duration::from_secs(2),
            reconnect_deadline: Duration::from_secs(10),
            max_faults: 4,
        }
    }
}

/// Why one attempt at a frame failed.
enum Fault {
    /// The frame's bytes are damaged (the driver's error flag, or they do not decode).
    Corrupt(String),
    /// No frame arrived within the time limit.
    Stall,
    /// The device is gone (ENODEV, POLLERR/POLLHUP).
    Gone(String),
    /// Anything else: not retried.
    Fatal(CameraError),
}

/// A streaming V4L2 camera.
pub(crate) struct V4l2Source {
    cfg: V4l2Config,
    stream: Option<ReadStream>,
    settings: CameraSettings,
    pixel: PixelFormat,
    index: u64,
    dequeued: u64,
}

fn dev_err(path: &Path, what: &str, e: std::io::Error) -> CameraError {
    CameraError::Device(format!("{}: {what}: {e}", path.display()))
}

fn is_gone(e: &std::io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(libc::ENODEV | libc::ENXIO | libc::EIO)
    )
}

impl V4l2Source {
    /// Open and configure the camera, lock its controls, start streaming and discard the
    /// warm-up frames (timing them: the measured frame rate).
    pub fn open(cfg: &V4l2Config) -> Result<Self, CameraError> {
        let path = &cfg.path;
        let open = |p: &Path| {
            Device::open(p).map_err(|reason| CameraError::Io {
                path: p.to_path_buf(),
                reason,
            })
        };
        let dev = open(path)?;
        let pixel = choose_format(&dev, cfg)?;
        // Let the auto modes settle on a stream before locking them where they are.
        let needs_settling =
            cfg.exposure.is_none() || cfg.white_balance_k.is_none() || cfg.focus.is_none();
        let dev = if needs_settling && cfg.warmup_frames > 0 {
            let mut stream = start(dev, cfg, pixel)?.0;
            for _ in 0..cfg.warmup_frames {
                warmup_frame(&mut stream, cfg)?;
            }
            drop(stream);
            open(path)?
        } else {
            dev
        };
        let mut dev = dev;
        let caps = dev
            .capabilities()
            .map_err(|e| dev_err(path, "querying capabilities", e))?;
        let controls = lock_controls(&mut dev, cfg)?;
        let (mut stream, size, reported) = start(dev, cfg, pixel)?;
        // Discard frames taken before the lock took hold, timing them from the first.
        let n = cfg.warmup_frames.max(3);
        warmup_frame(&mut stream, cfg)?;
        let t0 = Instant::now();
        for _ in 1..n {
            warmup_frame(&mut stream, cfg)?;
        }
        let measured = f64::from(n - 1) / t0.elapsed().as_secs_f64().max(1e-9);
        let settings = CameraSettings {
            device: path.display().to_string(),
            driver: caps.driver().to_string(),
            card: caps.card().to_string(),
            bus: caps.bus_info().to_string(),
            format: pixel.name().to_string(),
            width: size.0,
            height: size.1,
            fps_asked: cfg.fps,
            fps_reported: reported,
            fps_measured: Some((measured * 10.0).round() / 10.0),
            controls,
        };
        // From now on (restarts, reconnects) the camera is held at exactly these values.
        let mut cfg = cfg.clone();
        for c in &settings.controls {
            match c.name.as_str() {
                "exposure" => cfg.exposure = c.value.or(cfg.exposure),
                "white_balance_k" => cfg.white_balance_k = c.value.or(cfg.white_balance_k),
                "focus" => cfg.focus = c.value.or(cfg.focus),
                _ => {}
            }
        }
        Ok(Self {
            cfg,
            stream: Some(stream),
            settings,
            pixel,
            index: 0,
            dequeued: u64::from(n),
        })
    }

    /// Close and reopen the device, lock the same controls and stream again; for a replugged
    /// camera, keep trying until the reconnect deadline.
    fn reopen(&mut self, deadline: Duration) -> Result<Duration, CameraError> {
        self.stream = None; // STREAMOFF, unmap, close
        let t0 = Instant::now();
        let path = self.cfg.path.clone();
        loop {
            let last = match Device::open(&path) {
                Ok(mut dev) => {
                    let controls = lock_controls(&mut dev, &self.cfg)?;
                    if controls != self.settings.controls {
                        return Err(CameraError::Device(format!(
                            "{}: after reopening, the controls read back {:?}, not the session's {:?}",
                            path.display(),
                            controls,
                            self.settings.controls
                        )));
                    }
                    // `start` refuses any size but the configured one.
                    let (stream, _, _) = start(dev, &self.cfg, self.pixel)?;
                    self.stream = Some(stream);
                    return Ok(t0.elapsed());
                }
                Err(e) => e.to_string(),
            };
            if t0.elapsed() >= deadline {
                return Err(CameraError::Device(format!(
                    "{}: the camera did not come back within {:.1} s ({last})",
                    path.display(),
                    deadline.as_secs_f64()
                )));
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// Wait (up to the frame timeout) for the next filled buffer and copy its bytes out, with
/// whether the driver flagged it as damaged.
fn next_raw(stream: &mut ReadStream, cfg: &V4l2Config) -> Result<(Vec<u8>, bool), Fault> {
    let mut pfd = libc::pollfd {
        fd: stream.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    let ms = cfg.frame_timeout.as_millis().min(i32::MAX as u128) as i32;
    // SAFETY: one valid pollfd, the count says one.
    let r = unsafe { libc::poll(&mut pfd, 1, ms) };
    if r < 0 {
        let e = std::io::Error::last_os_error();
        return Err(if is_gone(&e) {
            Fault::Gone(e.to_string())
        } else {
            Fault::Fatal(dev_err(&cfg.path, "waiting for a frame", e))
        });
    }
    if r == 0 {
        return Err(Fault::Stall);
    }
    if pfd.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL) != 0 {
        return Err(Fault::Gone(format!("poll reported {:#x}", pfd.revents)));
    }
    let mut flagged = false;
    let bytes = stream
        .dequeue(|view| {
            flagged = view.is_error();
            Ok(view.to_vec())
        })
        .map_err(|e| {
            if is_gone(&e) {
                Fault::Gone(e.to_string())
            } else {
                Fault::Fatal(dev_err(&cfg.path, "dequeuing a frame", e))
            }
        })?;
    Ok((bytes, flagged))
}

/// A frame of a warm-up, discarded: a corrupt one does not matter, a stall or a lost device
/// fails the opening (before anything has moved).
fn warmup_frame(stream: &mut ReadStream, cfg: &V4l2Config) -> Result<(), CameraError> {
    next_raw(stream, cfg)
        .map(|_| ())
        .map_err(|f| fault_error(&cfg.path, f))
}

fn fault_error(path: &Path, f: Fault) -> CameraError {
    match f {
        Fault::Corrupt(d) => CameraError::Device(format!("{}: corrupt frame: {d}", path.display())),
        Fault::Stall => CameraError::Device(format!("{}: no frame arrives", path.display())),
        Fault::Gone(d) => CameraError::Device(format!("{}: device lost: {d}", path.display())),
        Fault::Fatal(e) => e,
    }
}

impl V4l2Source {
    /// Drain the frames filled before this call, then take the next one and decode it.
    fn fresh(&mut self) -> Result<(Frame, u64), Fault> {
        let stream = self
            .stream
            .as_mut()
            .ok_or_else(|| Fault::Gone("not streaming".into()))?;
        let mut stale = 0;
        while !stream.will_block().map_err(|e| {
            if is_gone(&e) {
                Fault::Gone(e.to_string())
            } else {
                Fault::Fatal(dev_err(&self.cfg.path, "querying buffers", e))
            }
        })? {
            next_raw(stream, &self.cfg)?;
            self.dequeued += 1;
            stale += 1;
        }
        let (bytes, flagged) = next_raw(stream, &self.cfg)?;
        self.dequeued += 1;
        if flagged {
            return Err(Fault::Corrupt("the driver flagged the buffer".into()));
        }
        let (w, h) = (self.settings.width, self.settings.height);
        let image = match self.pixel {
            PixelFormat::Mjpeg => decode_mjpeg(&bytes),
            PixelFormat::Yuyv => yuyv_to_rgb(&bytes, w, h, 2 * w as usize),
        }
        .map_err(|e| Fault::Corrupt(e.to_string()))?;
        if (image.width(), image.height()) != (w, h) {
            return Err(Fault::Corrupt(format!(
                "a {}x{} frame in a {w}x{h} stream",
                image.width(),
                image.height()
            )));
        }
        let frame = Frame {
            image,
            index: self.index,
            origin: format!(
                "{} {} {w}x{h} frame {}",
                self.cfg.path.display(),
                self.pixel.name(),
                self.dequeued - 1
            ),
            events: Vec::new(),
        };
        Ok((frame, stale))
    }
}

impl FrameSource for V4l2Source {
    fn capture(&mut self) -> Result<Frame, CameraError> {
        let mut events = Vec::new();
        loop {
            let fault = match self.fresh() {
                Ok((mut frame, stale)) => {
                    if stale > 0 {
                        frame.origin += &format!(" ({stale} older frames discarded)");
                    }
                    frame.events = events;
                    self.index += 1;
                    return Ok(frame);
                }
                Err(f) => f,
            };
            let event = match fault {
                Fault::Fatal(e) => return Err(e),
                Fault::Corrupt(d) => format!("corrupt frame dropped: {d}"),
                Fault::Stall => {
                    let took = self.reopen(self.cfg.frame_timeout)?;
                    format!(
                        "no frame within {:.1} s: stream restarted ({:.2} s)",
                        self.cfg.frame_timeout.as_secs_f64(),
                        took.as_secs_f64()
                    )
                }
                Fault::Gone(d) => {
                    let took = self.reopen(self.cfg.reconnect_deadline)?;
                    format!(
                        "device lost ({d}): reopened with the session's settings after {:.2} s",
                        took.as_secs_f64()
                    )
                }
            };
            events.push(event);
            if events.len() > self.cfg.max_faults as usize {
                return Err(CameraError::Device(format!(
                    "{}: gave up on this frame after {} faults: {}",
                    self.cfg.path.display(),
                    events.len(),
                    events.join("; ")
                )));
            }
        }
    }

    fn describe(&self) -> String {
        let s = &self.settings;
        format!(
            "V4L2 {} ({} {}) {}x{} {}",
            s.device, s.driver, s.card, s.width, s.height, s.format
        )
    }

    fn settings(&self) -> Option<CameraSettings> {
        Some(self.settings.clone())
    }
}
