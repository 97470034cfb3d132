//! The whole rig simulated: the simulated firmware behind a pseudo-terminal (so the real serial
//! driver is exercised), a simulated operator when there is no rail, and the digital twin's pose
//! read from the simulated mechanics. Simulated time runs `speedup` times faster than real time.
//! [`capture`] is `cac capture --simulate`: a whole session on the simulated rig.

#![cfg(unix)]

use super::{DeviceConfig, FaultConfig, LinkConfig, PtySim, SimHandle, SimWorld};
use crate::capture::{CaptureJob, CaptureOutcome};
use crate::rig::Rig;
use crate::serial::SerialTransport;
use crate::session::{self, CaptureOptions};
use crate::stage::TurntableStage;
use crate::turntable::{Turntable, TurntableConfig};
use crate::twin::{DigitalTwin, Pose, PoseSource};
use anyhow::{Context, Result};
use firmware_protocol::Axis;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// A simulated rig.
pub struct SimRig {
    pty: PtySim,
    speedup: f64,
    rail_near_m: Option<f64>,
    /// Where the simulated operator put the camera (m from the axis).
    manual: Arc<Mutex<f64>>,
}

impl SimRig {
    /// Starts the simulated firmware (with a rail when the rig file has one) with `faults`.
    pub fn spawn(rig: &Rig, faults: FaultConfig, speedup: f64) -> Result<SimRig> {
        let rail = &rig.config.rail;
        let device = DeviceConfig {
            rail: rail
                .present
                .then(|| (0, (rail.length_m * 1e6).round() as i32)),
            ..DeviceConfig::default()
        };
        let pty = PtySim::spawn(
            SimWorld::new(device, LinkConfig::default(), faults),
            speedup,
        )
        .context("cannot start the simulated turntable on a pseudo-terminal")?;
        let start = rig.horizontal_distance(rig.config.ratios[0])?;
        Ok(SimRig {
            pty,
            speedup,
            rail_near_m: rail.present.then_some(rail.near_m),
            manual: Arc::new(Mutex::new(start)),
        })
    }

    /// The simulated world (device log, fault counts).
    pub fn world(&self) -> &SimHandle {
        self.pty.world()
    }

    /// The serial port path the driver opens.
    pub fn port(&self) -> &std::path::Path {
        self.pty.path()
    }

    /// Driver timing for the sped-up clock.
    pub fn driver_config(&self) -> TurntableConfig {
        TurntableConfig {
            attempt_timeout: Duration::from_millis(60),
            boot_wait: Duration::from_millis(150),
            reconnect_backoff: Duration::from_millis(20),
            done_slack: Duration::from_millis(150),
            // The device reports ETAs in simulated time.
            done_factor: 1.5 / self.speedup,
            ..TurntableConfig::default()
        }
    }

    /// The real driver on the pty, with a simulated operator moving the camera when needed.
    pub fn stage(&self, rig: &Rig) -> Result<TurntableStage<SerialTransport>> {
        let path = self.port().to_str().context("pty path is not UTF-8")?;
        let port = SerialTransport::open(path, 115_200)
            .with_context(|| format!("cannot open the simulated port {path}"))?;
        let mut tt = Turntable::open(port, self.driver_config())
            .context("cannot reach the simulated turntable")?;
        if let Some(v) = rig.config.turntable.speed_deg_s {
            tt.set_speed(Axis::Turntable, (v * 1000.0).round() as u32)?;
        }
        let manual = self.manual.clone();
        let operator = Box::new(move |_ratio: f64, dist: f64| {
            *manual.lock().unwrap_or_else(|e| e.into_inner()) = dist;
            Ok(())
        });
        Ok(TurntableStage::new(tt, operator))
    }

    /// The twin's pose: the table's mechanical angle (whatever the driver believes) and the
    /// rail's mechanical position or the simulated operator's camera distance.
    pub fn pose_source(&self) -> PoseSource {
        let world = self.world().clone();
        let manual = self.manual.clone();
        let near = self.rail_near_m;
        Box::new(move || {
            let w = world.lock();
            let d = w.device();
            if d.is_moving(Axis::Turntable) || near.is_some() && d.is_moving(Axis::Rail) {
                return Err("the rig is still moving at capture time".into());
            }
            let angle = d.physical_position(Axis::Turntable) / 1000.0;
            let horizontal_m = match near {
                Some(n) => n + d.physical_position(Axis::Rail) * 1e-6,
                None => *manual.lock().unwrap_or_else(|e| e.into_inner()),
            };
            Ok(Pose {
                angle_deg: angle.rem_euclid(360.0),
                horizontal_m,
            })
        })
    }

    /// Wait `settle` of simulated time.
    pub fn settle(&self, settle: Duration) {
        std::thread::sleep(settle.div_f64(self.speedup));
    }
}

/// The fault kinds `cac capture --simulate --faults` accepts.
pub(crate) const FAULT_KINDS: [&str; 7] = [
    "none",
    "drops",
    "garbles",
    "delays",
    "resets",
    "disconnects",
    "mix",
];

/// A fault configuration by name (rates as in the driver's own pty tests).
pub fn faults_by_name(name: &str, seed: u64) -> Result<FaultConfig> {
    Ok(match name {
        "none" => FaultConfig::none(),
        "drops" => FaultConfig::drops(seed, 0.004),
        "garbles" => FaultConfig::garbles(seed, 0.004),
        "delays" => FaultConfig::delays(seed, 0.2, Duration::from_millis(2000)),
        "resets" => FaultConfig::resets(seed, 0.25),
        "disconnects" => FaultConfig::disconnects(seed, 0.05, Duration::from_millis(2000)),
        "mix" => FaultConfig::mix(seed),
        other => anyhow::bail!(
            "unknown fault kind {other:?}: expected one of {}",
            FAULT_KINDS.join(", ")
        ),
    })
}

/// Captures `job`'s session on the simulated rig (faults by name, see [`FAULT_KINDS`]) with the
/// digital twin as the camera; the outcome's device line counts the faults, boots and the
/// driver's retries.
pub fn capture(job: &CaptureJob, faults: &str, speedup: f64) -> Result<CaptureOutcome> {
    let (rig, plan, atlas) = job.prepare()?;
    let settle = Duration::from_millis(rig.config.turntable.settle_ms);
    let sim = SimRig::spawn(&rig, faults_by_name(faults, job.seed)?, speedup)?;
    let mut stage = sim.stage(&rig)?;
    let mut cam = DigitalTwin::new(rig.clone(), &atlas, sim.pose_source(), job.seed);
    let info = job.info(
        plan,
        &rig,
        crate::camera::FrameSource::describe(&cam),
        None,
        true,
    )?;
    let sim = Arc::new(sim);
    let s2 = sim.clone();
    let opts = CaptureOptions {
        settle: Box::new(move || s2.settle(settle)),
        progress: true,
    };
    let summary = session::capture(&job.out, &info, &rig, &mut stage, &mut cam, &opts)?;
    let w = sim.world().lock();
    let device = format!(
        "simulated device: {}; {} boots; driver {:?}",
        w.fault_counts(),
        w.device().boots(),
        stage.turntable().stats()
    );
    Ok(CaptureOutcome { summary, device })
}
