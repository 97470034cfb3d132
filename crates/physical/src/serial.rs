//! [`Transport`] over a serial port (`serialport` crate): a USB-serial adapter, a board's CDC-ACM
//! port, or a pseudo-terminal. Reopens by path, so a stable name (`/dev/serial/by-id/...`, or the
//! simulator's symlink) survives the device re-enumerating under a new node.

use super::transport::Transport;
use serialport::{ClearBuffer, SerialPort};
use std::io::{self, Read, Write};
use std::time::{Duration, Instant};

/// A serial port opened by path.
pub struct SerialTransport {
    path: String,
    baud: u32,
    port: Option<Box<dyn SerialPort>>,
    epoch: Instant,
}

impl std::fmt::Debug for SerialTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SerialTransport")
            .field("path", &self.path)
            .field("baud", &self.baud)
            .field("open", &self.port.is_some())
            .finish()
    }
}

impl SerialTransport {
    /// Open `path` at `baud` (8N1, no flow control).
    pub fn open(path: &str, baud: u32) -> io::Result<Self> {
        let mut t = Self {
            path: path.to_string(),
            baud,
            port: None,
            epoch: Instant::now(),
        };
        t.reopen()?;
        Ok(t)
    }

    /// The path it opens.
    pub fn path(&self) -> &str {
        &self.path
    }

    fn port(&mut self) -> io::Result<&mut Box<dyn SerialPort>> {
        self.port.as_mut().ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::NotConnected,
                "serial port is closed (reopen failed)",
            )
        })
    }

    fn fail<T>(&mut self, e: io::Error) -> io::Result<T> {
        // Any hard error closes the port: the driver reopens it.
        self.port = None;
        Err(e)
    }
}

impl Transport for SerialTransport {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        let r = self
            .port()?
            .write_all(bytes)
            .and_then(|()| self.port()?.flush());
        match r {
            Ok(()) => Ok(()),
            Err(e) => self.fail(e),
        }
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let port = self.port()?;
        port.set_timeout(timeout.max(Duration::from_millis(1)))
            .map_err(io::Error::from)?;
        match port.read(buf) {
            Ok(0) => self.fail(io::Error::new(
                io::ErrorKind::BrokenPipe,
                "serial port hung up",
            )),
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
                ) =>
            {
                Ok(0)
            }
            Err(e) => self.fail(e),
        }
    }

    fn discard_input(&mut self) -> io::Result<()> {
        let r = self
            .port()?
            .clear(ClearBuffer::Input)
            .map_err(io::Error::from);
        match r {
            Ok(()) => Ok(()),
            Err(e) => self.fail(e),
        }
    }

    fn reopen(&mut self) -> io::Result<()> {
        self.port = None;
        let port = serialport::new(&self.path, self.baud)
            .timeout(Duration::from_millis(50))
            .open()
            .map_err(|e| {
                io::Error::new(io::ErrorKind::NotConnected, format!("{}: {e}", self.path))
            })?;
        self.port = Some(port);
        Ok(())
    }

    fn now(&self) -> Duration {
        self.epoch.elapsed()
    }

    fn pause(&mut self, d: Duration) {
        std::thread::sleep(d);
    }
}
