//! What a capture session moves: the table angle and the camera distance. [`TurntableStage`]
//! drives the turntable (any [`Transport`]) and sets the distance with the rail when the rig has
//! one, or asks an operator (a prompt on the terminal, or a simulated operator). It also keeps
//! the pose the driver reports ([`TurntableStage::reported_pose`]), for the digital-twin camera
//! on a real serial port (`cac capture --port ... --twin-camera`).

use super::rig::Rig;
use super::transport::Transport;
use super::turntable::{MoveReport, Turntable};
use super::twin::{Pose, PoseSource};
use anyhow::{Context, Result};
use firmware_protocol::Axis;
use std::io::BufRead;
use std::sync::{Arc, Mutex};

/// The positioning side of a capture session.
pub trait Stage {
    /// Turn the table to `angle_deg` and wait until it is there.
    fn turn_to(&mut self, angle_deg: f64) -> Result<MoveReport>;
    /// Put the camera at distance ratio `ratio` (rail move or operator).
    fn set_ratio(&mut self, ratio: f64, rig: &Rig) -> Result<()>;
    /// The device state for the manifest.
    fn status(&self) -> serde_json::Value;
}

/// Moves the camera by hand: called with the ratio and the camera-to-axis distance (m).
pub(crate) type Operator = Box<dyn FnMut(f64, f64) -> Result<()> + Send>;

/// An operator at the terminal: prints where to put the camera and waits for Enter on stdin.
pub(crate) fn terminal_operator() -> Operator {
    Box::new(|ratio, dist| {
        eprintln!(
            "\nMove the camera to {dist:.3} m from the turntable axis (distance ratio {ratio}), horizontally, then press Enter."
        );
        let mut line = String::new();
        let n = std::io::stdin()
            .lock()
            .read_line(&mut line)
            .context("cannot read the operator's confirmation from stdin")?;
        if n == 0 {
            anyhow::bail!("stdin closed while waiting for the operator to move the camera");
        }
        Ok(())
    })
}

/// The turntable driver plus the rail or an operator.
pub struct TurntableStage<T: Transport> {
    tt: Turntable<T>,
    operator: Operator,
    last_turn: Option<MoveReport>,
    last_rail: Option<MoveReport>,
    reported: Arc<Mutex<Reported>>,
}

/// What the driver reported last: the table position (m°) of the last completed turn and the
/// camera-to-axis distance (m) of the last rail move (near end + reported rail position) or of
/// the operator's confirmed placement.
#[derive(Debug, Clone, Copy, Default)]
struct Reported {
    table_mdeg: Option<i32>,
    horizontal_m: Option<f64>,
}

impl<T: Transport> TurntableStage<T> {
    /// `operator` is used when the rig file says there is no rail (or the device has none).
    pub fn new(tt: Turntable<T>, operator: Operator) -> Self {
        TurntableStage {
            tt,
            operator,
            last_turn: None,
            last_rail: None,
            reported: Arc::default(),
        }
    }

    /// A [`PoseSource`] for the digital twin: the pose as the driver reports it after each
    /// completed move (table position from the move's report, rail position plus the rig's
    /// `near_m`, or the distance the operator was asked to set). Fails before the first turn
    /// and camera placement.
    pub(crate) fn reported_pose(&self) -> PoseSource {
        let r = self.reported.clone();
        Box::new(move || {
            let r = *r.lock().unwrap_or_else(|e| e.into_inner());
            match (r.table_mdeg, r.horizontal_m) {
                (Some(mdeg), Some(h)) => Ok(Pose {
                    angle_deg: (f64::from(mdeg) / 1000.0).rem_euclid(360.0),
                    horizontal_m: h,
                }),
                _ => {
                    Err("the driver has not reported a table angle and camera distance yet".into())
                }
            }
        })
    }

    fn report(&self, f: impl FnOnce(&mut Reported)) {
        f(&mut self.reported.lock().unwrap_or_else(|e| e.into_inner()));
    }

    /// The driver.
    pub fn turntable(&self) -> &Turntable<T> {
        &self.tt
    }
}

impl<T: Transport> Stage for TurntableStage<T> {
    fn turn_to(&mut self, angle_deg: f64) -> Result<MoveReport> {
        let target = (angle_deg * 1000.0).round() as i32;
        let r = self
            .tt
            .move_to(Axis::Turntable, target)
            .with_context(|| format!("turning the table to {angle_deg}°"))?;
        self.last_turn = Some(r);
        self.report(|p| p.table_mdeg = Some(r.position));
        Ok(r)
    }

    fn set_ratio(&mut self, ratio: f64, rig: &Rig) -> Result<()> {
        if rig.config.rail.present && self.tt.has_rail() {
            let target = rig.rail_target(ratio)?;
            let r = self
                .tt
                .move_to(Axis::Rail, target)
                .with_context(|| format!("moving the rail to {target} µm (ratio {ratio})"))?;
            self.last_rail = Some(r);
            let near = rig.config.rail.near_m;
            self.report(|p| p.horizontal_m = Some(near + f64::from(r.position) * 1e-6));
            Ok(())
        } else {
            if rig.config.rail.present {
                anyhow::bail!("the rig file says there is a rail, but the turntable reports none");
            }
            let d = rig.horizontal_distance(ratio)?;
            (self.operator)(ratio, d)?;
            self.report(|p| p.horizontal_m = Some(d));
            Ok(())
        }
    }

    fn status(&self) -> serde_json::Value {
        let s = self.tt.stats();
        serde_json::json!({
            "turntable_mdeg": self.tt.position(Axis::Turntable),
            "move_seq": self.last_turn.map(|r| r.seq.get()),
            "recoveries": self.last_turn.map(|r| r.recoveries),
            "rail_um": self.last_rail.map(|r| r.position),
            "driver": {
                "commands": s.commands, "retries": s.retries, "resyncs": s.resyncs,
                "reconnects": s.reconnects, "resets_seen": s.resets_seen, "homings": s.homings,
                "redone_moves": s.redone_moves, "lost_done_recovered": s.lost_done_recovered,
                "bad_lines": s.bad_lines,
            }
        })
    }
}
