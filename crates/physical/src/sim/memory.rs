//! In-memory [`Transport`] to a [`SimWorld`] on a virtual clock: reading with a timeout runs the
//! simulation forward instead of sleeping, so a thousand moves with faults take milliseconds.

use super::world::SimHandle;
use crate::Transport;
use std::io;
use std::time::Duration;

/// The host end of the simulated serial link, on virtual time.
#[derive(Debug, Clone)]
pub struct MemoryTransport {
    world: SimHandle,
}

impl MemoryTransport {
    /// Connect to `world`, opening the port (which reboots the device if the link is configured
    /// with DTR auto-reset).
    pub fn open(world: SimHandle) -> io::Result<Self> {
        world.lock().host_open()?;
        Ok(Self { world })
    }

    /// The world behind it.
    pub fn world(&self) -> &SimHandle {
        &self.world
    }
}

impl Transport for MemoryTransport {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.world.lock().host_write(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let mut w = self.world.lock();
        let deadline = w.now() + timeout;
        loop {
            if w.is_down() {
                return Err(io::Error::new(
                    io::ErrorKind::BrokenPipe,
                    "simulated port unplugged",
                ));
            }
            let got = w.host_take(buf.len());
            if !got.is_empty() {
                buf[..got.len()].copy_from_slice(&got);
                return Ok(got.len());
            }
            match w.next_event_time() {
                Some(t) if t <= deadline => {
                    let t = t.max(w.now());
                    w.advance_to(t);
                }
                _ => {
                    w.advance_to(deadline);
                    return Ok(0);
                }
            }
        }
    }

    fn discard_input(&mut self) -> io::Result<()> {
        let mut w = self.world.lock();
        if w.is_down() {
            return Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                "simulated port unplugged",
            ));
        }
        w.host_discard();
        Ok(())
    }

    fn reopen(&mut self) -> io::Result<()> {
        self.world.lock().host_open()
    }

    fn now(&self) -> Duration {
        self.world.lock().now()
    }

    fn pause(&mut self, d: Duration) {
        let mut w = self.world.lock();
        let t = w.now() + d;
        w.advance_to(t);
    }
}
