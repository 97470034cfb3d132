//! The host-side turntable driver. Speaks `firmware-protocol` over any [`Transport`] with
//! per-attempt timeouts inside outer deadlines, retries that reuse the sequence number (so the
//! device's reply cache makes them idempotent), resynchronisation, reopening after a disconnect,
//! waiting for the BOOT banner, and recovery from a device reset in the middle of a move
//! (re-home, then redo the move once). See `docs/protocol.md`, section 11.

mod types;
mod wire;

pub use types::{DeviceInfo, DriverStats, MoveReport, TurntableConfig, TurntableError};

use super::transport::Transport;
use firmware_protocol::{
    Axis, Command, DoneEnd, ErrorCode, FaultCode, LineAssembler, Seq, StatusInfo, PROTOCOL_VERSION,
};
use std::collections::{HashMap, VecDeque};
use std::time::Duration;
use wire::{unexpected, OwnedReply};

type Result<T> = std::result::Result<T, TurntableError>;

enum MotionOutcome {
    Ended { seq: Seq, pos: i32, end: DoneEnd },
    Reset,
    NotAccepted,
    Refused(ErrorCode),
}

#[derive(Debug, Clone, Copy, Default)]
struct AxisView {
    homed: bool,
    pos: Option<i32>,
    speed: Option<u32>,
    accel: Option<u32>,
    settings_lost: bool,
}

/// A connected turntable.
pub struct Turntable<T: Transport> {
    t: T,
    cfg: TurntableConfig,
    seq: Seq,
    asm: LineAssembler,
    pending: VecDeque<u8>,
    info: DeviceInfo,
    axes: [AxisView; 2],
    boots: u64,
    fault: FaultCode,
    done: HashMap<u16, (Axis, i32, DoneEnd)>,
    stats: DriverStats,
    /// The device rebooted since our last HELLO (it refuses most commands until one).
    needs_hello: bool,
}

impl<T: Transport> std::fmt::Debug for Turntable<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Turntable")
            .field("info", &self.info)
            .field("stats", &self.stats)
            .finish()
    }
}

impl<T: Transport> Turntable<T> {
    /// Take over an opened transport: wait for the BOOT banner (boards that reset on open send
    /// one), resynchronise, PING, HELLO (checks the protocol version), then read each axis' state.
    pub fn open(transport: T, cfg: TurntableConfig) -> Result<Self> {
        let mut tt = Self {
            t: transport,
            cfg,
            seq: Seq::new(u16::MAX).unwrap_or(Seq::FIRST),
            asm: LineAssembler::new(),
            pending: VecDeque::new(),
            info: DeviceInfo {
                proto: 0,
                fw: String::new(),
                rail: None,
            },
            axes: [AxisView::default(); 2],
            boots: 0,
            fault: FaultCode::None,
            done: HashMap::new(),
            stats: DriverStats::default(),
            needs_hello: true,
        };
        let deadline = tt.t.now() + tt.cfg.command_deadline + tt.cfg.boot_wait;
        if let Err(e) = tt.wait_for_boot(tt.cfg.boot_wait) {
            tt.link_failed(e, deadline)?;
        }
        tt.resync(deadline)?;
        let hello_deadline = tt.t.now() + tt.cfg.command_deadline;
        tt.hello(hello_deadline)?;
        for axis in tt.axes_present() {
            let d = tt.t.now() + tt.cfg.command_deadline;
            tt.status_until(axis, d)?;
        }
        // The banner awaited at open is not a reset.
        tt.stats.resets_seen = 0;
        Ok(tt)
    }

    /// HELLO: identify the device, check its protocol version, and end its post-boot lockout.
    fn hello(&mut self, deadline: Duration) -> Result<()> {
        match self.transact(Command::Hello, deadline)?.1 {
            OwnedReply::Hello { proto, fw, rail } if proto == PROTOCOL_VERSION => {
                if self.info.proto != 0 && self.info.rail != rail {
                    return Err(TurntableError::Protocol(format!(
                        "device changed its rail from {:?} to {rail:?} across a reboot",
                        self.info.rail
                    )));
                }
                self.info = DeviceInfo { proto, fw, rail };
                self.needs_hello = false;
                Ok(())
            }
            OwnedReply::Hello { proto, .. } => Err(TurntableError::Version(proto)),
            r => Err(unexpected("HELLO", r)),
        }
    }

    /// Firmware identification from HELLO.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Whether the camera rail (axis 2) is fitted.
    pub fn has_rail(&self) -> bool {
        self.info.rail.is_some()
    }

    /// Recovery counters.
    pub fn stats(&self) -> DriverStats {
        self.stats
    }

    /// The driver's belief of where `axis` is: `None` when not homed (after a reset).
    pub fn position(&self, axis: Axis) -> Option<i32> {
        let a = &self.axes[axis.index()];
        a.homed.then_some(a.pos).flatten()
    }

    /// The transport (e.g. to reach the simulator behind it).
    pub fn transport(&self) -> &T {
        &self.t
    }

    /// Give the transport back.
    pub fn into_transport(self) -> T {
        self.t
    }

    fn axes_present(&self) -> Vec<Axis> {
        Axis::ALL
            .into_iter()
            .filter(|&a| a == Axis::Turntable || self.has_rail())
            .collect()
    }

    fn check_axis(&self, axis: Axis) -> Result<()> {
        if axis == Axis::Rail && !self.has_rail() {
            return Err(TurntableError::NoAxis(axis));
        }
        Ok(())
    }

    // ---- public commands ---------------------------------------------------------------------

    /// Home `axis` (always runs, even when homed). Returns the home position.
    pub fn home(&mut self, axis: Axis) -> Result<i32> {
        self.check_axis(axis)?;
        let deadline = self.t.now() + self.cfg.move_deadline;
        self.home_until(axis, deadline)
    }

    /// Move `axis` to `target` (m° or µm) and wait until it is there. Homes first when needed,
    /// and survives device resets mid-move by re-homing and commanding the move again.
    pub fn move_to(&mut self, axis: Axis, target: i32) -> Result<MoveReport> {
        self.check_axis(axis)?;
        let deadline = self.t.now() + self.cfg.move_deadline;
        let (seq, pos, end, recoveries) =
            self.run_until_ended(axis, Command::MoveAbs(axis, target), deadline)?;
        if end == DoneEnd::Reached && pos == target {
            let a = &mut self.axes[axis.index()];
            if a.homed {
                a.pos = Some(pos);
            }
            return Ok(MoveReport {
                axis,
                position: pos,
                seq,
                recoveries,
            });
        }
        self.axes[axis.index()].pos = Some(pos);
        Err(TurntableError::Interrupted { axis, pos, end })
    }

    /// Move `axis` by `delta` from the driver's known position (homing first when needed); sent
    /// as an absolute move so a redo after a reset lands on the same target.
    pub fn move_by(&mut self, axis: Axis, delta: i32) -> Result<MoveReport> {
        self.check_axis(axis)?;
        if self.position(axis).is_none() {
            let d = self.t.now() + self.cfg.move_deadline;
            self.home_until(axis, d)?;
        }
        let from = self.position(axis).unwrap_or(0);
        let target = from.checked_add(delta).ok_or(TurntableError::Refused {
            cmd: "MOVE_REL",
            code: ErrorCode::Range,
        })?;
        self.move_to(axis, target)
    }

    /// Set the cruise speed of `axis` (units/s); re-applied automatically after a device reset.
    pub fn set_speed(&mut self, axis: Axis, v: u32) -> Result<()> {
        self.setting(axis, Command::Speed(axis, v))?;
        self.axes[axis.index()].speed = Some(v);
        Ok(())
    }

    /// Set the acceleration of `axis` (units/s²); re-applied automatically after a device reset.
    pub fn set_accel(&mut self, axis: Axis, a: u32) -> Result<()> {
        self.setting(axis, Command::Accel(axis, a))?;
        self.axes[axis.index()].accel = Some(a);
        Ok(())
    }

    fn setting(&mut self, axis: Axis, cmd: Command) -> Result<()> {
        self.check_axis(axis)?;
        let d = self.t.now() + self.cfg.command_deadline;
        match self.transact(cmd, d)?.1 {
            OwnedReply::Ok => Ok(()),
            OwnedReply::Err(code) => Err(TurntableError::Refused {
                cmd: cmd.kind().word(),
                code,
            }),
            r => Err(unexpected(cmd.kind().word(), r)),
        }
    }

    /// Ask the device for the state of `axis`.
    pub fn status(&mut self, axis: Axis) -> Result<StatusInfo> {
        self.check_axis(axis)?;
        let d = self.t.now() + self.cfg.command_deadline;
        self.status_until(axis, d)
    }

    /// Controlled stop of one axis or all.
    pub fn stop(&mut self, axis: Option<Axis>) -> Result<()> {
        self.simple(Command::Stop(axis))
    }

    /// Emergency stop: everything halts, homing is lost, the ESTOP fault latches.
    pub fn estop(&mut self) -> Result<()> {
        self.simple(Command::Estop)?;
        self.fault = FaultCode::Estop;
        for a in &mut self.axes {
            a.homed = false;
        }
        Ok(())
    }

    /// Clear a latched fault (axes stay unhomed; the next move homes them).
    pub fn clear_fault(&mut self) -> Result<()> {
        self.simple(Command::Clear)?;
        self.fault = FaultCode::None;
        Ok(())
    }

    /// Check the device is there (PING).
    pub fn ping(&mut self) -> Result<()> {
        self.simple(Command::Ping)
    }

    fn simple(&mut self, cmd: Command) -> Result<()> {
        let d = self.t.now() + self.cfg.command_deadline;
        match self.transact(cmd, d)?.1 {
            OwnedReply::Ok => Ok(()),
            OwnedReply::Err(code) => Err(TurntableError::Refused {
                cmd: cmd.kind().word(),
                code,
            }),
            r => Err(unexpected(cmd.kind().word(), r)),
        }
    }

    // ---- motion ------------------------------------------------------------------------------

    fn check_fault(&self) -> Result<()> {
        match self.fault {
            FaultCode::None => Ok(()),
            f => Err(TurntableError::Fault(f)),
        }
    }

    fn home_until(&mut self, axis: Axis, deadline: Duration) -> Result<i32> {
        let (_, pos, end, _) = self.run_until_ended(axis, Command::Home(axis), deadline)?;
        if end != DoneEnd::Reached {
            return Err(TurntableError::Interrupted { axis, pos, end });
        }
        self.stats.homings += 1;
        let a = &mut self.axes[axis.index()];
        a.homed = true;
        a.pos = Some(pos);
        Ok(pos)
    }

    /// Runs a homing or a move (`cmd`) until the device reports it ended, before `deadline`.
    /// Before each attempt a latched fault stops it, an axis whose homing was lost is homed
    /// first (for a move) and the settings a reset lost are restored; a motion that did not
    /// end (a reset, a lost reply, a refusal to recover from) is recovered and sent again, up to
    /// `max_recoveries` times (a redone move is counted in the statistics). Returns the
    /// motion's sequence number, where it ended, how, and the recoveries it took.
    fn run_until_ended(
        &mut self,
        axis: Axis,
        cmd: Command,
        deadline: Duration,
    ) -> Result<(Seq, i32, DoneEnd, u32)> {
        let is_move = !matches!(cmd, Command::Home(_));
        let mut recoveries = 0;
        let mut last = String::from("none");
        loop {
            if recoveries > self.cfg.max_recoveries || self.t.now() >= deadline {
                return Err(TurntableError::GaveUp {
                    axis,
                    recoveries,
                    last,
                });
            }
            self.check_fault()?;
            if is_move && !self.axes[axis.index()].homed {
                self.home_until(axis, deadline)?;
            }
            self.restore_settings(axis, deadline)?;
            match self.run_motion(axis, cmd, deadline)? {
                MotionOutcome::Ended { seq, pos, end } => return Ok((seq, pos, end, recoveries)),
                other => {
                    last = self.recover(axis, other, deadline)?;
                    recoveries += 1;
                    if is_move {
                        self.stats.redone_moves += 1;
                    }
                }
            }
        }
    }

    /// Handle a motion that did not end: returns a description for error messages, or fails
    /// when the situation needs an operator.
    fn recover(
        &mut self,
        axis: Axis,
        outcome: MotionOutcome,
        deadline: Duration,
    ) -> Result<String> {
        match outcome {
            MotionOutcome::Reset => Ok("device reset during the motion".into()),
            MotionOutcome::NotAccepted => Ok("command lost; device did not start it".into()),
            MotionOutcome::Refused(ErrorCode::NotHomed) => {
                // Homing lost without us seeing BOOT: a reset whose banner was lost.
                if self.axes[axis.index()].homed {
                    self.note_reset();
                }
                self.axes[axis.index()].homed = false;
                Ok("device says not homed".into())
            }
            MotionOutcome::Refused(ErrorCode::Busy) => {
                self.settle(axis, deadline)?;
                Ok("axis was busy".into())
            }
            MotionOutcome::Refused(ErrorCode::Estop) => {
                Err(TurntableError::Fault(FaultCode::Estop))
            }
            MotionOutcome::Refused(ErrorCode::Fault) => {
                let st = self.status_until(axis, deadline)?;
                Err(TurntableError::Fault(st.fault))
            }
            MotionOutcome::Refused(code) => Err(TurntableError::Refused {
                cmd: "MOVE_ABS",
                code,
            }),
            MotionOutcome::Ended { .. } => Ok("ended".into()),
        }
    }

    /// Wait (polling STATUS) until `axis` stands still.
    fn settle(&mut self, axis: Axis, deadline: Duration) -> Result<()> {
        while self.t.now() < deadline {
            if !self.status_until(axis, deadline)?.moving {
                return Ok(());
            }
            self.t.pause(Duration::from_millis(100));
        }
        Err(TurntableError::Timeout {
            cmd: "STATUS",
            waited: self.cfg.move_deadline,
        })
    }

    fn restore_settings(&mut self, axis: Axis, deadline: Duration) -> Result<()> {
        let a = self.axes[axis.index()];
        if !a.settings_lost {
            return Ok(());
        }
        for cmd in [
            a.speed.map(|v| Command::Speed(axis, v)),
            a.accel.map(|v| Command::Accel(axis, v)),
        ]
        .into_iter()
        .flatten()
        {
            match self.transact(cmd, deadline)?.1 {
                OwnedReply::Ok => {}
                OwnedReply::Err(code) => {
                    return Err(TurntableError::Refused {
                        cmd: cmd.kind().word(),
                        code,
                    })
                }
                r => return Err(unexpected(cmd.kind().word(), r)),
            }
        }
        self.axes[axis.index()].settings_lost = false;
        Ok(())
    }

    /// Send a motion command and follow it to its end.
    fn run_motion(
        &mut self,
        axis: Axis,
        cmd: Command,
        deadline: Duration,
    ) -> Result<MotionOutcome> {
        if self.needs_hello {
            self.hello(deadline)?;
        }
        let before = self.boots;
        let seq = self.next_seq();
        let eta = match self.transact_seq(seq, cmd, deadline) {
            Ok(OwnedReply::Moving(eta)) => Some(eta),
            Ok(OwnedReply::Err(ErrorCode::Booted)) => {
                // Rebooted and its BOOT banner was lost.
                self.note_reset();
                return Ok(MotionOutcome::Reset);
            }
            Ok(OwnedReply::Err(code)) => return Ok(MotionOutcome::Refused(code)),
            Ok(r) => return Err(unexpected(cmd.kind().word(), r)),
            Err(TurntableError::Timeout { .. }) if self.t.now() < deadline => {
                // Was it accepted before contact was lost? PING re-establishes contact (the
                // command is abandoned, so replacing the device's reply cache is safe), STATUS says.
                self.resync(deadline)?;
                let st = self.status_until(axis, deadline)?;
                if st.seq != Some(seq) {
                    return Ok(if self.boots != before {
                        MotionOutcome::Reset
                    } else {
                        MotionOutcome::NotAccepted
                    });
                }
                None
            }
            Err(TurntableError::DeviceReset { .. }) => return Ok(MotionOutcome::Reset),
            Err(e) => return Err(e),
        };
        // A BOOT read before the reply came before the command ran: the motion belongs to the
        // device's current boot, so only later BOOTs interrupt it.
        let epoch = self.boots;
        self.wait_motion(seq, axis, eta, epoch, deadline)
    }

    fn wait_motion(
        &mut self,
        seq: Seq,
        axis: Axis,
        eta_ms: Option<u32>,
        epoch: u64,
        deadline: Duration,
    ) -> Result<MotionOutcome> {
        let eta = Duration::from_millis(u64::from(eta_ms.unwrap_or(0)));
        let mut until =
            (self.t.now() + eta.mul_f64(self.cfg.done_factor) + self.cfg.done_slack).min(deadline);
        loop {
            if let Some((_, pos, end)) = self.done.remove(&seq.get()) {
                return Ok(MotionOutcome::Ended { seq, pos, end });
            }
            if self.boots != epoch {
                return Ok(MotionOutcome::Reset);
            }
            match self.next_message(until) {
                Err(e) => self.link_failed(e, deadline)?,
                Ok(Some(_)) => {}
                Ok(None) => {
                    // No DONE in time: ask the device.
                    if self.t.now() >= deadline {
                        return Err(TurntableError::Timeout {
                            cmd: "DONE",
                            waited: self.cfg.move_deadline,
                        });
                    }
                    let st = match self.status_until(axis, deadline) {
                        Ok(st) => st,
                        Err(TurntableError::Timeout { .. }) => {
                            self.resync(deadline)?;
                            continue;
                        }
                        Err(e) => return Err(e),
                    };
                    if let Some((_, pos, end)) = self.done.remove(&seq.get()) {
                        return Ok(MotionOutcome::Ended { seq, pos, end });
                    }
                    if self.boots != epoch {
                        return Ok(MotionOutcome::Reset);
                    }
                    if st.seq != Some(seq) {
                        // Only a reboot makes the device forget the motion it was running: a
                        // reset whose BOOT banner was lost.
                        self.note_reset();
                        return Ok(MotionOutcome::Reset);
                    }
                    if st.moving {
                        until = (self.t.now()
                            + eta.mul_f64(self.cfg.done_factor / 4.0)
                            + self.cfg.done_slack)
                            .min(deadline);
                        continue;
                    }
                    // It ended and its DONE was lost.
                    self.stats.lost_done_recovered += 1;
                    let end = match (st.homed, st.pos == st.target) {
                        (true, true) => DoneEnd::Reached,
                        (true, false) => DoneEnd::Stopped,
                        (false, _) => DoneEnd::Aborted,
                    };
                    return Ok(MotionOutcome::Ended {
                        seq,
                        pos: st.pos,
                        end,
                    });
                }
            }
        }
    }

    fn status_until(&mut self, axis: Axis, deadline: Duration) -> Result<StatusInfo> {
        let st = match self.transact(Command::Status(axis), deadline)?.1 {
            OwnedReply::Status(st) => st,
            OwnedReply::Err(code) => {
                return Err(TurntableError::Refused {
                    cmd: "STATUS",
                    code,
                })
            }
            r => return Err(unexpected("STATUS", r)),
        };
        let a = &mut self.axes[axis.index()];
        if a.homed && !st.homed && st.fault == FaultCode::None {
            // Homing lost with no BOOT seen: the banner was lost.
            self.note_reset();
        }
        let a = &mut self.axes[axis.index()];
        a.homed = st.homed;
        if st.homed && !st.moving {
            a.pos = Some(st.pos);
        }
        self.fault = st.fault;
        Ok(st)
    }
}
