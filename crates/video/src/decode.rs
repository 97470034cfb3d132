//! Frame streams: ffmpeg as a subprocess writing raw `rgb24` frames to a pipe (one frame in
//! memory at a time), with each frame's presentation time read from the `showinfo` filter's log
//! in the same pass; or a folder of images read directly (lossless, times from a frame rate).
//!
//! Rotation: ffmpeg's automatic rotation is switched off (`-noautorotate`) and the probed (or
//! overridden) rotation is applied as an explicit `transpose`/flip filter, so the frame size is
//! known before the first frame arrives.

use super::probe::{probe, StreamInfo, SUPPORTED_CODECS};
use crate::tools::{is_pattern, missing, Tools};
use anyhow::{bail, Context, Result};
use cac_physical::{FolderSource, FrameSource};
use image::RgbImage;
use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Stdio};
use std::sync::{mpsc, Arc, Mutex};

/// One decoded, display-oriented frame.
#[derive(Clone, Debug)]
pub struct VideoFrame {
    /// Running number in presentation order, from 0.
    pub index: u64,
    /// Presentation time in seconds.
    pub pts: f64,
    pub image: RgbImage,
}

/// Anything that yields display-oriented frames in presentation order.
pub trait FrameStream {
    /// The next frame, or `None` at the end.
    fn next_frame(&mut self) -> Result<Option<VideoFrame>>;
    /// Display size `(width, height)` of every frame.
    fn size(&self) -> (u32, u32);
    /// Nominal frame rate (frames/s), for the annotated video.
    fn fps(&self) -> f64;
    /// One line for logs and reports.
    fn describe(&self) -> String;
    /// Unix seconds of the recording's start from the container's `creation_time`, if any.
    fn creation_time(&self) -> Option<f64> {
        None
    }
}

/// How to open an input.
#[derive(Clone, Debug, PartialEq)]
pub struct OpenOptions {
    /// Counter-clockwise rotation (0, 90, 180, 270) overriding the video's metadata.
    pub rotate_ccw: Option<u32>,
    /// Frame rate of image folders and patterns (their frames carry no times).
    pub fps: f64,
    /// Decode codecs other than H.264, HEVC, MJPEG and PNG (tolerances not measured).
    pub allow_any_codec: bool,
}

impl Default for OpenOptions {
    /// No rotation override, 30 frames/s, the measured codecs only.
    fn default() -> Self {
        OpenOptions {
            rotate_ccw: None,
            fps: 30.0,
            allow_any_codec: false,
        }
    }
}

/// Opens a video file, a printf-style image pattern (`frames/%04d.png`, through ffmpeg) or a
/// folder of PNG/JPEG images (read directly, in name order).
pub fn open(tools: &Tools, input: &Path, opts: &OpenOptions) -> Result<Box<dyn FrameStream>> {
    if !(opts.fps.is_finite() && opts.fps > 0.0) {
        bail!("frame rate must be positive, got {}", opts.fps);
    }
    if input.is_dir() {
        return Ok(Box::new(FolderStream::open(input, opts)?));
    }
    Ok(Box::new(FfmpegStream::open(tools, input, opts)?))
}

/// Images of a folder in name order; frame `i` is at `i / fps` seconds.
pub(crate) struct FolderStream {
    src: FolderSource,
    size: (u32, u32),
    fps: f64,
    rotate_ccw: u32,
    first: Option<VideoFrame>,
    index: u64,
    left: usize,
}

impl FolderStream {
    pub fn open(dir: &Path, opts: &OpenOptions) -> Result<Self> {
        let mut src = FolderSource::open(dir, false)
            .with_context(|| format!("cannot read image folder {}", dir.display()))?;
        let left = src.len();
        let rotate_ccw = opts.rotate_ccw.unwrap_or(0) % 360;
        let f = src.capture().context("first image")?;
        let image = rotate(f.image, rotate_ccw);
        Ok(FolderStream {
            size: image.dimensions(),
            src,
            fps: opts.fps,
            rotate_ccw,
            first: Some(VideoFrame {
                index: 0,
                pts: 0.0,
                image,
            }),
            index: 1,
            left: left - 1,
        })
    }
}

impl FrameStream for FolderStream {
    fn next_frame(&mut self) -> Result<Option<VideoFrame>> {
        if let Some(f) = self.first.take() {
            return Ok(Some(f));
        }
        if self.left == 0 {
            return Ok(None);
        }
        let f = self.src.capture()?;
        let image = rotate(f.image, self.rotate_ccw);
        if image.dimensions() != self.size {
            bail!(
                "{}: {}x{} differs from the first image's {}x{}",
                f.origin,
                image.width(),
                image.height(),
                self.size.0,
                self.size.1
            );
        }
        self.left -= 1;
        let index = self.index;
        self.index += 1;
        Ok(Some(VideoFrame {
            index,
            pts: index as f64 / self.fps,
            image,
        }))
    }
    fn size(&self) -> (u32, u32) {
        self.size
    }
    fn fps(&self) -> f64 {
        self.fps
    }
    fn describe(&self) -> String {
        format!("{} at {} frames/s", self.src.describe(), self.fps)
    }
}

/// Turns an image counter-clockwise by 0, 90, 180 or 270 degrees.
pub fn rotate(img: RgbImage, ccw: u32) -> RgbImage {
    match ccw % 360 {
        90 => image::imageops::rotate270(&img),
        180 => image::imageops::rotate180(&img),
        270 => image::imageops::rotate90(&img),
        _ => img,
    }
}

/// The ffmpeg filter that turns the stored picture counter-clockwise by `ccw` degrees.
fn rotation_filter(ccw: u32) -> Option<&'static str> {
    match ccw % 360 {
        90 => Some("transpose=cclock"),
        180 => Some("hflip,vflip"),
        270 => Some("transpose=clock"),
        _ => None,
    }
}

/// ffmpeg decoding to a pipe.
pub(crate) struct FfmpegStream {
    path: PathBuf,
    info: StreamInfo,
    child: Child,
    stdout: ChildStdout,
    pts: mpsc::Receiver<f64>,
    log: Arc<Mutex<VecDeque<String>>>,
    size: (u32, u32),
    fps: f64,
    index: u64,
    done: bool,
}

impl FfmpegStream {
    pub fn open(tools: &Tools, path: &Path, opts: &OpenOptions) -> Result<Self> {
        let pattern = is_pattern(path);
        let mut info = probe(tools, path)?;
        if !opts.allow_any_codec && !SUPPORTED_CODECS.contains(&info.codec.as_str()) {
            bail!(
                "{}: unsupported codec {:?} (supported: {}; H.264/HEVC in MP4, MJPEG AVI, PNG/JPEG \
                 image sequences)",
                path.display(),
                info.codec,
                SUPPORTED_CODECS.join(", ")
            );
        }
        if let Some(r) = opts.rotate_ccw {
            info.rotation_ccw = r % 360;
        }
        let mut filters = vec!["showinfo".to_string()];
        filters.extend(rotation_filter(info.rotation_ccw).map(String::from));
        let mut cmd = tools.command(&tools.ffmpeg);
        cmd.args(["-hide_banner", "-nostdin", "-nostats", "-loglevel", "info"]);
        cmd.arg("-noautorotate");
        if pattern {
            cmd.args(["-framerate", &opts.fps.to_string()]);
        }
        cmd.arg("-i").arg(path);
        cmd.args(["-map", "0:v:0", "-an", "-sn", "-vf", &filters.join(",")]);
        cmd.args([
            "-fps_mode",
            "passthrough",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "rgb24",
        ]);
        cmd.arg("pipe:1");
        cmd.stdout(Stdio::piped()).stderr(Stdio::piped());
        let mut child = cmd.spawn().map_err(|e| missing(&tools.ffmpeg, e))?;
        let stdout = child.stdout.take().expect("piped stdout");
        let stderr = child.stderr.take().expect("piped stderr");
        let (tx, rx) = mpsc::channel();
        let log = Arc::new(Mutex::new(VecDeque::new()));
        let log2 = log.clone();
        std::thread::spawn(move || read_log(stderr, tx, log2));
        let fps = if pattern {
            opts.fps
        } else {
            info.avg_fps.or(info.r_fps).unwrap_or(opts.fps)
        };
        Ok(FfmpegStream {
            path: path.to_path_buf(),
            size: info.display_size(),
            info,
            child,
            stdout,
            pts: rx,
            log,
            fps,
            index: 0,
            done: false,
        })
    }

    fn log_tail(&self) -> String {
        let l = self.log.lock().unwrap();
        l.iter()
            .filter(|s| !s.trim().is_empty())
            .cloned()
            .collect::<Vec<_>>()
            .join("\n")
    }

    fn finish(&mut self) -> Result<()> {
        self.done = true;
        let status = self.child.wait().context("waiting for ffmpeg")?;
        if !status.success() {
            bail!(
                "ffmpeg failed decoding {} ({status}) after {} frames:\n{}",
                self.path.display(),
                self.index,
                self.log_tail()
            );
        }
        if self.index == 0 {
            bail!("{}: no frames decoded", self.path.display());
        }
        Ok(())
    }
}

/// Reads ffmpeg's log: `showinfo` frame lines give the times, the last other lines are kept for
/// error messages.
fn read_log(stderr: impl Read, tx: mpsc::Sender<f64>, log: Arc<Mutex<VecDeque<String>>>) {
    let mut r = BufReader::new(stderr);
    let mut line = Vec::new();
    loop {
        line.clear();
        match r.read_until(b'\n', &mut line) {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
        let s = String::from_utf8_lossy(&line);
        if s.contains("Parsed_showinfo") {
            if let Some(t) = parse_pts_time(&s) {
                if tx.send(t).is_err() {
                    break;
                }
            }
            continue;
        }
        let mut l = log.lock().unwrap();
        if l.len() >= 24 {
            l.pop_front();
        }
        l.push_back(s.trim_end().to_string());
    }
}

/// `pts_time:<seconds>` of a showinfo frame line; NaN for a frame without a time.
fn parse_pts_time(line: &str) -> Option<f64> {
    if !line.contains(" n:") {
        return None; // the filter's configuration lines
    }
    let rest = &line[line.find("pts_time:")? + "pts_time:".len()..];
    let tok = rest.split_whitespace().next()?;
    Some(tok.parse().unwrap_or(f64::NAN))
}

impl FrameStream for FfmpegStream {
    fn next_frame(&mut self) -> Result<Option<VideoFrame>> {
        if self.done {
            return Ok(None);
        }
        let (w, h) = self.size;
        let mut buf = vec![0u8; (w * h * 3) as usize];
        let mut got = 0;
        while got < buf.len() {
            match self.stdout.read(&mut buf[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e).context("reading frames from ffmpeg"),
            }
        }
        if got == 0 {
            self.finish()?;
            return Ok(None);
        }
        if got < buf.len() {
            let _ = self.finish();
            bail!(
                "{}: truncated frame {} ({got} of {} bytes):\n{}",
                self.path.display(),
                self.index,
                buf.len(),
                self.log_tail()
            );
        }
        let pts = match self.pts.recv_timeout(std::time::Duration::from_secs(30)) {
            Ok(t) if t.is_finite() => t,
            Ok(_) => self.index as f64 / self.fps,
            Err(_) => bail!(
                "{}: ffmpeg gave frame {} without its showinfo time",
                self.path.display(),
                self.index
            ),
        };
        let image = RgbImage::from_raw(w, h, buf).expect("buffer has the frame size");
        let index = self.index;
        self.index += 1;
        Ok(Some(VideoFrame { index, pts, image }))
    }
    fn size(&self) -> (u32, u32) {
        self.size
    }
    fn fps(&self) -> f64 {
        self.fps
    }
    fn creation_time(&self) -> Option<f64> {
        self.info.creation_time
    }
    fn describe(&self) -> String {
        format!(
            "{} ({}, {}x{}, rotation {}° ccw, {:.3} frames/s{})",
            self.path.display(),
            self.info.codec,
            self.info.width,
            self.info.height,
            self.info.rotation_ccw,
            self.fps,
            if self.info.looks_variable_rate() {
                ", variable rate"
            } else {
                ""
            }
        )
    }
}

impl Drop for FfmpegStream {
    fn drop(&mut self) {
        if !self.done {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn showinfo_lines() {
        let l = "[Parsed_showinfo_0 @ 0x5] n:   3 pts:   3072 pts_time:0.3     pos: 4 fmt:yuv420p";
        assert_eq!(parse_pts_time(l), Some(0.3));
        let c = "[Parsed_showinfo_0 @ 0x5] config in time_base: 1/10240, frame_rate: 10/1";
        assert_eq!(parse_pts_time(c), None);
        let n = "[Parsed_showinfo_0 @ 0x5] n:   0 pts:NOPTS pts_time:NOPTS pos: 4";
        assert!(parse_pts_time(n).unwrap().is_nan());
    }

    #[test]
    fn rotation_turns_counter_clockwise() {
        // A 2x1 image: left red, right blue. 90° ccw puts the right column on top.
        let mut img = RgbImage::new(2, 1);
        img.put_pixel(0, 0, image::Rgb([255, 0, 0]));
        img.put_pixel(1, 0, image::Rgb([0, 0, 255]));
        let r = rotate(img.clone(), 90);
        assert_eq!(r.dimensions(), (1, 2));
        assert_eq!(r.get_pixel(0, 0).0, [0, 0, 255]);
        assert_eq!(rotate(img.clone(), 270).get_pixel(0, 0).0, [255, 0, 0]);
        assert_eq!(rotate(img, 180).get_pixel(0, 0).0, [0, 0, 255]);
    }
}
