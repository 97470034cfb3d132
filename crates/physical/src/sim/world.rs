//! The simulated world: the device, the serial link between it and the host (latency, byte time,
//! fault injection, disconnects) and the clock, advanced in event order. Both the in-memory
//! transport and the pseudo-terminal harness drive one of these.

use super::device::{DeviceConfig, SimDevice};
use super::faults::{FaultConfig, FaultCounts, FaultInjector};
use firmware_protocol::{Axis, BootReason};
use std::collections::VecDeque;
use std::io;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// Link timing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkConfig {
    /// Fixed one-way latency.
    pub latency: Duration,
    /// Time per byte (115200 baud 8N1 ≈ 87 µs).
    pub byte_time: Duration,
    /// Whether opening the port reboots the board (Arduino-style DTR auto-reset).
    pub reset_on_open: bool,
}

impl Default for LinkConfig {
    fn default() -> Self {
        Self {
            latency: Duration::from_millis(2),
            byte_time: Duration::from_micros(87),
            reset_on_open: false,
        }
    }
}

/// Device + link + clock.
#[derive(Debug)]
pub struct SimWorld {
    now: Duration,
    device: SimDevice,
    link: LinkConfig,
    faults: FaultInjector,
    to_device: VecDeque<(Duration, u8)>,
    to_host: VecDeque<(Duration, u8)>,
    down_until: Option<Duration>,
    reset_at: Option<Duration>,
    motions_seen: usize,
}

impl SimWorld {
    /// A powered-on device (its BOOT banner comes after `boot_time`) behind a link.
    pub fn new(device: DeviceConfig, link: LinkConfig, faults: FaultConfig) -> Self {
        // Start the table at a seed-dependent angle so homing times differ between runs.
        let angle = (faults.seed % 360) as f64 * 1000.0 + 123.0;
        Self {
            now: Duration::ZERO,
            device: SimDevice::new(device, Duration::ZERO, angle),
            link,
            faults: FaultInjector::new(faults),
            to_device: VecDeque::new(),
            to_host: VecDeque::new(),
            down_until: None,
            reset_at: None,
            motions_seen: 0,
        }
    }

    /// Current simulated time.
    pub fn now(&self) -> Duration {
        self.now
    }

    /// The device (for test oracles).
    pub fn device(&self) -> &SimDevice {
        &self.device
    }

    /// Faults injected so far.
    pub fn fault_counts(&self) -> FaultCounts {
        self.faults.counts()
    }

    /// Change the fault configuration (e.g. stop injecting before a final check). Keeps counts.
    pub fn set_faults(&mut self, cfg: FaultConfig) {
        let counts = self.faults.counts();
        self.faults = FaultInjector::new(cfg);
        self.faults.add_counts(counts);
    }

    /// Whether the link is down (unplugged).
    pub(crate) fn is_down(&self) -> bool {
        self.down_until.is_some()
    }

    /// When a downed link can be reopened.
    pub fn down_until(&self) -> Option<Duration> {
        self.down_until
    }

    fn queue(
        q: &mut VecDeque<(Duration, u8)>,
        now: Duration,
        link: &LinkConfig,
        extra: Duration,
        bytes: &[u8],
    ) {
        let mut t = (now + link.latency + extra).max(q.back().map_or(Duration::ZERO, |b| b.0));
        for &b in bytes {
            t += link.byte_time;
            q.push_back((t, b));
        }
    }

    /// The host writes bytes. Fails while the link is down (and may bring it down).
    pub(crate) fn host_write(&mut self, bytes: &[u8]) -> io::Result<()> {
        if self.down_until.is_some() {
            return Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                "simulated port unplugged",
            ));
        }
        if let Some(d) = self.faults.disconnect() {
            self.go_down(d);
            return Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                "simulated port unplugged",
            ));
        }
        let bytes = self.faults.corrupt(bytes);
        let extra = self.faults.delay();
        Self::queue(&mut self.to_device, self.now, &self.link, extra, &bytes);
        Ok(())
    }

    /// Unplug the link for `d` (bytes in flight are lost).
    pub(crate) fn go_down(&mut self, d: Duration) {
        self.to_device.clear();
        self.to_host.clear();
        self.down_until = Some(self.now + d);
    }

    /// The host (re)opens the port: fails while unplugged; may reboot the device (DTR reset, or a
    /// board that lost power with the link).
    pub(crate) fn host_open(&mut self) -> io::Result<()> {
        let was_down = match self.down_until {
            Some(t) if self.now < t => {
                return Err(io::Error::new(
                    io::ErrorKind::NotFound,
                    "simulated port not present",
                ))
            }
            Some(_) => true,
            None => false,
        };
        self.down_until = None;
        self.to_host.clear();
        if self.link.reset_on_open || (was_down && self.faults.reset_on_reconnect()) {
            if !self.link.reset_on_open {
                self.faults.count_reset();
            }
            self.device.reset(BootReason::Reset);
            self.reset_at = None;
        }
        Ok(())
    }

    /// Take up to `max` bytes that have reached the host by now.
    pub(crate) fn host_take(&mut self, max: usize) -> Vec<u8> {
        let mut out = Vec::new();
        while out.len() < max {
            match self.to_host.front() {
                Some(&(t, b)) if t <= self.now => {
                    out.push(b);
                    self.to_host.pop_front();
                }
                _ => break,
            }
        }
        out
    }

    /// Drop bytes that have reached the host but were not read.
    pub(crate) fn host_discard(&mut self) {
        while self.to_host.front().is_some_and(|&(t, _)| t <= self.now) {
            self.to_host.pop_front();
        }
    }

    /// The next time anything happens (a byte arrives at either end, a motion ends, a boot
    /// finishes, a reset fires).
    pub(crate) fn next_event_time(&self) -> Option<Duration> {
        [
            self.to_device.front().map(|b| b.0),
            self.to_host.front().map(|b| b.0),
            self.device.next_event_time(),
            self.reset_at,
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Run the world forward to `t`.
    pub(crate) fn advance_to(&mut self, t: Duration) {
        loop {
            let next = [
                self.to_device.front().map(|b| b.0),
                self.device.next_event_time(),
                self.reset_at,
            ]
            .into_iter()
            .flatten()
            .min();
            let Some(next) = next.filter(|&n| n <= t) else {
                break;
            };
            self.now = self.now.max(next);
            self.device.advance(self.now);
            if self.reset_at.is_some_and(|r| r <= self.now) {
                self.reset_at = None;
                self.faults.count_reset();
                self.device.reset(BootReason::Watchdog);
            }
            let mut arrived = Vec::new();
            while self
                .to_device
                .front()
                .is_some_and(|&(bt, _)| bt <= self.now)
            {
                arrived.push(self.to_device.pop_front().map(|b| b.1).unwrap_or(0));
            }
            if !arrived.is_empty() {
                self.device.receive(&arrived);
                self.roll_reset_for_new_motions();
            }
            self.flush_device_output();
        }
        self.now = self.now.max(t);
        self.device.advance(self.now);
        self.flush_device_output();
    }

    fn roll_reset_for_new_motions(&mut self) {
        let log = self.device.log();
        while self.motions_seen < log.len() {
            self.motions_seen += 1;
            if self.reset_at.is_none() {
                let rec = &self.device.log()[self.motions_seen - 1];
                if rec.end.is_none() {
                    // Estimate this motion's length from the device's own clocking.
                    let eta = self
                        .device
                        .next_event_time()
                        .map_or(Duration::ZERO, |t| t - self.now);
                    if let Some(after) = self.faults.reset_during(eta) {
                        self.reset_at = Some(self.now + after);
                    }
                }
            }
        }
    }

    fn flush_device_output(&mut self) {
        let out = self.device.take_output();
        if out.is_empty() || self.down_until.is_some() {
            return;
        }
        let out = self.faults.corrupt(&out);
        let extra = self.faults.delay();
        Self::queue(&mut self.to_host, self.now, &self.link, extra, &out);
    }

    /// The device's homed position of `axis` (`None` when not homed).
    pub fn position(&self, axis: Axis) -> Option<i32> {
        self.device.position(axis)
    }
}

/// A shared handle on a [`SimWorld`], for the transport and the test that inspects it.
#[derive(Debug, Clone)]
pub struct SimHandle(Arc<Mutex<SimWorld>>);

impl SimHandle {
    /// Wrap a world.
    pub fn new(world: SimWorld) -> Self {
        Self(Arc::new(Mutex::new(world)))
    }

    /// Lock it (a panic in another holder does not poison the simulation for inspection).
    pub fn lock(&self) -> MutexGuard<'_, SimWorld> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }
}
