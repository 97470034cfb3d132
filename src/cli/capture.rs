//! `cac capture`: a physical capture session — turn, settle, capture, write each frame and its
//! manifest line; `--resume` continues a killed session; `--simulate` runs the simulated
//! firmware on a pseudo-terminal and the digital twin camera; `--twin-camera` keeps the real
//! `--port` (a board, or the firmware in an emulator) and renders the frames with the digital
//! twin posed from what the driver reports.

use anyhow::{bail, Context, Result};
use cac::physical::camera::FrameSource;
use cac::physical::rig::Rig;
use cac::physical::session::{self, CaptureOptions, SessionInfo, SessionPlan};
use cac::physical::stage::{terminal_operator, TurntableStage};
use cac::physical::{SerialTransport, Turntable, TurntableConfig};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The rig file (calib/rig.toml is an example).
    #[arg(long)]
    pub rig: PathBuf,
    /// Camouflage atlas painted on the object (the twin renders it; recorded in the session).
    #[arg(long)]
    pub texture: Option<PathBuf>,
    /// Distance ratios, comma separated (default: the rig file's).
    #[arg(long)]
    pub ratios: Option<String>,
    /// Table angles: START:END:STEP (END exclusive) or a comma list, degrees.
    #[arg(long, default_value = "0:360:15")]
    pub angles: String,
    /// Captures of every (ratio, angle).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Session folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Simulated firmware (pseudo-terminal) and digital-twin camera.
    #[arg(long)]
    pub simulate: bool,
    /// Continue the session in --out, capturing only missing frames.
    #[arg(long)]
    pub resume: bool,
    /// Serial port of the turntable (real rig).
    #[arg(long)]
    pub port: Option<String>,
    /// V4L2 camera device (real rig; needs the v4l2 feature).
    #[arg(long, conflicts_with = "twin_camera")]
    pub camera: Option<PathBuf>,
    /// With --port: render the frames with the digital twin, posed from the table angle and
    /// rail position the driver reports, instead of a camera.
    #[arg(long, conflicts_with = "simulate")]
    pub twin_camera: bool,
    /// Simulated faults: none, drops, garbles, delays, resets, disconnects, mix.
    #[arg(long, default_value = "none")]
    pub faults: String,
    /// Seed of the simulated faults and of the twin's sensor noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// How much faster simulated time runs than real time.
    #[arg(long, default_value_t = 40.0)]
    pub speedup: f64,
}

pub fn run(a: Args) -> Result<()> {
    let rig = Arc::new(Rig::load(&a.rig)?);
    let ratios = match &a.ratios {
        Some(s) => SessionPlan::parse_ratios(s)?,
        None => rig.config.ratios.clone(),
    };
    let plan = SessionPlan::new(ratios, SessionPlan::parse_angles(&a.angles)?, a.repeats)?;
    let atlas = match &a.texture {
        Some(p) => cac::scene::Texture::from_rgb8(&cac::io::load_rgb(p)?),
        None => rig
            .renderer
            .scene
            .initial_atlas(rig.renderer.settings.atlas_res),
    };
    let settle = Duration::from_millis(rig.config.turntable.settle_ms);
    if a.simulate {
        let faults = cac::physical::simrig::faults_by_name(&a.faults, a.seed)?;
        let sim = cac::physical::simrig::SimRig::spawn(&rig, faults, a.speedup)?;
        let mut stage = sim.stage(&rig)?;
        let mut cam =
            cac::physical::twin::DigitalTwin::new(rig.clone(), &atlas, sim.pose_source(), a.seed);
        let info = new_info(&a, plan, &rig, cam.describe(), true)?;
        let sim = Arc::new(sim);
        let s2 = sim.clone();
        let opts = CaptureOptions {
            settle: Box::new(move || s2.settle(settle)),
            progress: true,
        };
        let sum = session::capture(&a.out, &info, &rig, &mut stage, &mut cam, &opts)?;
        report(&a, &sum);
        let w = sim.world().lock();
        println!(
            "simulated device: {}; {} boots; driver {:?}",
            w.fault_counts(),
            w.device().boots(),
            stage.turntable().stats()
        );
        return Ok(());
    }
    let Some(port) = &a.port else {
        bail!("--port is required with a real rig (or pass --simulate)");
    };
    // A real camera is opened before the port, so a wrong --camera fails before anything moves.
    let real_cam = match (&a.camera, a.twin_camera) {
        (_, true) => None,
        (Some(dev), false) => Some(open_camera(dev, rig.lens.width, rig.lens.height)?),
        (None, false) => {
            bail!("--camera (or --twin-camera) is required with a real rig (or pass --simulate)")
        }
    };
    let t = SerialTransport::open(port, 115_200)
        .with_context(|| format!("cannot open --port {port}"))?;
    let mut tt = Turntable::open(t, TurntableConfig::default())
        .with_context(|| format!("no turntable answers on {port}"))?;
    if let Some(v) = rig.config.turntable.speed_deg_s {
        tt.set_speed(cac::physical::Axis::Turntable, (v * 1000.0).round() as u32)?;
    }
    let mut stage = TurntableStage::new(tt, terminal_operator());
    let mut cam: Box<dyn FrameSource> = match real_cam {
        Some(c) => c,
        None => Box::new(cac::physical::twin::DigitalTwin::new(
            rig.clone(),
            &atlas,
            stage.reported_pose(),
            a.seed,
        )),
    };
    let info = new_info(&a, plan, &rig, cam.describe(), a.twin_camera)?;
    let opts = CaptureOptions {
        settle: Box::new(move || std::thread::sleep(settle)),
        progress: true,
    };
    let sum = session::capture(&a.out, &info, &rig, &mut stage, cam.as_mut(), &opts)?;
    report(&a, &sum);
    println!("driver {:?}", stage.turntable().stats());
    Ok(())
}

fn new_info(
    a: &Args,
    plan: SessionPlan,
    rig: &Rig,
    camera: String,
    simulated: bool,
) -> Result<SessionInfo> {
    let texture = a
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
    }
    .prepare(&a.out, a.resume)
}

fn report(a: &Args, s: &session::CaptureSummary) {
    if s.dropped_bytes > 0 {
        println!(
            "manifest: cut a partial last line ({} bytes) left by an interrupted run",
            s.dropped_bytes
        );
    }
    println!(
        "captured {} frames ({} were already in the session) into {}",
        s.captured,
        s.already,
        a.out.display()
    );
}

#[cfg(all(feature = "v4l2", target_os = "linux"))]
fn open_camera(dev: &std::path::Path, w: usize, h: usize) -> Result<Box<dyn FrameSource>> {
    use cac::physical::camera::v4l2::{V4l2Config, V4l2Source};
    let cfg = V4l2Config {
        path: dev.to_path_buf(),
        width: w as u32,
        height: h as u32,
        ..V4l2Config::default()
    };
    Ok(Box::new(
        V4l2Source::open(&cfg).with_context(|| format!("--camera {}", dev.display()))?,
    ))
}

#[cfg(not(all(feature = "v4l2", target_os = "linux")))]
fn open_camera(dev: &std::path::Path, _w: usize, _h: usize) -> Result<Box<dyn FrameSource>> {
    bail!("--camera {}: this cac was built without the v4l2 feature (cargo build --release --features v4l2)", dev.display())
}
