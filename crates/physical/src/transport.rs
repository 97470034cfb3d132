//! The byte-stream abstraction the turntable driver runs on, with its own clock so that the
//! in-memory simulator can run the driver on virtual time.

use std::io;
use std::time::Duration;

/// A bidirectional byte stream to a turntable controller, plus the clock the driver measures its
/// timeouts with.
///
/// Errors from `write_all` / `read` of kind other than `TimedOut` / `Interrupted` mean the link is
/// gone (unplugged, port closed): the driver then calls [`reopen`](Transport::reopen) until it
/// succeeds or its deadline passes.
pub trait Transport {
    /// Send all of `bytes`.
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Read what is available, waiting at most `timeout` for the first byte. `Ok(0)` means the
    /// timeout passed with nothing received.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
    /// Throw away bytes received but not yet read.
    fn discard_input(&mut self) -> io::Result<()>;
    /// Close and open the link again (after a disconnect).
    fn reopen(&mut self) -> io::Result<()>;
    /// Monotonic time since some fixed start.
    fn now(&self) -> Duration;
    /// Let `d` pass.
    fn pause(&mut self, d: Duration);
}

impl<T: Transport + ?Sized> Transport for Box<T> {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        (**self).write_all(bytes)
    }
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        (**self).read(buf, timeout)
    }
    fn discard_input(&mut self) -> io::Result<()> {
        (**self).discard_input()
    }
    fn reopen(&mut self) -> io::Result<()> {
        (**self).reopen()
    }
    fn now(&self) -> Duration {
        (**self).now()
    }
    fn pause(&mut self, d: Duration) {
        (**self).pause(d)
    }
}
