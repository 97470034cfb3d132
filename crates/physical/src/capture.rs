//! One capture session run end to end (`cac capture`): load the rig, plan the session, set up the
//! stage and the camera — a real turntable on a serial port with a V4L2 camera or the twin posed
//! from what the driver reports — prepare (or resume) the session folder and capture
//! ([`super::session::capture`]). [`CaptureJob::run`] returns what the caller prints. The same
//! job on the simulated rig (firmware on a pseudo-terminal, the twin as camera) is
//! `crate::sim::rig::capture`, built from [`CaptureJob::prepare`] and [`CaptureJob::info`].

use super::camera::{CameraSettings, FrameSource};
use super::rig::Rig;
use super::session::{self, CaptureOptions, CaptureSummary, SessionInfo, SessionPlan};
use super::stage::{terminal_operator, TurntableStage};
use super::twin::DigitalTwin;
use super::{Axis, SerialTransport, Turntable, TurntableConfig};
use anyhow::{Context, Result};
use cac_scene::Texture;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// Everything a capture needs but the device (its flags are `cac capture`'s).
#[derive(Clone, Debug)]
pub struct CaptureJob {
    /// The rig file (calib/rig.toml is an example).
    pub rig: PathBuf,
    /// Camouflage atlas painted on the object (the twin renders it; recorded in the session;
    /// default: the mesh's own look).
    pub texture: Option<PathBuf>,
    /// Distance ratios, comma separated (default: the rig file's).
    pub ratios: Option<String>,
    /// Table angles: START:END:STEP (END exclusive) or a comma list, degrees.
    pub angles: String,
    /// Captures of every (ratio, angle).
    pub repeats: usize,
    /// Session folder.
    pub out: PathBuf,
    /// Continue the session in --out, capturing only missing frames.
    pub resume: bool,
    /// Seed of the simulated faults and of the twin's sensor noise.
    pub seed: u64,
}

/// What a capture did.
pub struct CaptureOutcome {
    pub summary: CaptureSummary,
    /// The device's own account (simulated faults and boots, driver statistics).
    pub device: String,
}

impl CaptureJob {
    /// Captures the session with the turntable on serial `port` and the V4L2 `camera`, or
    /// (`None`) the digital twin posed from the angle and rail position the driver reports (a
    /// progress bar on stderr; an operator prompt on the terminal when no rail moves the camera).
    pub fn run(&self, port: &str, camera: Option<&std::path::Path>) -> Result<CaptureOutcome> {
        let (rig, plan, atlas) = self.prepare()?;
        self.serial(&rig, plan, &atlas, port, camera)
    }

    /// The rig, the session plan and the atlas the twin paints.
    pub fn prepare(&self) -> Result<(Arc<Rig>, SessionPlan, Texture)> {
        let rig = Arc::new(Rig::load(&self.rig)?);
        let ratios = match &self.ratios {
            Some(s) => SessionPlan::parse_ratios(s)?,
            None => rig.config.ratios.clone(),
        };
        let plan = SessionPlan::new(
            ratios,
            SessionPlan::parse_angles(&self.angles)?,
            self.repeats,
        )?;
        let atlas = match &self.texture {
            Some(p) => Texture::from_rgb8(&cac_core::io::load_rgb(p)?),
            None => rig
                .renderer
                .scene
                .initial_atlas(rig.renderer.settings.atlas_res),
        };
        Ok((rig, plan, atlas))
    }

    fn serial(
        &self,
        rig: &Arc<Rig>,
        plan: SessionPlan,
        atlas: &Texture,
        port: &str,
        camera: Option<&std::path::Path>,
    ) -> Result<CaptureOutcome> {
        // A real camera is opened before the port, so a wrong camera fails before anything moves.
        // Resuming holds it at the settings the session was captured with.
        let recorded = match (camera, self.resume) {
            (Some(_), true) => SessionInfo::load(&self.out)?.camera_settings,
            _ => None,
        };
        let real_cam = match camera {
            None => None,
            Some(dev) => Some(open_camera(dev, rig, recorded.as_ref())?),
        };
        let t = SerialTransport::open(port, 115_200)
            .with_context(|| format!("cannot open --port {port}"))?;
        let mut tt = Turntable::open(t, TurntableConfig::default())
            .with_context(|| format!("no turntable answers on {port}"))?;
        if let Some(v) = rig.config.turntable.speed_deg_s {
            tt.set_speed(Axis::Turntable, (v * 1000.0).round() as u32)?;
        }
        let mut stage = TurntableStage::new(tt, terminal_operator());
        let twin = real_cam.is_none();
        let mut cam: Box<dyn FrameSource> = match real_cam {
            Some(c) => c,
            None => Box::new(DigitalTwin::new(
                rig.clone(),
                atlas,
                stage.reported_pose(),
                self.seed,
            )),
        };
        let info = self.info(plan, rig, cam.describe(), cam.settings(), twin)?;
        let settle = Duration::from_millis(rig.config.turntable.settle_ms);
        let opts = CaptureOptions {
            settle: Box::new(move || std::thread::sleep(settle)),
            progress: true,
        };
        let summary = session::capture(&self.out, &info, rig, &mut stage, cam.as_mut(), &opts)?;
        let device = format!("driver {:?}", stage.turntable().stats());
        Ok(CaptureOutcome { summary, device })
    }

    /// The session's `session.json`, written (or checked against the folder on resume).
    pub fn info(
        &self,
        plan: SessionPlan,
        rig: &Rig,
        camera: String,
        camera_settings: Option<CameraSettings>,
        simulated: bool,
    ) -> Result<SessionInfo> {
        let texture = self
            .texture
            .as_ref()
            .map(|p| std::path::absolute(p).unwrap_or(p.clone()));
        SessionInfo {
            plan,
            rig: rig.config.clone(),
            lens: rig.lens.clone(),
            texture,
            camera,
            simulated,
            camera_settings,
        }
        .prepare(&self.out, self.resume)
    }
}

/// The V4L2 camera at the lens's size, with the rig file's frame rate and control values, or
/// (resuming) the values the session recorded.
#[cfg(target_os = "linux")]
pub(crate) fn open_camera(
    dev: &std::path::Path,
    rig: &Rig,
    recorded: Option<&CameraSettings>,
) -> Result<Box<dyn FrameSource>> {
    use super::camera::v4l2::{V4l2Config, V4l2Source};
    let mount = &rig.config.camera;
    let held = |name: &str| {
        recorded.and_then(|s| {
            s.controls
                .iter()
                .find(|c| c.name == name)
                .and_then(|c| c.value)
        })
    };
    let cfg = V4l2Config {
        path: dev.to_path_buf(),
        width: rig.lens.width as u32,
        height: rig.lens.height as u32,
        fps: mount.fps,
        exposure: held("exposure").or(mount.exposure),
        white_balance_k: held("white_balance_k").or(mount.white_balance_k),
        focus: held("focus").or(mount.focus),
        ..V4l2Config::default()
    };
    Ok(Box::new(
        V4l2Source::open(&cfg).context("opening the camera")?,
    ))
}

#[cfg(not(target_os = "linux"))]
pub(crate) fn open_camera(
    dev: &std::path::Path,
    _: &Rig,
    _: Option<&CameraSettings>,
) -> Result<Box<dyn FrameSource>> {
    anyhow::bail!(
        "--camera {}: V4L2 cameras are read on Linux only",
        dev.display()
    )
}
