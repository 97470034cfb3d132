//! `cac camera`: a camera checked as a session will use it, before anything turns — opened at
//! the rig's lens size with the rig file's frame rate and controls, locked, a few frames
//! captured the way the capture loop takes them (stale frames drained, faults recovered), and
//! written with `camera.json`: what the camera runs at and what happened on the way to each frame.

use super::camera::CameraSettings;
use super::rig::Rig;
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// What `cac camera` does (its flags).
#[derive(Clone, Debug)]
pub struct CameraCheck {
    /// The rig file: the lens size to capture at and the camera settings to lock.
    pub rig: PathBuf,
    /// V4L2 device node.
    pub device: PathBuf,
    /// Frames to capture.
    pub frames: usize,
    /// Folder for the frames and camera.json.
    pub out: PathBuf,
}

/// `camera.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraReport {
    /// The camera's one-line description.
    pub camera: String,
    /// What it was locked to and runs at (none for sources without settings).
    pub settings: Option<CameraSettings>,
    /// The frames, in capture order.
    pub frames: Vec<CheckedFrame>,
}

/// One frame of the check.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckedFrame {
    /// PNG file, relative to the output folder.
    pub file: String,
    /// The camera's description of the frame.
    pub origin: String,
    /// What was recovered on the way to it.
    pub events: Vec<String>,
}

impl CameraCheck {
    /// Opens the camera, captures the frames, writes each and `camera.json` as it arrives
    /// (atomically) and returns the report.
    pub fn run(&self) -> Result<CameraReport> {
        let rig = Rig::load(&self.rig)?;
        let mut cam = super::capture::open_camera(&self.device, &rig, None)?;
        std::fs::create_dir_all(&self.out)
            .with_context(|| format!("cannot create {}", self.out.display()))?;
        let mut report = CameraReport {
            camera: cam.describe(),
            settings: cam.settings(),
            frames: Vec::new(),
        };
        for i in 0..self.frames {
            let f = cam
                .capture()
                .with_context(|| format!("{}: frame {i}", self.device.display()))?;
            let file = format!("frame_{i:03}.png");
            cac_core::io::save_png_atomic(&self.out.join(&file), &f.image)?;
            report.frames.push(CheckedFrame {
                file,
                origin: f.origin,
                events: f.events,
            });
            // Rewritten after every frame: a check that fails later keeps what it found.
            cac_core::io::write_atomic(
                &self.out.join("camera.json"),
                serde_json::to_string_pretty(&report)?.as_bytes(),
            )?;
        }
        Ok(report)
    }
}
