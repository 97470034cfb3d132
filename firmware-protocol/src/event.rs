//! Unsolicited device→host events, framed with `!` instead of a sequence number:
//! `BOOT` (the device started), `DONE` (a motion command finished), `FAULT` (a fault latched).

use crate::command::Axis;
use crate::frame::Seq;
use crate::reply::FaultCode;
use crate::token::{field, parse_i32, parse_u32, req, ParseError};
use core::fmt::{self, Write};

/// Why the device (re)started, in the `BOOT` event.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BootReason {
    /// `POWERON`
    PowerOn,
    /// `RESET`: reset pin, DTR auto-reset, or the `RESET` command.
    Reset,
    /// `WATCHDOG`
    Watchdog,
    /// `BROWNOUT`
    Brownout,
    /// A reason this version does not know.
    Other,
}

impl BootReason {
    /// The word on the wire.
    pub const fn word(self) -> &'static str {
        match self {
            BootReason::PowerOn => "POWERON",
            BootReason::Reset => "RESET",
            BootReason::Watchdog => "WATCHDOG",
            BootReason::Brownout => "BROWNOUT",
            BootReason::Other => "OTHER",
        }
    }

    fn from_word(w: &str) -> BootReason {
        match w {
            "POWERON" => BootReason::PowerOn,
            "RESET" => BootReason::Reset,
            "WATCHDOG" => BootReason::Watchdog,
            "BROWNOUT" => BootReason::Brownout,
            _ => BootReason::Other,
        }
    }
}

/// How a motion ended, in the `DONE` event.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DoneEnd {
    /// `REACHED`: the target (or, for HOME, the reference) was reached.
    Reached,
    /// `STOPPED`: cut short by `STOP`.
    Stopped,
    /// `ABORTED`: cut short by `ESTOP` or a fault.
    Aborted,
}

impl DoneEnd {
    /// The word on the wire.
    pub const fn word(self) -> &'static str {
        match self {
            DoneEnd::Reached => "REACHED",
            DoneEnd::Stopped => "STOPPED",
            DoneEnd::Aborted => "ABORTED",
        }
    }

    fn from_word(w: &str) -> Option<DoneEnd> {
        match w {
            "REACHED" => Some(DoneEnd::Reached),
            "STOPPED" => Some(DoneEnd::Stopped),
            "ABORTED" => Some(DoneEnd::Aborted),
            _ => None,
        }
    }
}

/// An unsolicited event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event<'a> {
    /// `BOOT PROTO=.. FW=.. REASON=..`: the device started; nothing is homed, the reply cache is empty.
    Boot {
        /// Protocol version.
        proto: u16,
        /// Firmware name/version.
        fw: &'a str,
        /// Why it started.
        reason: BootReason,
    },
    /// `DONE SEQ=.. AXIS=.. POS=.. END=..`: the motion command `SEQ` finished.
    Done {
        /// Sequence number of the HOME / MOVE_ABS / MOVE_REL command.
        seq: Seq,
        /// Its axis.
        axis: Axis,
        /// Position where it ended.
        pos: i32,
        /// How it ended.
        end: DoneEnd,
    },
    /// `FAULT CODE=.. [AXIS=..]`: a fault latched.
    Fault {
        /// Which fault.
        code: FaultCode,
        /// The axis concerned, if any.
        axis: Option<Axis>,
    },
}

impl<'a> Event<'a> {
    /// Parse an event body. Unknown `KEY=value` fields are ignored. Never panics.
    pub fn parse(body: &'a str) -> Result<Event<'a>, ParseError> {
        let (name, rest) = body.split_once(' ').unwrap_or((body, ""));
        match name {
            "BOOT" => Ok(Event::Boot {
                proto: req(rest, "PROTO", |v| {
                    parse_u32(v).and_then(|p| u16::try_from(p).ok())
                })?,
                fw: req(rest, "FW", |v| {
                    (!v.is_empty() && v.len() <= crate::MAX_FW_LEN).then_some(v)
                })?,
                reason: req(rest, "REASON", |v| Some(BootReason::from_word(v)))?,
            }),
            "DONE" => Ok(Event::Done {
                seq: req(rest, "SEQ", |v| {
                    parse_u32(v)
                        .and_then(|s| u16::try_from(s).ok())
                        .and_then(Seq::new)
                })?,
                axis: req(rest, "AXIS", |v| Axis::parse(v).ok())?,
                pos: req(rest, "POS", parse_i32)?,
                end: req(rest, "END", DoneEnd::from_word)?,
            }),
            "FAULT" => Ok(Event::Fault {
                code: req(rest, "CODE", |v| Some(FaultCode::from_word(v)))?,
                axis: match field(rest, "AXIS") {
                    None => None,
                    Some(v) => Some(Axis::parse(v).map_err(|_| ParseError::BadField("AXIS"))?),
                },
            }),
            _ => Err(ParseError::UnknownEvent),
        }
    }

    pub(crate) fn write_body<W: Write>(&self, w: &mut W) -> fmt::Result {
        match self {
            Event::Boot { proto, fw, reason } => {
                write!(w, "BOOT PROTO={proto} FW={fw} REASON={}", reason.word())
            }
            Event::Done {
                seq,
                axis,
                pos,
                end,
            } => {
                write!(w, "DONE SEQ={seq} AXIS={axis} POS={pos} END={}", end.word())
            }
            Event::Fault { code, axis } => {
                write!(w, "FAULT CODE={}", code.word())?;
                match axis {
                    Some(a) => write!(w, " AXIS={a}"),
                    None => Ok(()),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_events() {
        assert_eq!(
            Event::parse("BOOT PROTO=1 FW=cacsim-0.1 REASON=WATCHDOG"),
            Ok(Event::Boot {
                proto: 1,
                fw: "cacsim-0.1",
                reason: BootReason::Watchdog
            })
        );
        assert_eq!(
            Event::parse("DONE SEQ=7 AXIS=2 POS=-3 END=STOPPED"),
            Ok(Event::Done {
                seq: Seq::new(7).unwrap(),
                axis: Axis::Rail,
                pos: -3,
                end: DoneEnd::Stopped
            })
        );
        assert_eq!(
            Event::parse("FAULT CODE=ESTOP"),
            Ok(Event::Fault {
                code: FaultCode::Estop,
                axis: None
            })
        );
        assert_eq!(
            Event::parse("DONE SEQ=0 AXIS=1 POS=0 END=REACHED"),
            Err(ParseError::BadField("SEQ"))
        );
        assert_eq!(
            Event::parse("FAULT CODE=LIMIT AXIS=9"),
            Err(ParseError::BadField("AXIS"))
        );
        assert_eq!(Event::parse("NOPE"), Err(ParseError::UnknownEvent));
    }
}
