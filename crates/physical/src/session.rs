//! A capture session: the plan (distance ratios × table angles × repeats), the session folder
//! (`session.json`, `frames/`, `manifest.jsonl`), and the capture loop — set the distance, turn,
//! settle, capture, write the frame atomically, append its manifest line. Resuming captures each
//! frame missing from the manifest exactly once.

use super::calib::CameraModel;
use super::camera::{CameraSettings, FrameSource};
use super::manifest::{key_of, Entry, Manifest};
use super::rig::{Rig, RigConfig};
use super::stage::Stage;
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// What a session captures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionPlan {
    pub ratios: Vec<f64>,
    /// Table angles (degrees, in [0, 360)).
    pub angles: Vec<f64>,
    pub repeats: usize,
}

/// One frame of the plan.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedFrame {
    pub ratio: f64,
    pub angle: f64,
    pub repeat: usize,
    /// Image path relative to the session folder.
    pub file: String,
}

impl SessionPlan {
    /// Checks the plan.
    pub fn new(ratios: Vec<f64>, angles: Vec<f64>, repeats: usize) -> Result<Self> {
        if ratios.is_empty() || ratios.iter().any(|r| !(*r > 0.0 && r.is_finite())) {
            bail!("--ratios: need at least one positive distance ratio, got {ratios:?}");
        }
        if angles.is_empty() || angles.iter().any(|a| !(0.0..360.0).contains(a)) {
            bail!("--angles: need at least one angle in [0, 360), got {angles:?}");
        }
        if repeats == 0 {
            bail!("--repeats must be at least 1");
        }
        Ok(SessionPlan {
            ratios,
            angles,
            repeats,
        })
    }

    /// Parses `START:END:STEP` (END exclusive) or a comma list of angles (degrees).
    pub fn parse_angles(s: &str) -> Result<Vec<f64>> {
        let num = |t: &str| {
            t.trim()
                .parse::<f64>()
                .with_context(|| format!("--angles {s:?}: {t:?} is not a number"))
        };
        if let [a, b, c] = s.split(':').collect::<Vec<_>>()[..] {
            let (a, b, c) = (num(a)?, num(b)?, num(c)?);
            if c.is_nan() || c <= 0.0 || b <= a || (b - a) / c > 100_000.0 {
                bail!("--angles {s:?}: expected START:END:STEP with END > START and STEP > 0");
            }
            let n = ((b - a) / c - 1e-9).ceil() as usize;
            return Ok((0..n)
                .map(|i| (a + i as f64 * c).rem_euclid(360.0))
                .collect());
        }
        s.split(',')
            .map(|t| Ok(num(t)?.rem_euclid(360.0)))
            .collect()
    }

    /// Parses a comma list of distance ratios.
    pub(crate) fn parse_ratios(s: &str) -> Result<Vec<f64>> {
        s.split(',')
            .map(|t| {
                t.trim()
                    .parse::<f64>()
                    .with_context(|| format!("--ratios {s:?}: {t:?} is not a number"))
            })
            .collect()
    }

    /// Every frame in capture order: per ratio (one camera move each), per repeat, per angle.
    pub fn frames(&self) -> Vec<PlannedFrame> {
        let mut v = Vec::new();
        for &ratio in &self.ratios {
            for repeat in 0..self.repeats {
                for &angle in &self.angles {
                    v.push(PlannedFrame {
                        ratio,
                        angle,
                        repeat,
                        file: format!("frames/r{ratio:.2}_a{angle:07.3}_k{repeat}.png"),
                    });
                }
            }
        }
        v
    }
}

/// `session.json`: everything needed to resume and to score.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionInfo {
    pub plan: SessionPlan,
    /// The rig file as read (paths made absolute) and the lens it names.
    pub rig: RigConfig,
    pub lens: CameraModel,
    /// The camouflage atlas on the object (none: the object's own texture).
    pub texture: Option<PathBuf>,
    /// The camera, as described by its frame source.
    pub camera: String,
    pub simulated: bool,
    /// What a real camera was locked to and runs at (format, size, frame rate asked, reported
    /// and measured, exposure, white balance, focus); absent for the twin and folders.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_settings: Option<CameraSettings>,
}

impl SessionInfo {
    /// Reads `DIR/session.json`.
    pub fn load(dir: &Path) -> Result<Self> {
        let p = dir.join("session.json");
        let t = std::fs::read_to_string(&p).with_context(|| {
            format!(
                "cannot read {} (is {} a capture session?)",
                p.display(),
                dir.display()
            )
        })?;
        serde_json::from_str(&t).with_context(|| format!("malformed {}", p.display()))
    }

    /// Starts or resumes the session in `dir`. A new session refuses a folder that already
    /// holds one; resuming requires the same plan, rig and lens.
    pub fn prepare(self, dir: &Path, resume: bool) -> Result<Self> {
        let p = dir.join("session.json");
        if resume {
            let old = SessionInfo::load(dir)?;
            // Compare after the same JSON round trip (float parsing need not be bit-exact).
            let new: SessionInfo = serde_json::from_str(&serde_json::to_string(&self)?)?;
            if old.plan != new.plan {
                bail!(
                    "--resume: the plan differs from the session's in {} ({:?} vs {:?})",
                    p.display(),
                    new.plan,
                    old.plan
                );
            }
            if old.rig != new.rig || old.lens != new.lens {
                bail!(
                    "--resume: the rig file or its calibration changed since the session in {} started",
                    dir.display()
                );
            }
            if let (Some(was), Some(now)) = (&old.camera_settings, &new.camera_settings) {
                let held =
                    |s: &CameraSettings| (s.format.clone(), s.width, s.height, s.controls.clone());
                if held(was) != held(now) {
                    bail!(
                        "--resume: the camera runs at {:?}, the session in {} was captured at {:?} (format, size, controls)",
                        held(now),
                        dir.display(),
                        held(was)
                    );
                }
            }
            return Ok(old);
        }
        if p.exists() {
            bail!(
                "{} already holds a capture session: pass --resume to continue it, or choose another --out",
                dir.display()
            );
        }
        cac_core::io::write_atomic(&p, serde_json::to_string_pretty(&self)?.as_bytes())?;
        Ok(self)
    }
}

/// How the capture loop waits and reports.
pub struct CaptureOptions {
    /// Wait after each move before capturing.
    pub settle: Box<dyn Fn()>,
    /// Show a progress bar on stderr.
    pub progress: bool,
}

/// What a capture run did.
#[derive(Debug, Clone, Default)]
pub struct CaptureSummary {
    /// Frames captured in this run.
    pub captured: usize,
    /// Frames already in the manifest.
    pub already: usize,
    /// Bytes of a partial manifest line cut off on start.
    pub dropped_bytes: usize,
}

fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or(Duration::ZERO)
        .as_secs_f64()
}

/// Captures every planned frame missing from `dir/manifest.jsonl`.
pub fn capture(
    dir: &Path,
    info: &SessionInfo,
    rig: &Rig,
    stage: &mut dyn Stage,
    camera: &mut dyn FrameSource,
    opts: &CaptureOptions,
) -> Result<CaptureSummary> {
    let loaded = Manifest::open(&dir.join("manifest.jsonl"))?;
    let mut manifest = loaded.manifest;
    let done: HashSet<(String, usize)> = loaded.entries.iter().map(Entry::key).collect();
    let todo: Vec<_> = info
        .plan
        .frames()
        .into_iter()
        .filter(|f| !done.contains(&(key_of(f.ratio, f.angle), f.repeat)))
        .collect();
    let mut sum = CaptureSummary {
        already: loaded.entries.len(),
        dropped_bytes: loaded.dropped_bytes,
        ..Default::default()
    };
    let bar = if opts.progress {
        indicatif::ProgressBar::new(todo.len() as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} frames, {elapsed} elapsed, ETA {eta} {msg}",
        )
        .expect("valid template"),
    );
    let mut ratio = None;
    for f in &todo {
        if ratio != Some(f.ratio) {
            bar.suspend(|| stage.set_ratio(f.ratio, rig))?;
            ratio = Some(f.ratio);
        }
        bar.set_message(format!(
            "ratio {} angle {} repeat {}",
            f.ratio, f.angle, f.repeat
        ));
        stage.turn_to(f.angle)?;
        (opts.settle)();
        let frame = camera
            .capture()
            .with_context(|| format!("capturing {}", f.file))?;
        let timestamp = now_s();
        cac_core::io::save_png_atomic(&dir.join(&f.file), &frame.image)?;
        manifest.append(&Entry {
            frame: f.file.clone(),
            angle: f.angle,
            ratio: f.ratio,
            repeat: f.repeat,
            timestamp,
            device: stage.status(),
            camera: frame.origin,
            camera_events: frame.events,
        })?;
        sum.captured += 1;
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(sum)
}
