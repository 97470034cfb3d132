//! `cac capture`: a physical capture session — turn, settle, capture, write each frame and its
//! manifest line; `--resume` continues a killed session; `--simulate` runs the simulated
//! firmware on a pseudo-terminal and the digital twin camera; `--twin-camera` keeps the real
//! `--port` (a board, or the firmware in an emulator) and renders the frames with the digital
//! twin posed from what the driver reports. Parse → `cac::physical::capture::CaptureJob` (a real
//! rig) or `cac::sim::rig::capture` (the simulated one) → print.

use anyhow::{bail, Result};
use cac::physical::capture::{CaptureJob, CaptureOutcome};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub job: super::flags::physical::CaptureFlags,
    /// Simulated firmware (pseudo-terminal) and digital-twin camera.
    #[arg(long)]
    pub simulate: bool,
    /// Serial port of the turntable (real rig).
    #[arg(long)]
    pub port: Option<String>,
    /// V4L2 camera device (real rig, Linux).
    #[arg(long, conflicts_with = "twin_camera")]
    pub camera: Option<PathBuf>,
    /// With --port: render the frames with the digital twin, posed from the table angle and
    /// rail position the driver reports, instead of a camera.
    #[arg(long, conflicts_with = "simulate")]
    pub twin_camera: bool,
    /// Simulated faults: none, drops, garbles, delays, resets, disconnects, mix.
    #[arg(long, default_value = "none")]
    pub faults: String,
    /// How much faster simulated time runs than real time.
    #[arg(long, default_value_t = 40.0)]
    pub speedup: f64,
}

pub fn run(a: Args) -> Result<()> {
    let job = &CaptureJob::from(a.job.clone());
    let o = if a.simulate {
        simulated(job, &a.faults, a.speedup)?
    } else {
        let Some(port) = &a.port else {
            bail!("--port is required with a real rig (or pass --simulate)");
        };
        if a.camera.is_none() && !a.twin_camera {
            bail!("--camera (or --twin-camera) is required with a real rig (or pass --simulate)")
        }
        job.run(port, a.camera.as_deref().filter(|_| !a.twin_camera))?
    };
    let s = &o.summary;
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
        job.out.display()
    );
    println!("{}", o.device);
    Ok(())
}

#[cfg(unix)]
fn simulated(job: &CaptureJob, faults: &str, speedup: f64) -> Result<CaptureOutcome> {
    cac::sim::rig::capture(job, faults, speedup)
}

#[cfg(not(unix))]
fn simulated(_: &CaptureJob, _: &str, _: f64) -> Result<CaptureOutcome> {
    bail!("the simulated rig needs a pseudo-terminal (Unix)")
}
