//! `ffprobe` of the first video stream: codec, size, display rotation (display-matrix side data,
//! or the older `rotate` tag), frame rates and frame count; and the per-frame presentation
//! timestamps (`-show_entries frame=best_effort_timestamp_time`), for variable frame rate.

use crate::tools::{ctx_input, run_tool, Tools};
use anyhow::{bail, Context, Result};
use serde_json::Value;
use std::ffi::OsStr;
use std::path::Path;

/// The codecs whose tolerances were measured (docs/video.md); others need `allow_any_codec`.
pub(crate) const SUPPORTED_CODECS: [&str; 4] = ["h264", "hevc", "mjpeg", "png"];

/// What ffprobe says about the first video stream.
#[derive(Clone, Debug, PartialEq)]
pub struct StreamInfo {
    pub codec: String,
    /// Stored (coded) size, before rotation.
    pub width: u32,
    pub height: u32,
    /// Counter-clockwise degrees (0, 90, 180, 270) to turn the stored picture for display.
    pub rotation_ccw: u32,
    /// Average frame rate (frames/s), when known.
    pub avg_fps: Option<f64>,
    /// The stream's base ("real") frame rate; differs from `avg_fps` for variable frame rate.
    pub r_fps: Option<f64>,
    pub frames: Option<u64>,
    pub duration_s: Option<f64>,
    /// The `creation_time` tag (stream, else container) as Unix seconds: when the recording
    /// started on most cameras (some phones write the end; check against a visible event).
    pub creation_time: Option<f64>,
}

impl StreamInfo {
    /// Size of the displayed (rotated) frames.
    pub fn display_size(&self) -> (u32, u32) {
        if self.rotation_ccw % 180 == 90 {
            (self.height, self.width)
        } else {
            (self.width, self.height)
        }
    }

    /// A heuristic from the header only: the average and base frame rates differ.
    pub fn looks_variable_rate(&self) -> bool {
        match (self.avg_fps, self.r_fps) {
            (Some(a), Some(r)) => (a - r).abs() > 1e-3 * r.max(1.0),
            _ => false,
        }
    }
}

fn rate(v: &Value) -> Option<f64> {
    let s = v.as_str()?;
    let (n, d) = s.split_once('/').unwrap_or((s, "1"));
    let (n, d): (f64, f64) = (n.parse().ok()?, d.parse().ok()?);
    (n > 0.0 && d > 0.0).then_some(n / d)
}

fn num(v: &Value) -> Option<f64> {
    match v {
        Value::String(s) => s.parse().ok(),
        Value::Number(n) => n.as_f64(),
        _ => None,
    }
}

/// Counter-clockwise display rotation from a stream's side data (preferred) or `rotate` tag
/// (clockwise degrees), rounded to a multiple of 90.
pub(crate) fn rotation_of(stream: &Value) -> Result<u32> {
    let side = stream["side_data_list"].as_array().and_then(|l| {
        l.iter()
            .find(|s| s["side_data_type"].as_str() == Some("Display Matrix"))
            .and_then(|s| num(&s["rotation"]))
    });
    let ccw = match side {
        Some(r) => r,
        None => match num(&stream["tags"]["rotate"]) {
            Some(cw) => -cw,
            None => 0.0,
        },
    };
    let q = (ccw / 90.0).round();
    if (ccw - 90.0 * q).abs() > 1.0 {
        bail!("display rotation of {ccw} degrees is not a multiple of 90 (not supported)");
    }
    Ok(((q as i64).rem_euclid(4) * 90) as u32)
}

/// Probes the first video stream of `path` (a file or an image-sequence pattern).
pub fn probe(tools: &Tools, path: &Path) -> Result<StreamInfo> {
    if !crate::tools::is_pattern(path) && !path.is_file() {
        bail!("cannot read video {}: no such file", path.display());
    }
    let out = run_tool(
        tools,
        &tools.ffprobe,
        &[
            OsStr::new("-v"),
            OsStr::new("error"),
            OsStr::new("-print_format"),
            OsStr::new("json"),
            OsStr::new("-show_streams"),
            OsStr::new("-show_format"),
            path.as_os_str(),
        ],
    )
    .with_context(ctx_input(path))?;
    let v: Value = serde_json::from_slice(&out)
        .with_context(|| format!("ffprobe gave unreadable JSON for {}", path.display()))?;
    let stream = v["streams"]
        .as_array()
        .and_then(|s| s.iter().find(|s| s["codec_type"] == "video"))
        .with_context(|| format!("{} has no video stream", path.display()))?;
    let codec = stream["codec_name"]
        .as_str()
        .unwrap_or("unknown")
        .to_string();
    let (width, height) = (
        stream["width"].as_u64().unwrap_or(0) as u32,
        stream["height"].as_u64().unwrap_or(0) as u32,
    );
    if width == 0 || height == 0 {
        bail!(
            "{}: video stream ({codec}) has no frame size (unreadable or unsupported codec)",
            path.display()
        );
    }
    let duration_s = num(&stream["duration"]).or_else(|| num(&v["format"]["duration"]));
    let creation_time = [&stream["tags"], &v["format"]["tags"]]
        .iter()
        .find_map(|t| t["creation_time"].as_str().and_then(parse_utc));
    Ok(StreamInfo {
        rotation_ccw: rotation_of(stream).with_context(|| path.display().to_string())?,
        codec,
        width,
        height,
        avg_fps: rate(&stream["avg_frame_rate"]),
        r_fps: rate(&stream["r_frame_rate"]),
        frames: num(&stream["nb_frames"]).map(|n| n as u64),
        duration_s,
        creation_time,
    })
}

/// Unix seconds of an ISO 8601 UTC time `YYYY-MM-DDTHH:MM:SS[.frac]Z` (the form ffmpeg writes).
pub(crate) fn parse_utc(s: &str) -> Option<f64> {
    let s = s.trim().strip_suffix('Z').unwrap_or(s.trim());
    let (date, time) = s.split_once(['T', ' '])?;
    let d: Vec<i64> = date
        .split('-')
        .map(|x| x.parse().ok())
        .collect::<Option<_>>()?;
    let (hms, frac) = time.split_once('.').unwrap_or((time, ""));
    let t: Vec<i64> = hms
        .split(':')
        .map(|x| x.parse().ok())
        .collect::<Option<_>>()?;
    if d.len() != 3 || t.len() != 3 || !(1..=12).contains(&d[1]) || !(1..=31).contains(&d[2]) {
        return None;
    }
    // Days from 1970-01-01 of a proleptic Gregorian date (H. Hinnant's days_from_civil).
    let (y, m) = if d[1] <= 2 {
        (d[0] - 1, d[1] + 9)
    } else {
        (d[0], d[1] - 3)
    };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * m + 2) / 5 + d[2] - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe - 719_468;
    let frac: f64 = if frac.is_empty() {
        0.0
    } else {
        format!("0.{frac}").parse().ok()?
    };
    Some((days * 86_400 + t[0] * 3600 + t[1] * 60 + t[2]) as f64 + frac)
}

/// Presentation time (s) of every frame of the first video stream, in presentation order. Decodes
/// the whole stream once (slow for long videos); the scorer takes its times from the decode pass.
pub fn frame_times(tools: &Tools, path: &Path) -> Result<Vec<f64>> {
    let out = run_tool(
        tools,
        &tools.ffprobe,
        &[
            OsStr::new("-v"),
            OsStr::new("error"),
            OsStr::new("-select_streams"),
            OsStr::new("v:0"),
            OsStr::new("-show_entries"),
            OsStr::new("frame=best_effort_timestamp_time"),
            OsStr::new("-of"),
            OsStr::new("csv=p=0"),
            path.as_os_str(),
        ],
    )
    .with_context(ctx_input(path))?;
    let text = String::from_utf8_lossy(&out);
    let mut t: Vec<f64> = text
        .lines()
        .map(|l| l.trim().trim_end_matches(','))
        .filter(|l| !l.is_empty())
        .map(|l| {
            l.parse::<f64>()
                .with_context(|| format!("ffprobe frame time {l:?} of {}", path.display()))
        })
        .collect::<Result<_>>()?;
    t.sort_by(f64::total_cmp);
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_from_side_data_or_tag() {
        let s: Value = serde_json::json!({"side_data_list": [
            {"side_data_type": "Display Matrix", "rotation": -90}]});
        assert_eq!(rotation_of(&s).unwrap(), 270);
        let s: Value = serde_json::json!({"tags": {"rotate": "90"}});
        assert_eq!(rotation_of(&s).unwrap(), 270, "tag is clockwise");
        let s: Value = serde_json::json!({"side_data_list": [
            {"side_data_type": "Display Matrix", "rotation": 180.0}], "tags": {"rotate": "90"}});
        assert_eq!(rotation_of(&s).unwrap(), 180, "side data wins");
        assert_eq!(rotation_of(&serde_json::json!({})).unwrap(), 0);
        let s: Value = serde_json::json!({"tags": {"rotate": "45"}});
        assert!(rotation_of(&s).is_err());
    }

    #[test]
    fn utc_times() {
        assert_eq!(parse_utc("1970-01-01T00:00:00.000000Z"), Some(0.0));
        assert_eq!(parse_utc("2000-03-01T00:00:01Z"), Some(951_868_801.0));
        assert_eq!(
            parse_utc("2026-11-22T07:09:04.500000Z"),
            Some(1_795_331_344.5)
        );
        assert_eq!(parse_utc("yesterday"), None);
    }

    #[test]
    fn frame_rates_parse() {
        assert_eq!(rate(&Value::from("30000/1001")), Some(30000.0 / 1001.0));
        assert_eq!(rate(&Value::from("0/0")), None);
    }
}
