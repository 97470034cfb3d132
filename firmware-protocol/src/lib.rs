//! # firmware-protocol — the cac turntable serial protocol
//!
//! One ASCII line per message, `<seq> BODY *CRC16\n`, spoken between a host (the `cac` capture
//! rig) and a turntable controller (a microcontroller, or `cac`'s simulated firmware). The crate is
//! `no_std` and allocation-free so that firmware can use it as is: lines are assembled, parsed and
//! encoded in fixed buffers of [`MAX_LINE`] bytes, and parsed values borrow from the line.
//!
//! The complete specification — grammar, commands, replies, events, error codes, timing,
//! retry/idempotency rules and boot behaviour — is `docs/protocol.md` at the repository root.
//!
//! The firmware for a real board (`avr/`, in C) implements the same specification on its own; what
//! it shares with this crate is the test vectors, `tests/vectors.txt` (lines with their expected
//! parse), which this crate's `tests/vectors.rs` and the C parser's host unit test (`make test`)
//! both run.
//!
//! * [`LineAssembler`] turns a byte stream into lines, resynchronising on `\n`.
//! * [`Frame::parse`] checks a line's framing and CRC; [`Command`], [`Reply`] and [`Event`] parse and
//!   encode the bodies.
//! * [`LineBuf`] is the fixed-capacity output buffer the encoders write into.
//!
//! The parsers never panic on any input (property-tested over arbitrary bytes, and fuzzed by the
//! target under `fuzz/`).
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(feature = "alloc")]
extern crate alloc;

mod command;
mod crc;
mod event;
mod frame;
mod line;
mod reply;
mod token;

pub use command::{Axis, Command, CommandKind};
pub use crc::crc16;
pub use event::{BootReason, DoneEnd, Event};
pub use frame::{EncodeError, Frame, FrameError, Seq, SeqField};
pub use line::{LineAssembler, LineBuf, LineError, Overflow};
pub use reply::{ErrorCode, FaultCode, HelloInfo, Reply, StatusInfo};
pub use token::ParseError;

/// Protocol version announced in `HELLO` replies and `BOOT` events.
pub const PROTOCOL_VERSION: u16 = 1;

/// Longest line in bytes, not counting the terminating `\n` (an optional `\r` before it counts).
pub const MAX_LINE: usize = 96;

/// Longest firmware version string (`FW=` value) in bytes.
pub const MAX_FW_LEN: usize = 24;

/// Encode a complete host→device line: `<seq> BODY *CRC\n`.
pub fn encode_command(seq: Seq, cmd: &Command, out: &mut LineBuf) -> Result<(), EncodeError> {
    frame::encode(SeqField::Seq(seq), out, |b| cmd.write_body(b))
}

/// Encode a complete device→host reply line: `<seq> OK ...` or `<seq> ERR CODE`.
pub fn encode_reply(seq: Seq, reply: &Reply<'_>, out: &mut LineBuf) -> Result<(), EncodeError> {
    frame::encode(SeqField::Seq(seq), out, |b| reply.write_body(b))
}

/// Encode a complete unsolicited event line: `! EVENT ...`.
pub fn encode_event(event: &Event<'_>, out: &mut LineBuf) -> Result<(), EncodeError> {
    frame::encode(SeqField::Event, out, |b| event.write_body(b))
}
