//! The host-side turntable driver. Speaks `firmware-protocol` over any [`Transport`] with
//! per-attempt timeouts inside outer deadlines, retries that reuse the sequence number (so the
//! device's reply cache makes them idempotent), resynchronisation, reopening after a disconnect,
//! waiting for the BOOT banner, and recovery from a device reset in the middle of a move
//! (re-home, then redo the move once). See `docs/protocol.md`, section 11.

use super::transport::Transport;
use firmware_protocol::{
    encode_command, Axis, Command, DoneEnd, ErrorCode, Event, FaultCode, Frame, LineAssembler,
    LineBuf, Reply, Seq, SeqField, StatusInfo, PROTOCOL_VERSION,
};
use std::collections::{HashMap, VecDeque};
use std::io;
use std::time::Duration;

/// Timeouts and retry limits.
#[derive(Debug, Clone, PartialEq)]
pub struct TurntableConfig {
    /// How long to wait for a reply before resending the command.
    pub attempt_timeout: Duration,
    /// Outer deadline for one command, retries included.
    pub command_deadline: Duration,
    /// After this many unanswered attempts, send a newline and discard input before retrying.
    pub resync_after: u32,
    /// How long to wait for the BOOT banner after opening or reopening the port.
    pub boot_wait: Duration,
    /// How long to keep trying to reopen a vanished port.
    pub reconnect_deadline: Duration,
    /// Pause between reopen attempts.
    pub reconnect_backoff: Duration,
    /// Wait for DONE until `ETA × done_factor + done_slack` before asking `STATUS`.
    pub done_factor: f64,
    /// See `done_factor`.
    pub done_slack: Duration,
    /// Outer deadline for one move or homing, all recoveries included.
    pub move_deadline: Duration,
    /// Most re-homes/redos for one move before giving up.
    pub max_recoveries: u32,
}

impl Default for TurntableConfig {
    fn default() -> Self {
        Self {
            attempt_timeout: Duration::from_millis(150),
            command_deadline: Duration::from_secs(5),
            resync_after: 2,
            boot_wait: Duration::from_millis(2500),
            reconnect_deadline: Duration::from_secs(15),
            reconnect_backoff: Duration::from_millis(100),
            done_factor: 1.5,
            done_slack: Duration::from_millis(500),
            move_deadline: Duration::from_secs(120),
            max_recoveries: 8,
        }
    }
}

/// What the device said in HELLO.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    /// Protocol version.
    pub proto: u16,
    /// Firmware name/version.
    pub fw: String,
    /// Rail soft limits (µm), when the device has the camera rail (axis 2).
    pub rail: Option<(i32, i32)>,
}

/// A completed move.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MoveReport {
    /// Axis moved.
    pub axis: Axis,
    /// Position reached (equals the target).
    pub position: i32,
    /// Sequence number of the MOVE_ABS that completed it.
    pub seq: Seq,
    /// Re-homes/redos needed on the way (device resets, moves refused as not homed).
    pub recoveries: u32,
}

/// What the driver had to do to get its commands through.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DriverStats {
    /// Commands issued (each with a new sequence number).
    pub commands: u64,
    /// Resends of a command with the same sequence number.
    pub retries: u64,
    /// Newline-and-flush resynchronisations.
    pub resyncs: u64,
    /// Port reopenings after a disconnect.
    pub reconnects: u64,
    /// Device resets noticed (BOOT events, or homing lost without one).
    pub resets_seen: u64,
    /// Homing runs completed.
    pub homings: u64,
    /// Moves commanded again after a reset or refusal.
    pub redone_moves: u64,
    /// Motions whose DONE event was lost and whose end was learnt from STATUS.
    pub lost_done_recovered: u64,
    /// Lines from the device thrown away (bad framing, CRC, over-long, unparsable).
    pub bad_lines: u64,
}

/// Driver errors.
#[derive(Debug, thiserror::Error)]
pub enum TurntableError {
    /// The link failed and could not be reopened.
    #[error("serial link to the turntable lost and not back within {waited:?}: {source}")]
    Disconnected {
        /// How long reopening was tried.
        waited: Duration,
        /// Last error.
        source: io::Error,
    },
    /// No valid reply in time.
    #[error("no reply to {cmd} from the turntable within {waited:?}")]
    Timeout {
        /// Command word.
        cmd: &'static str,
        /// Time spent.
        waited: Duration,
    },
    /// The device answered `ERR`.
    #[error("turntable refused {cmd}: ERR {code}")]
    Refused {
        /// Command word.
        cmd: &'static str,
        /// Its error code.
        code: ErrorCode,
    },
    /// The device said something that breaks the protocol.
    #[error("turntable protocol violation: {0}")]
    Protocol(String),
    /// Incompatible firmware.
    #[error("turntable speaks protocol version {0}; this driver speaks {PROTOCOL_VERSION}")]
    Version(u16),
    /// The axis is not fitted.
    #[error("the turntable has no axis {0} (no camera rail)")]
    NoAxis(Axis),
    /// A fault is latched (CLEAR, then home).
    #[error("turntable fault {} latched: clear it, then home", .0.word())]
    Fault(FaultCode),
    /// A motion ended somewhere other than its target (STOP, ESTOP, fault).
    #[error("axis {axis} motion ended {} at {pos}", .end.word())]
    Interrupted {
        /// Axis.
        axis: Axis,
        /// Where it stopped.
        pos: i32,
        /// How.
        end: DoneEnd,
    },
    /// Recovery did not converge.
    #[error("gave up on axis {axis} after {recoveries} recoveries: {last}")]
    GaveUp {
        /// Axis.
        axis: Axis,
        /// How many were tried.
        recoveries: u32,
        /// The last thing that went wrong.
        last: String,
    },
}

type Result<T> = std::result::Result<T, TurntableError>;

#[derive(Debug, Clone, PartialEq)]
enum OwnedReply {
    Ok,
    Hello {
        proto: u16,
        fw: String,
        rail: Option<(i32, i32)>,
    },
    Moving(u32),
    Status(StatusInfo),
    Err(ErrorCode),
}

enum Msg {
    Reply(Seq, String),
    Event,
}

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
        };
        let deadline = tt.t.now() + tt.cfg.command_deadline + tt.cfg.boot_wait;
        if let Err(e) = tt.wait_for_boot(tt.cfg.boot_wait) {
            tt.link_failed(e, deadline)?;
        }
        tt.resync(deadline)?;
        let hello_deadline = tt.t.now() + tt.cfg.command_deadline;
        match tt.transact(Command::Hello, hello_deadline)?.1 {
            OwnedReply::Hello { proto, fw, rail } if proto == PROTOCOL_VERSION => {
                tt.info.proto = proto;
                tt.info.fw = fw;
                tt.info.rail = rail;
            }
            OwnedReply::Hello { proto, .. } => return Err(TurntableError::Version(proto)),
            r => return Err(unexpected("HELLO", r)),
        }
        for axis in tt.axes_present() {
            let d = tt.t.now() + tt.cfg.command_deadline;
            tt.status_until(axis, d)?;
        }
        Ok(tt)
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
            if !self.axes[axis.index()].homed {
                self.home_until(axis, deadline)?;
            }
            self.restore_settings(axis, deadline)?;
            match self.run_motion(axis, Command::MoveAbs(axis, target), deadline)? {
                MotionOutcome::Ended {
                    seq,
                    pos,
                    end: DoneEnd::Reached,
                } if pos == target => {
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
                MotionOutcome::Ended { pos, end, .. } => {
                    self.axes[axis.index()].pos = Some(pos);
                    return Err(TurntableError::Interrupted { axis, pos, end });
                }
                other => {
                    last = self.recover(axis, other, deadline)?;
                    recoveries += 1;
                    self.stats.redone_moves += 1;
                }
            }
        }
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
            self.restore_settings(axis, deadline)?;
            match self.run_motion(axis, Command::Home(axis), deadline)? {
                MotionOutcome::Ended {
                    pos,
                    end: DoneEnd::Reached,
                    ..
                } => {
                    self.stats.homings += 1;
                    let a = &mut self.axes[axis.index()];
                    a.homed = true;
                    a.pos = Some(pos);
                    return Ok(pos);
                }
                MotionOutcome::Ended { pos, end, .. } => {
                    return Err(TurntableError::Interrupted { axis, pos, end })
                }
                other => {
                    last = self.recover(axis, other, deadline)?;
                    recoveries += 1;
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
        let epoch = self.boots;
        let seq = self.next_seq();
        let eta = match self.transact_seq(seq, cmd, deadline) {
            Ok(OwnedReply::Moving(eta)) => Some(eta),
            Ok(OwnedReply::Err(code)) => return Ok(MotionOutcome::Refused(code)),
            Ok(r) => return Err(unexpected(cmd.kind().word(), r)),
            Err(TurntableError::Timeout { .. }) if self.t.now() < deadline => {
                // Was it accepted before contact was lost? PING re-establishes contact (the
                // command is abandoned, so replacing the device's reply cache is safe), STATUS says.
                self.resync(deadline)?;
                let st = self.status_until(axis, deadline)?;
                if st.seq != Some(seq) {
                    return Ok(if self.boots != epoch {
                        MotionOutcome::Reset
                    } else {
                        MotionOutcome::NotAccepted
                    });
                }
                None
            }
            Err(e) => return Err(e),
        };
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
                        return Err(TurntableError::Protocol(format!(
                            "STATUS {axis} reports motion {:?}, expected {seq}",
                            st.seq.map(Seq::get)
                        )));
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

    // ---- line level --------------------------------------------------------------------------

    fn next_seq(&mut self) -> Seq {
        self.seq = self.seq.next();
        self.done.remove(&self.seq.get());
        self.stats.commands += 1;
        self.seq
    }

    fn transact(&mut self, cmd: Command, deadline: Duration) -> Result<(Seq, OwnedReply)> {
        let seq = self.next_seq();
        Ok((seq, self.transact_seq(seq, cmd, deadline)?))
    }

    /// Send `cmd` as `seq` until its reply arrives, resending the identical line on silence.
    fn transact_seq(&mut self, seq: Seq, cmd: Command, deadline: Duration) -> Result<OwnedReply> {
        let mut line = LineBuf::new();
        encode_command(seq, &cmd, &mut line)
            .map_err(|e| TurntableError::Protocol(format!("cannot encode {cmd:?}: {e}")))?;
        let start = self.t.now();
        let deadline = deadline.min(start + self.cfg.command_deadline);
        let mut attempts = 0u32;
        loop {
            if self.t.now() >= deadline {
                return Err(TurntableError::Timeout {
                    cmd: cmd.kind().word(),
                    waited: self.t.now() - start,
                });
            }
            if attempts > 0 {
                self.stats.retries += 1;
                if attempts % self.cfg.resync_after.max(1) == 0 {
                    self.soft_resync();
                }
            }
            attempts += 1;
            if let Err(e) = self.t.write_all(line.as_bytes()) {
                self.link_failed(e, deadline)?;
                continue;
            }
            let until = (self.t.now() + self.cfg.attempt_timeout).min(deadline);
            loop {
                match self.next_message(until) {
                    Err(e) => {
                        self.link_failed(e, deadline)?;
                        break;
                    }
                    Ok(None) => break,
                    Ok(Some(Msg::Reply(s, body))) if s == seq => {
                        match Reply::parse(cmd.kind(), &body) {
                            Ok(r) => return Ok(own(r)),
                            Err(_) => self.stats.bad_lines += 1,
                        }
                    }
                    Ok(Some(_)) => {}
                }
            }
        }
    }

    /// Newline (ends any partial line at the device), short pause, drop pending input.
    fn soft_resync(&mut self) {
        self.stats.resyncs += 1;
        if self.t.write_all(b"\n").is_ok() {
            self.t.pause(Duration::from_millis(20));
            let _ = self.t.discard_input();
        }
        self.pending.clear();
        self.asm.clear();
    }

    /// Full resynchronisation: newline, flush, PING until answered.
    fn resync(&mut self, deadline: Duration) -> Result<()> {
        self.soft_resync();
        match self.transact(Command::Ping, deadline)?.1 {
            OwnedReply::Ok => Ok(()),
            r => Err(unexpected("PING", r)),
        }
    }

    /// The link failed: reopen it (until the reconnect deadline), then wait for a BOOT banner.
    fn link_failed(&mut self, mut err: io::Error, deadline: Duration) -> Result<()> {
        let start = self.t.now();
        let until = deadline.min(start + self.cfg.reconnect_deadline).max(start);
        loop {
            self.stats.reconnects += 1;
            self.pending.clear();
            self.asm.clear();
            loop {
                match self.t.reopen() {
                    Ok(()) => break,
                    Err(e) if self.t.now() < until => {
                        err = e;
                        self.t.pause(self.cfg.reconnect_backoff);
                    }
                    Err(e) => {
                        return Err(TurntableError::Disconnected {
                            waited: self.t.now() - start,
                            source: e,
                        })
                    }
                }
            }
            match self.wait_for_boot(self.cfg.boot_wait) {
                Ok(_) => {
                    let _ = self.t.write_all(b"\n");
                    return Ok(());
                }
                Err(e) if self.t.now() < until => err = e,
                Err(e) => {
                    let _ = err;
                    return Err(TurntableError::Disconnected {
                        waited: self.t.now() - start,
                        source: e,
                    });
                }
            }
        }
    }

    /// Read until a BOOT event arrives or `wait` passes. Returns whether one came.
    fn wait_for_boot(&mut self, wait: Duration) -> io::Result<bool> {
        let boots = self.boots;
        let until = self.t.now() + wait;
        while self.boots == boots {
            if self.next_message(until)?.is_none() {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// The next well-framed line before `until`; events are applied to the driver state.
    fn next_message(&mut self, until: Duration) -> io::Result<Option<Msg>> {
        let mut buf = [0u8; 256];
        loop {
            while let Some(b) = self.pending.pop_front() {
                let line = match self.asm.push(b) {
                    None => continue,
                    Some(Err(_)) => {
                        self.stats.bad_lines += 1;
                        continue;
                    }
                    Some(Ok(l)) => l.to_vec(),
                };
                match Frame::parse(&line) {
                    Ok(Frame {
                        seq: SeqField::Seq(s),
                        body,
                    }) => return Ok(Some(Msg::Reply(s, body.to_string()))),
                    Ok(Frame {
                        seq: SeqField::Event,
                        body,
                    }) => match Event::parse(body) {
                        Ok(ev) => {
                            self.apply_event(ev);
                            return Ok(Some(Msg::Event));
                        }
                        Err(_) => self.stats.bad_lines += 1,
                    },
                    Err(_) => self.stats.bad_lines += 1,
                }
            }
            let now = self.t.now();
            if now >= until {
                return Ok(None);
            }
            let n = self.t.read(&mut buf, until - now)?;
            self.pending.extend(&buf[..n]);
        }
    }

    fn note_reset(&mut self) {
        self.boots += 1;
        self.stats.resets_seen += 1;
        for a in &mut self.axes {
            a.homed = false;
            a.pos = None;
            a.settings_lost = true;
        }
    }

    fn apply_event(&mut self, ev: Event<'_>) {
        match ev {
            Event::Boot { .. } => {
                self.note_reset();
                self.fault = FaultCode::None;
            }
            Event::Done {
                seq,
                axis,
                pos,
                end,
            } => {
                self.done.insert(seq.get(), (axis, pos, end));
            }
            Event::Fault { code, .. } => {
                self.fault = code;
                for a in &mut self.axes {
                    a.homed = false;
                }
            }
        }
    }
}

fn own(r: Reply<'_>) -> OwnedReply {
    match r {
        Reply::Ok => OwnedReply::Ok,
        Reply::Hello(h) => OwnedReply::Hello {
            proto: h.proto,
            fw: h.fw.to_string(),
            rail: h.rail,
        },
        Reply::Moving { eta_ms } => OwnedReply::Moving(eta_ms),
        Reply::Status(s) => OwnedReply::Status(s),
        Reply::Err(c) => OwnedReply::Err(c),
    }
}

fn unexpected(cmd: &str, r: OwnedReply) -> TurntableError {
    TurntableError::Protocol(format!("unexpected reply to {cmd}: {r:?}"))
}
