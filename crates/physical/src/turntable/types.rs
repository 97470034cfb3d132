//! Configuration, reports, counters and errors of the turntable driver.

use firmware_protocol::{Axis, DoneEnd, ErrorCode, FaultCode, Seq, PROTOCOL_VERSION};
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
    /// Device resets noticed after open (BOOT events, or homing lost without one).
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
    /// The device rebooted while the command was outstanding; it may or may not have run.
    #[error("turntable rebooted while {cmd} was outstanding")]
    DeviceReset {
        /// Command word.
        cmd: &'static str,
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
