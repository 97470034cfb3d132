//! Line framing: `<seq> BODY *CRC16`, where `<seq>` is a decimal sequence number (commands and
//! their replies) or `!` (unsolicited events), and the CRC covers every byte before ` *`.

use crate::crc::crc16;
use crate::line::LineBuf;
use core::fmt::{self, Write};

/// A command sequence number, `1..=65535`. `0` is never used on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Seq(u16);

impl Seq {
    /// The first sequence number a host uses after opening the port.
    pub const FIRST: Seq = Seq(1);

    /// `Some` for `1..=65535`.
    pub const fn new(n: u16) -> Option<Seq> {
        if n == 0 {
            None
        } else {
            Some(Seq(n))
        }
    }

    /// The numeric value.
    pub const fn get(self) -> u16 {
        self.0
    }

    /// The next sequence number; 65535 wraps to 1.
    pub const fn next(self) -> Seq {
        if self.0 == u16::MAX {
            Seq(1)
        } else {
            Seq(self.0 + 1)
        }
    }
}

impl fmt::Display for Seq {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// The first field of a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeqField {
    /// A command, or the reply to the command with this number.
    Seq(Seq),
    /// `!`: an unsolicited event.
    Event,
}

/// Why a line is not a well-framed message. A device stays silent on these (see the spec).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameError {
    /// A byte outside printable ASCII (0x20..=0x7E).
    NotAscii,
    /// No ` *` followed by four uppercase hex digits at the end of the line.
    MissingCrc,
    /// The CRC in the line does not match the content.
    CrcMismatch {
        /// CRC carried by the line.
        received: u16,
        /// CRC computed over the content.
        computed: u16,
    },
    /// The first field is neither `!` nor a decimal number in `1..=65535` without leading zeros.
    BadSeq,
    /// Nothing after the sequence field.
    EmptyBody,
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameError::NotAscii => write!(f, "byte outside printable ASCII"),
            FrameError::MissingCrc => write!(f, "missing or malformed ' *XXXX' CRC suffix"),
            FrameError::CrcMismatch { received, computed } => {
                write!(
                    f,
                    "CRC mismatch: line says {received:04X}, content gives {computed:04X}"
                )
            }
            FrameError::BadSeq => write!(f, "bad sequence field"),
            FrameError::EmptyBody => write!(f, "empty message body"),
        }
    }
}

/// A line whose framing and CRC are valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    /// Sequence number, or `!` for events.
    pub seq: SeqField,
    /// Everything between the sequence field and ` *CRC`, e.g. `MOVE_ABS 1 90000`.
    pub body: &'a str,
}

impl<'a> Frame<'a> {
    /// Check framing and CRC of one line (without its `\r\n`). Never panics.
    pub fn parse(line: &'a [u8]) -> Result<Frame<'a>, FrameError> {
        if line.iter().any(|&b| !(0x20..=0x7E).contains(&b)) {
            return Err(FrameError::NotAscii);
        }
        let n = line.len();
        if n < 6 || &line[n - 6..n - 4] != b" *" {
            return Err(FrameError::MissingCrc);
        }
        let received = parse_crc(&line[n - 4..]).ok_or(FrameError::MissingCrc)?;
        let content = &line[..n - 6];
        let computed = crc16(content);
        if received != computed {
            return Err(FrameError::CrcMismatch { received, computed });
        }
        // Printable ASCII is valid UTF-8.
        let content = core::str::from_utf8(content).map_err(|_| FrameError::NotAscii)?;
        let (seq, body) = content.split_once(' ').ok_or(FrameError::EmptyBody)?;
        let seq = parse_seq_field(seq).ok_or(FrameError::BadSeq)?;
        if body.is_empty() {
            return Err(FrameError::EmptyBody);
        }
        Ok(Frame { seq, body })
    }
}

fn parse_crc(hex: &[u8]) -> Option<u16> {
    let mut v: u16 = 0;
    for &c in hex {
        let d = match c {
            b'0'..=b'9' => c - b'0',
            b'A'..=b'F' => c - b'A' + 10,
            _ => return None,
        };
        v = (v << 4) | u16::from(d);
    }
    Some(v)
}

fn parse_seq_field(s: &str) -> Option<SeqField> {
    if s == "!" {
        return Some(SeqField::Event);
    }
    if s.is_empty() || s.len() > 5 || s.starts_with('0') || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let n: u32 = s.parse().ok()?;
    let n = u16::try_from(n).ok()?;
    Seq::new(n).map(SeqField::Seq)
}

/// Errors when encoding a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeError {
    /// The line would exceed [`crate::MAX_LINE`] bytes.
    TooLong,
    /// The body holds a byte that may not appear in it (control character, non-ASCII, `*`,
    /// or an empty token from a leading, trailing or doubled space).
    InvalidText,
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EncodeError::TooLong => write!(f, "encoded line longer than {} bytes", crate::MAX_LINE),
            EncodeError::InvalidText => write!(f, "message text not allowed on the wire"),
        }
    }
}

/// Write `<seq> ` + body + ` *CRC\n` into `out` (cleared first), validating the body.
pub(crate) fn encode(
    seq: SeqField,
    out: &mut LineBuf,
    body: impl FnOnce(&mut LineBuf) -> fmt::Result,
) -> Result<(), EncodeError> {
    out.clear();
    match seq {
        SeqField::Seq(s) => write!(out, "{s} "),
        SeqField::Event => out.write_str("! "),
    }
    .map_err(|_| EncodeError::TooLong)?;
    let start = out.len();
    body(out).map_err(|_| EncodeError::TooLong)?;
    let text = &out.as_bytes()[start..];
    let valid_bytes = text
        .iter()
        .all(|&b| (0x20..=0x7E).contains(&b) && b != b'*');
    let valid_tokens = !text.is_empty() && text.split(|&b| b == b' ').all(|t| !t.is_empty());
    if !(valid_bytes && valid_tokens) {
        out.clear();
        return Err(EncodeError::InvalidText);
    }
    let crc = crc16(out.as_bytes());
    let r = writeln!(out, " *{crc:04X}");
    if r.is_err() || out.len() > crate::MAX_LINE + 1 {
        out.clear();
        return Err(EncodeError::TooLong);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_valid_frames() {
        let mut b = LineBuf::new();
        encode(SeqField::Seq(Seq::new(42).unwrap()), &mut b, |b| {
            b.write_str("PING")
        })
        .unwrap();
        let line = b.as_bytes();
        assert_eq!(line.last(), Some(&b'\n'));
        let f = Frame::parse(&line[..line.len() - 1]).unwrap();
        assert_eq!(f.seq, SeqField::Seq(Seq::new(42).unwrap()));
        assert_eq!(f.body, "PING");
        let expected = crc16(b"42 PING");
        assert_eq!(line, alloc_free_fmt(expected).as_bytes());
    }

    fn alloc_free_fmt(crc: u16) -> LineBuf {
        let mut b = LineBuf::new();
        writeln!(b, "42 PING *{crc:04X}").unwrap();
        b
    }

    #[test]
    fn rejects_bad_frames() {
        let good = {
            let mut b = LineBuf::new();
            encode(SeqField::Event, &mut b, |b| b.write_str("BOOT PROTO=1")).unwrap();
            b
        };
        let g = &good.as_bytes()[..good.len() - 1];
        assert!(Frame::parse(g).is_ok());
        let mut bad = [0u8; 128];
        bad[..g.len()].copy_from_slice(g);
        bad[3] ^= 0x01;
        assert!(matches!(
            Frame::parse(&bad[..g.len()]),
            Err(FrameError::CrcMismatch { .. })
        ));
        assert_eq!(Frame::parse(b"1 PING"), Err(FrameError::MissingCrc));
        assert_eq!(Frame::parse(b"1 PING *zzzz"), Err(FrameError::MissingCrc));
        assert_eq!(Frame::parse(b"1 PING\x01*0000"), Err(FrameError::NotAscii));
        for seq in ["0", "01", "65536", "-1", "+1", "x"] {
            let mut b = LineBuf::new();
            write!(b, "{seq} PING").unwrap();
            let crc = crc16(b.as_bytes());
            write!(b, " *{crc:04X}").unwrap();
            assert_eq!(Frame::parse(b.as_bytes()), Err(FrameError::BadSeq), "{seq}");
        }
    }

    #[test]
    fn encoder_refuses_invalid_text() {
        let mut b = LineBuf::new();
        let s = SeqField::Seq(Seq::FIRST);
        assert_eq!(
            encode(s, &mut b, |b| b.write_str("A *B")),
            Err(EncodeError::InvalidText)
        );
        assert_eq!(
            encode(s, &mut b, |b| b.write_str("A  B")),
            Err(EncodeError::InvalidText)
        );
        assert_eq!(
            encode(s, &mut b, |b| b.write_str("")),
            Err(EncodeError::InvalidText)
        );
        assert_eq!(
            encode(s, &mut b, |b| b.write_str("A\nB")),
            Err(EncodeError::InvalidText)
        );
        let long = [b'A'; 90];
        let long = core::str::from_utf8(&long).unwrap();
        assert_eq!(
            encode(s, &mut b, |b| b.write_str(long)),
            Err(EncodeError::TooLong)
        );
    }

    #[test]
    fn seq_wraps() {
        assert_eq!(Seq::new(65535).unwrap().next(), Seq::FIRST);
        assert_eq!(Seq::new(0), None);
    }
}
