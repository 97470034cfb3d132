//! `cac capture`: a physical capture session — turn, settle, capture, write each frame and its
//! manifest line; `--resume` continues a killed session; `--simulate` runs the simulated
//! firmware on a pseudo-terminal and the digital twin camera; `--twin-camera` keeps the real
//! `--port` (a board, or the firmware in an emulator) and renders the frames with the digital
//! twin posed from what the driver reports. Parse → `cac::physical::capture::CaptureJob` → print.

use anyhow::{bail, Result};
use cac::physical::capture::{CaptureJob, Device};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub job: CaptureJob,
    /// Simulated firmware (pseudo-terminal) and digital-twin camera.
    #[arg(long)]
    pub simulate: bool,
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
    /// How much faster simulated time runs than real time.
    #[arg(long, default_value_t = 40.0)]
    pub speedup: f64,
}

pub fn run(a: Args) -> Result<()> {
    let mut job = a.job;
    job.device = if a.simulate {
        Device::Simulated {
            faults: a.faults.clone(),
            speedup: a.speedup,
        }
    } else {
        let Some(port) = &a.port else {
            bail!("--port is required with a real rig (or pass --simulate)");
        };
        if a.camera.is_none() && !a.twin_camera {
            bail!("--camera (or --twin-camera) is required with a real rig (or pass --simulate)")
        }
        Device::Serial {
            port: port.clone(),
            camera: a.camera.clone().filter(|_| !a.twin_camera),
        }
    };
    let o = job.run()?;
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
