//! Turntable logs: the turntable angle (and camera distance ratio) against time, read as CSV
//! (`t,angle_deg[,ratio][,repeat]`) or JSON lines (`t`/`timestamp`, `angle`/`angle_deg`, optional
//! `ratio`/`distance_ratio`, `repeat`; other fields such as `frame` or `status` are ignored, so a
//! capture manifest with timestamps in seconds reads as a log).
//!
//! The angle between samples is interpolated linearly along the shorter way round (the log may
//! wrap at 360 or count up; consecutive samples must be less than half a turn apart); the ratio and repeat hold from one sample to the next. Each frame
//! gets a segment: its ratio (and repeat), and with [`LogSegments::Revolution`] also the whole
//! revolution it is in since the ratio began. The ground-truth box comes from the rig camera model
//! (`physical::rig_camera::RigCamera`: the viewpoint twin, or the calibrated rig).

use super::annotations::{GroundTruth, GtBox};
use anyhow::{bail, Context, Result};
use cac_physical::rig_camera::RigCamera;
use std::path::Path;

/// One log sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LogSample {
    /// Seconds on the log's clock.
    pub t: f64,
    pub angle_deg: f64,
    pub ratio: Option<f64>,
    pub repeat: Option<u32>,
}

/// Where the turntable was at a time.
#[derive(Clone, Debug, PartialEq)]
pub struct Pose {
    /// Unwrapped angle (degrees, continuous across 360).
    pub angle_deg: f64,
    pub ratio: Option<f64>,
    pub repeat: Option<u32>,
    /// Whole revolutions since the current ratio (and repeat) began.
    pub revolution: u32,
}

/// A turntable log: samples sorted by time, angles unwrapped.
#[derive(Clone, Debug)]
pub struct TurntableLog {
    samples: Vec<LogSample>,
    /// Index of the first sample of the ratio/repeat run each sample belongs to.
    run_start: Vec<usize>,
    pub source: String,
}

impl TurntableLog {
    /// Reads a `.csv` or `.jsonl` / `.json` (one object per line) log.
    pub fn load(path: &Path) -> Result<TurntableLog> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read turntable log {}", path.display()))?;
        let json = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("jsonl") || e.eq_ignore_ascii_case("json"));
        let samples = if json {
            parse_jsonl(&text)
        } else {
            parse_csv(&text)
        }
        .with_context(|| format!("turntable log {}", path.display()))?;
        let mut log = TurntableLog::new(samples)
            .with_context(|| format!("turntable log {}", path.display()))?;
        log.source = path.display().to_string();
        Ok(log)
    }

    /// Sorts by time, unwraps the angles and marks the ratio/repeat runs.
    pub fn new(mut samples: Vec<LogSample>) -> Result<TurntableLog> {
        if samples.len() < 2 {
            bail!("a turntable log needs at least two samples");
        }
        samples.sort_by(|a, b| a.t.total_cmp(&b.t));
        for w in samples.windows(2) {
            if w[1].t == w[0].t {
                bail!("two samples at t = {}", w[0].t);
            }
        }
        for k in 1..samples.len() {
            // The step in (-180, 180]: exactly half a turn counts as forward.
            let d = 180.0
                - (180.0 - (samples[k].angle_deg - samples[k - 1].angle_deg)).rem_euclid(360.0);
            samples[k].angle_deg = samples[k - 1].angle_deg + d;
        }
        let mut run_start = vec![0];
        for k in 1..samples.len() {
            let (a, b) = (&samples[k - 1], &samples[k]);
            let same = a.ratio == b.ratio && a.repeat == b.repeat;
            run_start.push(if same { run_start[k - 1] } else { k });
        }
        Ok(TurntableLog {
            samples,
            run_start,
            source: "turntable log".into(),
        })
    }

    pub fn samples(&self) -> &[LogSample] {
        &self.samples
    }

    /// The pose at log time `t`; `None` outside the log.
    pub fn pose(&self, t: f64) -> Option<Pose> {
        let s = &self.samples;
        if !(t >= s[0].t && t <= s[s.len() - 1].t) {
            return None;
        }
        let k = s.partition_point(|x| x.t <= t).max(1) - 1;
        let (a, b) = (&s[k], &s[(k + 1).min(s.len() - 1)]);
        let u = if b.t > a.t {
            (t - a.t) / (b.t - a.t)
        } else {
            0.0
        };
        let angle = a.angle_deg + u * (b.angle_deg - a.angle_deg);
        let start = s[self.run_start[k]].angle_deg;
        Some(Pose {
            angle_deg: angle,
            ratio: a.ratio,
            repeat: a.repeat,
            revolution: ((angle - start).abs() / 360.0 + 1e-9).floor() as u32,
        })
    }
}

fn parse_csv(text: &str) -> Result<Vec<LogSample>> {
    let table = super::csv::Table::parse(text)?;
    let col = |names: &[&str]| table.col(names);
    let t = col(&["t", "time", "timestamp"]).context("header needs a t column")?;
    let a = col(&["angle_deg", "angle"]).context("header needs an angle_deg column")?;
    let (r, rep) = (col(&["ratio", "distance_ratio"]), col(&["repeat"]));
    let mut out = Vec::new();
    for row in table.rows() {
        let num = |i: usize| row.num(i);
        out.push(LogSample {
            t: num(t)?,
            angle_deg: num(a)?,
            ratio: r.map(num).transpose()?,
            repeat: rep.map(num).transpose()?.map(|v| v as u32),
        });
    }
    Ok(out)
}

fn parse_jsonl(text: &str) -> Result<Vec<LogSample>> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: serde_json::Value = serde_json::from_str(line)
            .with_context(|| format!("line {}: not a JSON object", n + 1))?;
        let field = |names: &[&str]| names.iter().find_map(|k| v.get(*k)).cloned();
        let num = |names: &[&str], need: bool| -> Result<Option<f64>> {
            match field(names) {
                Some(x) => x.as_f64().map(Some).with_context(|| {
                    format!(
                        "line {}: {} must be a number of {}",
                        n + 1,
                        names[0],
                        unit(names[0])
                    )
                }),
                None if need => bail!("line {}: no {} field", n + 1, names.join("/")),
                None => Ok(None),
            }
        };
        out.push(LogSample {
            t: num(&["t", "timestamp"], true)?.unwrap(),
            angle_deg: num(&["angle_deg", "angle"], true)?.unwrap(),
            ratio: num(&["ratio", "distance_ratio"], false)?,
            repeat: num(&["repeat"], false)?.map(|v| v as u32),
        });
    }
    Ok(out)
}

fn unit(field: &str) -> &'static str {
    match field {
        "t" => "seconds",
        "angle_deg" => "degrees",
        _ => "units",
    }
}

/// How frames of a logged session are grouped for P@0.5 ± std.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogSegments {
    /// One segment per distance ratio (and repeat).
    Ratio,
    /// One segment per whole revolution within a ratio.
    Revolution,
}

cac_core::choices!(LogSegments {
    Ratio => "ratio": "One segment per distance ratio (and repeat)",
    Revolution => "revolution": "One segment per whole revolution within a ratio",
});

/// Ground truth from a log and a rig camera. Video time `t` is log time `t + offset_s`.
pub struct LogGroundTruth<C: RigCamera> {
    pub log: TurntableLog,
    pub camera: C,
    pub offset_s: f64,
    pub segments: LogSegments,
    /// The ratio of logs without one.
    pub default_ratio: f64,
}

impl<C: RigCamera> GroundTruth for LogGroundTruth<C> {
    fn at(&self, _index: u64, pts: f64) -> Result<Option<GtBox>> {
        let Some(p) = self.log.pose(pts + self.offset_s) else {
            return Ok(None);
        };
        let ratio = p.ratio.unwrap_or(self.default_ratio);
        let Some(bbox) = self.camera.object_box(p.angle_deg, ratio)? else {
            return Ok(None);
        };
        let mut seg = format!("ratio {ratio}");
        if let Some(r) = p.repeat {
            seg += &format!(" repeat {r}");
        }
        if self.segments == LogSegments::Revolution {
            seg += &format!(" rev {}", p.revolution);
        }
        Ok(Some(GtBox {
            bbox,
            segment: Some(seg),
            angle_deg: Some(p.angle_deg),
        }))
    }
    fn describe(&self) -> String {
        format!(
            "{} ({} samples, offset {} s) projected by {}",
            self.log.source,
            self.log.samples.len(),
            self.offset_s,
            self.camera.describe()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(t: f64, a: f64, r: f64) -> LogSample {
        LogSample {
            t,
            angle_deg: a,
            ratio: Some(r),
            repeat: None,
        }
    }

    #[test]
    fn angle_interpolates_across_the_wrap_and_counts_revolutions() {
        let log = TurntableLog::new(vec![
            s(0.0, 0.0, 2.0),
            s(1.0, 180.0, 2.0),
            s(2.0, 350.0, 2.0),
            s(3.0, 10.0, 2.0),
            s(4.0, 190.0, 2.0),
            s(5.0, 0.0, 3.0),
            s(6.0, 90.0, 3.0),
        ])
        .unwrap();
        assert!((log.pose(2.5).unwrap().angle_deg - 360.0).abs() < 1e-9);
        assert_eq!(log.pose(2.4).unwrap().revolution, 0);
        assert_eq!(log.pose(2.6).unwrap().revolution, 1);
        let p = log.pose(5.5).unwrap();
        assert_eq!(
            (p.ratio, p.revolution),
            (Some(3.0), 0),
            "new ratio restarts"
        );
        assert!(log.pose(-0.1).is_none() && log.pose(6.1).is_none());
    }

    #[test]
    fn csv_and_jsonl_logs() {
        let c = parse_csv("t,angle_deg,ratio\n0,0,2\n1,30,2\n").unwrap();
        assert_eq!(c[1], s(1.0, 30.0, 2.0));
        let j = parse_jsonl(
            "{\"frame\":0,\"timestamp\":0.5,\"angle\":10,\"ratio\":1.5,\"repeat\":1,\"status\":\"ok\"}\n",
        )
        .unwrap();
        assert_eq!((j[0].t, j[0].angle_deg, j[0].repeat), (0.5, 10.0, Some(1)));
        let e = parse_jsonl("{\"timestamp\":\"12:00\",\"angle\":1}").unwrap_err();
        assert!(format!("{e:#}").contains("seconds"), "{e:#}");
        assert!(parse_csv("angle\n1\n").is_err());
    }
}
