//! Setting a V4L2 camera up for a session: the format at the lens's size ([`choose_format`]),
//! exposure, white balance and focus locked and read back ([`lock_controls`]), the format and
//! frame rate set and the stream started ([`start`]).

use super::{dev_err, PixelFormat, V4l2Config};
use crate::camera::{CameraError, LockedControl};
use linuxvideo::controls::Cid;
use linuxvideo::format::{FrameSizes, PixFormat, PixelFormat as Fourcc};
use linuxvideo::stream::ReadStream;
use linuxvideo::{BufType, Device, Fract};

/// One auto/manual pair of UVC controls: switch `auto` to `manual`, then hold `value`.
struct Lock {
    name: &'static str,
    auto: Cid,
    manual: i32,
    value: Cid,
    value_id: u32,
}

const LOCKS: [Lock; 3] = [
    Lock {
        name: "exposure",
        auto: Cid::EXPOSURE_AUTO,
        manual: 1, // V4L2_EXPOSURE_MANUAL
        value: Cid::EXPOSURE_ABSOLUTE,
        value_id: 0x009a_0902,
    },
    Lock {
        name: "white_balance_k",
        auto: Cid::AUTO_WHITE_BALANCE,
        manual: 0,
        value: Cid::WHITE_BALANCE_TEMPERATURE,
        value_id: 0x0098_091a,
    },
    Lock {
        name: "focus",
        auto: Cid::FOCUS_AUTO,
        manual: 0,
        value: Cid::FOCUS_ABSOLUTE,
        value_id: 0x009a_090a,
    },
];

/// The format to stream: the preferred one when offered at the lens's size, else the other.
pub(super) fn choose_format(dev: &Device, cfg: &V4l2Config) -> Result<PixelFormat, CameraError> {
    let path = &cfg.path;
    let mut offered = Vec::new();
    for d in dev.formats(BufType::VIDEO_CAPTURE) {
        let d = d.map_err(|e| dev_err(path, "listing formats", e))?;
        offered.push(d.pixel_format());
    }
    let other = match cfg.prefer {
        PixelFormat::Mjpeg => PixelFormat::Yuyv,
        PixelFormat::Yuyv => PixelFormat::Mjpeg,
    };
    let mut sizes_seen = Vec::new();
    for p in [cfg.prefer, other] {
        if !offered.contains(&p.fourcc()) {
            continue;
        }
        let sizes = dev
            .frame_sizes(p.fourcc())
            .map_err(|e| dev_err(path, "listing frame sizes", e))?;
        let fits = match &sizes {
            FrameSizes::Discrete(list) => list.iter().any(|s| {
                let listed = (s.width(), s.height());
                sizes_seen.push(format!("{} {}x{}", p.name(), listed.0, listed.1));
                listed == (cfg.width, cfg.height)
            }),
            FrameSizes::Stepwise(s) | FrameSizes::Continuous(s) => {
                sizes_seen.push(format!(
                    "{} {}x{}..{}x{}",
                    p.name(),
                    s.min_width(),
                    s.min_height(),
                    s.max_width(),
                    s.max_height()
                ));
                (s.min_width()..=s.max_width()).contains(&cfg.width)
                    && (s.min_height()..=s.max_height()).contains(&cfg.height)
            }
        };
        if fits {
            return Ok(p);
        }
    }
    if !offered
        .iter()
        .any(|f| *f == Fourcc::MJPG || *f == Fourcc::YUYV)
    {
        let names: Vec<String> = offered.iter().map(|f| format!("{f}")).collect();
        return Err(CameraError::Device(format!(
            "{}: offers {} but neither MJPG nor YUYV",
            path.display(),
            names.join(", ")
        )));
    }
    Err(CameraError::Device(format!(
        "{}: cannot capture {}x{} (the lens's calibrated size); it offers {}",
        path.display(),
        cfg.width,
        cfg.height,
        sizes_seen.join(", ")
    )))
}

/// Switch each auto mode off and hold its value (given, or where the auto mode left it); read
/// every value back. A camera without a control records it as not offered.
pub(super) fn lock_controls(
    dev: &mut Device,
    cfg: &V4l2Config,
) -> Result<Vec<LockedControl>, CameraError> {
    let path = &cfg.path;
    let offered: Vec<Cid> = dev
        .controls()
        .filter_map(|c| c.ok().map(|c| c.id()))
        .collect();
    let mut out = Vec::new();
    for lock in &LOCKS {
        let want = match lock.name {
            "exposure" => cfg.exposure,
            "white_balance_k" => cfg.white_balance_k,
            _ => cfg.focus,
        };
        let auto_off = offered.contains(&lock.auto);
        if auto_off {
            dev.write_control_raw(lock.auto, lock.manual)
                .map_err(|e| dev_err(path, &format!("switching {} to manual", lock.name), e))?;
        }
        let value = if offered.contains(&lock.value) {
            let v = match want {
                Some(v) => v,
                None => dev
                    .read_control_raw(lock.value)
                    .map_err(|e| dev_err(path, &format!("reading {}", lock.name), e))?,
            };
            dev.write_control_raw(lock.value, v)
                .map_err(|e| dev_err(path, &format!("setting {} to {v}", lock.name), e))?;
            Some(
                dev.read_control_raw(lock.value)
                    .map_err(|e| dev_err(path, &format!("reading {} back", lock.name), e))?,
            )
        } else if want.is_some() {
            return Err(CameraError::Device(format!(
                "{}: the rig file sets {} but the camera has no such control",
                path.display(),
                lock.name
            )));
        } else {
            None
        };
        out.push(LockedControl {
            name: lock.name.to_string(),
            id: lock.value_id,
            value,
            auto_off,
        });
    }
    Ok(out)
}

/// Set the format and the frame rate, map the buffers and start streaming. Returns the stream,
/// the size the driver chose and the frame rate it reports (when one was asked).
#[allow(clippy::type_complexity)]
pub(super) fn start(
    dev: Device,
    cfg: &V4l2Config,
    pixel: PixelFormat,
) -> Result<(ReadStream, (u32, u32), Option<f64>), CameraError> {
    let path = &cfg.path;
    let asked = format!("{} {}x{}", pixel.name(), cfg.width, cfg.height);
    let cap = dev
        .video_capture(PixFormat::new(cfg.width, cfg.height, pixel.fourcc()))
        .map_err(|e| dev_err(path, &format!("setting {asked}"), e))?;
    let f = cap.format();
    let got = (f.width(), f.height(), f.pixel_format());
    if got != (cfg.width, cfg.height, pixel.fourcc()) {
        return Err(CameraError::Device(format!(
            "{}: asked {asked}, the driver chose {} {}x{}",
            path.display(),
            got.2,
            got.0,
            got.1
        )));
    }
    let reported = match cfg.fps {
        Some(fps) => {
            let den = (fps * 1000.0).round().max(1.0) as u32;
            let i = cap
                .set_frame_interval(Fract::new(1000, den))
                .map_err(|e| dev_err(path, &format!("asking {fps} frames/s"), e))?;
            Some(if i.numerator() == 0 {
                0.0
            } else {
                f64::from(i.denominator()) / f64::from(i.numerator())
            })
        }
        None => None,
    };
    let stream = cap
        .into_stream()
        .map_err(|e| dev_err(path, "mapping buffers and starting the stream", e))?;
    Ok((stream, (got.0, got.1), reported))
}
