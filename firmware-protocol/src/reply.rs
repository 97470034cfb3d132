//! Device→host replies (`OK ...` / `ERR CODE`), their typed payloads, error and fault codes.

use crate::command::CommandKind;
use crate::frame::Seq;
use crate::token::{parse_flag, parse_i32, parse_u32, req, ParseError};
use core::fmt::{self, Write};

/// The code in an `ERR` reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorCode {
    /// `BADCMD`: unknown command word.
    BadCmd,
    /// `BADARG`: wrong number of arguments or a malformed number.
    BadArg,
    /// `NOAXIS`: the axis does not exist on this device.
    NoAxis,
    /// `RANGE`: a value outside what the device accepts (speed, acceleration, arithmetic overflow).
    Range,
    /// `LIMIT`: the target lies outside the axis' soft limits.
    Limit,
    /// `NOTHOMED`: the axis must be homed first.
    NotHomed,
    /// `BUSY`: the axis is already moving.
    Busy,
    /// `ESTOP`: the emergency-stop fault is latched; send `CLEAR`.
    Estop,
    /// `FAULT`: another latched fault prevents motion; `STATUS` names it, `CLEAR` clears it.
    Fault,
    /// `BOOTED`: the device has (re)booted since the last `HELLO`; send `HELLO` first.
    Booted,
    /// A code this version does not know.
    Other,
}

impl ErrorCode {
    /// The code on the wire.
    pub const fn word(self) -> &'static str {
        match self {
            ErrorCode::BadCmd => "BADCMD",
            ErrorCode::BadArg => "BADARG",
            ErrorCode::NoAxis => "NOAXIS",
            ErrorCode::Range => "RANGE",
            ErrorCode::Limit => "LIMIT",
            ErrorCode::NotHomed => "NOTHOMED",
            ErrorCode::Busy => "BUSY",
            ErrorCode::Estop => "ESTOP",
            ErrorCode::Fault => "FAULT",
            ErrorCode::Booted => "BOOTED",
            ErrorCode::Other => "OTHER",
        }
    }

    fn from_word(w: &str) -> ErrorCode {
        const KNOWN: [ErrorCode; 10] = [
            ErrorCode::BadCmd,
            ErrorCode::BadArg,
            ErrorCode::NoAxis,
            ErrorCode::Range,
            ErrorCode::Limit,
            ErrorCode::NotHomed,
            ErrorCode::Busy,
            ErrorCode::Estop,
            ErrorCode::Fault,
            ErrorCode::Booted,
        ];
        KNOWN
            .into_iter()
            .find(|c| c.word() == w)
            .unwrap_or(ErrorCode::Other)
    }

    /// The reply a device gives to a well-framed line whose body failed to parse.
    pub const fn for_parse_error(e: ParseError) -> ErrorCode {
        match e {
            ParseError::UnknownCommand => ErrorCode::BadCmd,
            ParseError::NoSuchAxis => ErrorCode::NoAxis,
            _ => ErrorCode::BadArg,
        }
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.word())
    }
}

/// A latched device fault (in `STATUS` replies and `FAULT` events).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FaultCode {
    /// `NONE`
    None,
    /// `ESTOP`: emergency stop (command or button).
    Estop,
    /// `LIMIT`: a hardware limit switch tripped.
    Limit,
    /// `STALL`: the motor stalled / lost steps.
    Stall,
    /// A code this version does not know.
    Other,
}

impl FaultCode {
    /// The code on the wire.
    pub const fn word(self) -> &'static str {
        match self {
            FaultCode::None => "NONE",
            FaultCode::Estop => "ESTOP",
            FaultCode::Limit => "LIMIT",
            FaultCode::Stall => "STALL",
            FaultCode::Other => "OTHER",
        }
    }

    pub(crate) fn from_word(w: &str) -> FaultCode {
        match w {
            "NONE" => FaultCode::None,
            "ESTOP" => FaultCode::Estop,
            "LIMIT" => FaultCode::Limit,
            "STALL" => FaultCode::Stall,
            _ => FaultCode::Other,
        }
    }
}

/// Payload of the `HELLO` reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HelloInfo<'a> {
    /// `PROTO=`: protocol version the firmware speaks.
    pub proto: u16,
    /// `FW=`: firmware name/version, one word of at most [`crate::MAX_FW_LEN`] bytes.
    pub fw: &'a str,
    /// `RAIL=min:max`: present when the device has axis 2 (camera rail), with its soft limits in µm.
    pub rail: Option<(i32, i32)>,
}

impl HelloInfo<'_> {
    /// Number of axes (`AXES=`): 1, or 2 with a rail.
    pub fn axes(&self) -> u8 {
        if self.rail.is_some() {
            2
        } else {
            1
        }
    }
}

/// Payload of the `STATUS a` reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatusInfo {
    /// `POS=`: current position (meaningless while `homed` is false).
    pub pos: i32,
    /// `TGT=`: target of the current or last move.
    pub target: i32,
    /// `MOV=`: whether the axis is moving.
    pub moving: bool,
    /// `HOMED=`: whether the axis has been homed since boot (and since the last `ESTOP`).
    pub homed: bool,
    /// `FAULT=`: the latched device fault.
    pub fault: FaultCode,
    /// `SEQ=`: sequence number of the current or last motion command on this axis (0 = none since boot).
    pub seq: Option<Seq>,
}

/// A reply to a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reply<'a> {
    /// `OK` with no payload (PING, SPEED, ACCEL, STOP, ESTOP, CLEAR, RESET).
    Ok,
    /// `OK PROTO=.. FW=.. AXES=.. [RAIL=min:max]` (HELLO).
    Hello(HelloInfo<'a>),
    /// `OK ETA=ms`: motion accepted, expected duration in ms (HOME, MOVE_ABS, MOVE_REL).
    Moving {
        /// Expected motion time in milliseconds (an upper bound for HOME).
        eta_ms: u32,
    },
    /// `OK POS=.. TGT=.. MOV=.. HOMED=.. FAULT=.. SEQ=..` (STATUS).
    Status(StatusInfo),
    /// `ERR CODE`.
    Err(ErrorCode),
}

impl<'a> Reply<'a> {
    /// Parse a reply body to a command of `kind`. Unknown `KEY=value` fields are ignored.
    pub fn parse(kind: CommandKind, body: &'a str) -> Result<Reply<'a>, ParseError> {
        if let Some(code) = body.strip_prefix("ERR ") {
            let code = code.split(' ').next().unwrap_or("");
            return Ok(Reply::Err(ErrorCode::from_word(code)));
        }
        let rest = match body.strip_prefix("OK") {
            Some("") => "",
            Some(r) => r.strip_prefix(' ').ok_or(ParseError::BadReply)?,
            None => return Err(ParseError::BadReply),
        };
        Ok(match kind {
            CommandKind::Hello => {
                let proto = req(rest, "PROTO", |v| {
                    parse_u32(v).and_then(|p| u16::try_from(p).ok())
                })?;
                let fw = req(rest, "FW", |v| {
                    (!v.is_empty() && v.len() <= crate::MAX_FW_LEN).then_some(v)
                })?;
                let axes = req(rest, "AXES", parse_u32)?;
                let rail = match axes {
                    1 => None,
                    2 => Some(req(rest, "RAIL", parse_range)?),
                    _ => return Err(ParseError::BadField("AXES")),
                };
                Reply::Hello(HelloInfo { proto, fw, rail })
            }
            CommandKind::Home | CommandKind::MoveAbs | CommandKind::MoveRel => Reply::Moving {
                eta_ms: req(rest, "ETA", parse_u32)?,
            },
            CommandKind::Status => Reply::Status(StatusInfo {
                pos: req(rest, "POS", parse_i32)?,
                target: req(rest, "TGT", parse_i32)?,
                moving: req(rest, "MOV", parse_flag)?,
                homed: req(rest, "HOMED", parse_flag)?,
                fault: req(rest, "FAULT", |v| Some(FaultCode::from_word(v)))?,
                seq: req(rest, "SEQ", |v| {
                    parse_u32(v).and_then(|s| u16::try_from(s).ok())
                })
                .map(Seq::new)?,
            }),
            _ => Reply::Ok,
        })
    }

    pub(crate) fn write_body<W: Write>(&self, w: &mut W) -> fmt::Result {
        match self {
            Reply::Ok => w.write_str("OK"),
            Reply::Hello(h) => {
                write!(w, "OK PROTO={} FW={} AXES={}", h.proto, h.fw, h.axes())?;
                match h.rail {
                    Some((lo, hi)) => write!(w, " RAIL={lo}:{hi}"),
                    None => Ok(()),
                }
            }
            Reply::Moving { eta_ms } => write!(w, "OK ETA={eta_ms}"),
            Reply::Status(s) => write!(
                w,
                "OK POS={} TGT={} MOV={} HOMED={} FAULT={} SEQ={}",
                s.pos,
                s.target,
                u8::from(s.moving),
                u8::from(s.homed),
                s.fault.word(),
                s.seq.map_or(0, Seq::get)
            ),
            Reply::Err(code) => write!(w, "ERR {}", code.word()),
        }
    }
}

fn parse_range(v: &str) -> Option<(i32, i32)> {
    let (lo, hi) = v.split_once(':')?;
    let (lo, hi) = (parse_i32(lo)?, parse_i32(hi)?);
    (lo <= hi).then_some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_replies() {
        let h = Reply::parse(
            CommandKind::Hello,
            "OK PROTO=1 FW=cacsim-0.1 AXES=2 RAIL=0:400000 X=9",
        );
        assert_eq!(
            h,
            Ok(Reply::Hello(HelloInfo {
                proto: 1,
                fw: "cacsim-0.1",
                rail: Some((0, 400000))
            }))
        );
        assert_eq!(Reply::parse(CommandKind::Ping, "OK"), Ok(Reply::Ok));
        assert_eq!(
            Reply::parse(CommandKind::MoveAbs, "OK ETA=1500"),
            Ok(Reply::Moving { eta_ms: 1500 })
        );
        assert_eq!(
            Reply::parse(CommandKind::MoveAbs, "ERR BUSY"),
            Ok(Reply::Err(ErrorCode::Busy))
        );
        assert_eq!(
            Reply::parse(CommandKind::MoveAbs, "ERR WHAT"),
            Ok(Reply::Err(ErrorCode::Other))
        );
        let s = Reply::parse(
            CommandKind::Status,
            "OK POS=-5 TGT=0 MOV=1 HOMED=0 FAULT=ESTOP SEQ=0",
        );
        assert_eq!(
            s,
            Ok(Reply::Status(StatusInfo {
                pos: -5,
                target: 0,
                moving: true,
                homed: false,
                fault: FaultCode::Estop,
                seq: None
            }))
        );
    }

    #[test]
    fn rejects_bad_replies() {
        assert_eq!(
            Reply::parse(CommandKind::Ping, "OKAY"),
            Err(ParseError::BadReply)
        );
        assert_eq!(
            Reply::parse(CommandKind::Ping, "NO"),
            Err(ParseError::BadReply)
        );
        assert_eq!(
            Reply::parse(CommandKind::MoveAbs, "OK"),
            Err(ParseError::BadField("ETA"))
        );
        assert_eq!(
            Reply::parse(CommandKind::Hello, "OK PROTO=1 FW=x AXES=2 RAIL=5:1"),
            Err(ParseError::BadField("RAIL"))
        );
        assert_eq!(
            Reply::parse(CommandKind::Hello, "OK PROTO=1 FW=x AXES=3"),
            Err(ParseError::BadField("AXES"))
        );
        assert_eq!(
            Reply::parse(
                CommandKind::Status,
                "OK POS=1 TGT=1 MOV=2 HOMED=1 FAULT=NONE SEQ=1"
            ),
            Err(ParseError::BadField("MOV"))
        );
    }
}
