//! Fixed-size line buffers: [`LineAssembler`] splits an incoming byte stream into lines and
//! resynchronises on `\n`; [`LineBuf`] is the bounded output buffer the encoders write into.

use crate::MAX_LINE;
use core::fmt;

/// Why an assembled line was thrown away.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineError {
    /// More than [`MAX_LINE`] bytes arrived before the `\n`; everything up to it was discarded.
    TooLong,
}

impl fmt::Display for LineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LineError::TooLong => write!(f, "line longer than {MAX_LINE} bytes"),
        }
    }
}

/// Splits a byte stream into lines of at most [`MAX_LINE`] bytes.
///
/// Feed bytes one at a time with [`push`](Self::push). A line ends at `\n`; one `\r` right before
/// it is removed. Empty lines are skipped silently (a lone `\n` is how a sender resynchronises).
/// An over-long line is reported once, at its `\n`, as [`LineError::TooLong`], and the assembler is
/// ready for the next line: one corrupt line never swallows the next.
#[derive(Clone)]
pub struct LineAssembler {
    buf: [u8; MAX_LINE],
    len: usize,
    overflowed: bool,
}

impl fmt::Debug for LineAssembler {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LineAssembler")
            .field("pending", &self.len)
            .field("overflowed", &self.overflowed)
            .finish()
    }
}

impl Default for LineAssembler {
    fn default() -> Self {
        Self::new()
    }
}

impl LineAssembler {
    /// An empty assembler.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_LINE],
            len: 0,
            overflowed: false,
        }
    }

    /// Add one byte. Returns `Some` when it completed a line (without `\r\n`) or an over-long one.
    pub fn push(&mut self, byte: u8) -> Option<Result<&[u8], LineError>> {
        if byte == b'\n' {
            let len = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.overflowed) {
                return Some(Err(LineError::TooLong));
            }
            let line = match &self.buf[..len] {
                [rest @ .., b'\r'] => rest,
                all => all,
            };
            return if line.is_empty() {
                None
            } else {
                Some(Ok(line))
            };
        }
        if self.overflowed {
            return None;
        }
        if self.len == MAX_LINE {
            self.overflowed = true;
            self.len = 0;
            return None;
        }
        self.buf[self.len] = byte;
        self.len += 1;
        None
    }

    /// Forget any partial line (used after a reset or a reopened port).
    pub fn clear(&mut self) {
        self.len = 0;
        self.overflowed = false;
    }

    /// Bytes of the partial line held so far.
    pub fn pending(&self) -> usize {
        self.len
    }
}

/// The output did not fit in a [`LineBuf`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Overflow;

impl fmt::Display for Overflow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "encoded line longer than {MAX_LINE} bytes")
    }
}

/// A bounded buffer holding one encoded line (up to [`MAX_LINE`] bytes plus the `\n`).
#[derive(Clone)]
pub struct LineBuf {
    buf: [u8; MAX_LINE + 1],
    len: usize,
}

impl Default for LineBuf {
    fn default() -> Self {
        Self::new()
    }
}

impl fmt::Debug for LineBuf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "LineBuf({:?})",
            core::str::from_utf8(self.as_bytes()).unwrap_or("<non-utf8>")
        )
    }
}

impl LineBuf {
    /// An empty buffer.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_LINE + 1],
            len: 0,
        }
    }

    /// The bytes written so far.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    /// Number of bytes written.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing has been written.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Empty the buffer.
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Shorten to `len` bytes (no-op when already shorter).
    pub fn truncate(&mut self, len: usize) {
        self.len = self.len.min(len);
    }

    /// Append raw bytes.
    pub fn push_bytes(&mut self, bytes: &[u8]) -> Result<(), Overflow> {
        let end = self.len.checked_add(bytes.len()).ok_or(Overflow)?;
        let dst = self.buf.get_mut(self.len..end).ok_or(Overflow)?;
        dst.copy_from_slice(bytes);
        self.len = end;
        Ok(())
    }
}

impl fmt::Write for LineBuf {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.push_bytes(s.as_bytes()).map_err(|_| fmt::Error)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(input: &[u8]) -> ([[u8; 8]; 4], usize, usize) {
        let mut asm = LineAssembler::new();
        let mut out = [[0u8; 8]; 4];
        let (mut n, mut errs) = (0, 0);
        for &b in input {
            match asm.push(b) {
                Some(Ok(l)) => {
                    out[n][..l.len()].copy_from_slice(l);
                    n += 1;
                }
                Some(Err(LineError::TooLong)) => errs += 1,
                None => {}
            }
        }
        (out, n, errs)
    }

    #[test]
    fn splits_strips_cr_and_skips_empty() {
        let (out, n, errs) = lines(b"\n\nab\r\ncd\n\r\n");
        assert_eq!((n, errs), (2, 0));
        assert_eq!(&out[0][..2], b"ab");
        assert_eq!(&out[1][..2], b"cd");
    }

    #[test]
    fn overlong_line_is_reported_once_and_next_line_survives() {
        let mut input = [b'x'; MAX_LINE + 10];
        input[MAX_LINE + 5] = b'\n';
        input[MAX_LINE + 6..].copy_from_slice(b"ok\n\n");
        let (out, n, errs) = lines(&input);
        assert_eq!((n, errs), (1, 1));
        assert_eq!(&out[0][..2], b"ok");
    }

    #[test]
    fn exactly_max_line_fits() {
        let mut asm = LineAssembler::new();
        for _ in 0..MAX_LINE {
            assert!(asm.push(b'a').is_none());
        }
        assert_eq!(
            asm.push(b'\n').map(|r| r.map(|l| l.len())),
            Some(Ok(MAX_LINE))
        );
    }

    #[test]
    fn linebuf_overflows_cleanly() {
        let mut b = LineBuf::new();
        assert!(b.push_bytes(&[b'a'; MAX_LINE + 1]).is_ok());
        assert_eq!(b.push_bytes(b"x"), Err(Overflow));
        assert_eq!(b.len(), MAX_LINE + 1);
    }
}
