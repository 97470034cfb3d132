//! Seeded, configurable fault injection for the simulated serial link and device, and the counts
//! of what was injected.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Duration;

/// Probabilities and sizes of the faults to inject. All zero = a perfect link.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultConfig {
    /// Seed of the fault generator (same seed, same faults on a virtual clock).
    pub seed: u64,
    /// Probability that a byte (either direction) is lost.
    pub drop_byte: f64,
    /// Probability that a byte (either direction) is replaced by a random other byte.
    pub garble_byte: f64,
    /// Probability that a written chunk (either direction) is held back by up to `max_delay`.
    pub delay_chunk: f64,
    /// Longest extra delay.
    pub max_delay: Duration,
    /// Probability that the device reboots (watchdog) during a motion it just started, at a random
    /// time before the motion would end.
    pub reset_per_motion: f64,
    /// Probability that the link goes away when the host writes a line.
    pub disconnect_per_write: f64,
    /// How long the link stays away.
    pub disconnect_for: Duration,
    /// Probability that the device also rebooted when the link comes back (USB-powered board).
    pub reset_on_reconnect: f64,
}

impl FaultConfig {
    /// No faults.
    pub fn none() -> Self {
        Self {
            seed: 0,
            drop_byte: 0.0,
            garble_byte: 0.0,
            delay_chunk: 0.0,
            max_delay: Duration::from_millis(0),
            reset_per_motion: 0.0,
            disconnect_per_write: 0.0,
            disconnect_for: Duration::from_millis(500),
            reset_on_reconnect: 0.0,
        }
    }

    /// Only dropped bytes.
    pub fn drops(seed: u64, p: f64) -> Self {
        Self {
            seed,
            drop_byte: p,
            ..Self::none()
        }
    }

    /// Only garbled bytes.
    pub fn garbles(seed: u64, p: f64) -> Self {
        Self {
            seed,
            garble_byte: p,
            ..Self::none()
        }
    }

    /// Only delays (long enough to outlast a reply timeout now and then).
    pub fn delays(seed: u64, p: f64, max: Duration) -> Self {
        Self {
            seed,
            delay_chunk: p,
            max_delay: max,
            ..Self::none()
        }
    }

    /// Only spontaneous resets during motions.
    pub fn resets(seed: u64, p: f64) -> Self {
        Self {
            seed,
            reset_per_motion: p,
            ..Self::none()
        }
    }

    /// Only disconnects (half of them with a reboot of the device).
    pub fn disconnects(seed: u64, p: f64, down_for: Duration) -> Self {
        Self {
            seed,
            disconnect_per_write: p,
            disconnect_for: down_for,
            reset_on_reconnect: 0.5,
            ..Self::none()
        }
    }

    /// Every fault kind at once.
    pub fn mix(seed: u64) -> Self {
        Self {
            seed,
            drop_byte: 0.002,
            garble_byte: 0.002,
            delay_chunk: 0.03,
            max_delay: Duration::from_millis(400),
            reset_per_motion: 0.04,
            disconnect_per_write: 0.01,
            disconnect_for: Duration::from_millis(700),
            reset_on_reconnect: 0.5,
        }
    }
}

/// How many faults of each kind were injected.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FaultCounts {
    /// Bytes dropped.
    pub dropped: u64,
    /// Bytes garbled.
    pub garbled: u64,
    /// Chunks delayed.
    pub delayed: u64,
    /// Spontaneous device reboots (during motion, or on reconnect).
    pub resets: u64,
    /// Link disconnects.
    pub disconnects: u64,
}

impl FaultCounts {
    /// All faults together.
    pub fn total(&self) -> u64 {
        self.dropped + self.garbled + self.delayed + self.resets + self.disconnects
    }
}

impl std::fmt::Display for FaultCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} faults: {} dropped bytes, {} garbled bytes, {} delays, {} resets, {} disconnects",
            self.total(),
            self.dropped,
            self.garbled,
            self.delayed,
            self.resets,
            self.disconnects
        )
    }
}

/// Rolls the dice for one [`FaultConfig`].
#[derive(Debug)]
pub struct FaultInjector {
    cfg: FaultConfig,
    rng: ChaCha8Rng,
    counts: FaultCounts,
}

impl FaultInjector {
    /// A generator seeded from `cfg.seed`.
    pub fn new(cfg: FaultConfig) -> Self {
        Self {
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            cfg,
            counts: FaultCounts::default(),
        }
    }

    /// Its configuration.
    pub fn config(&self) -> &FaultConfig {
        &self.cfg
    }

    /// What was injected so far.
    pub fn counts(&self) -> FaultCounts {
        self.counts
    }

    fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.rng.random_bool(p.min(1.0))
    }

    /// Apply byte loss and corruption to a chunk in transit.
    pub fn corrupt(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::with_capacity(bytes.len());
        for &b in bytes {
            if self.chance(self.cfg.drop_byte) {
                self.counts.dropped += 1;
            } else if self.chance(self.cfg.garble_byte) {
                self.counts.garbled += 1;
                let other = b ^ self.rng.random_range(1..=255u8);
                out.push(other);
            } else {
                out.push(b);
            }
        }
        out
    }

    /// Extra delay for a chunk, if any.
    pub fn delay(&mut self) -> Duration {
        if self.chance(self.cfg.delay_chunk) {
            self.counts.delayed += 1;
            self.cfg.max_delay.mul_f64(self.rng.random_range(0.2..1.0))
        } else {
            Duration::ZERO
        }
    }

    /// Whether a motion of `eta` just started should be cut by a reboot, and after how long.
    pub(crate) fn reset_during(&mut self, eta: Duration) -> Option<Duration> {
        self.chance(self.cfg.reset_per_motion)
            .then(|| eta.mul_f64(self.rng.random_range(0.0..1.1)))
    }

    /// Whether a host write brings the link down, and for how long.
    pub fn disconnect(&mut self) -> Option<Duration> {
        self.chance(self.cfg.disconnect_per_write).then(|| {
            self.counts.disconnects += 1;
            self.cfg
                .disconnect_for
                .mul_f64(self.rng.random_range(0.5..1.5))
        })
    }

    /// Whether the device rebooted while the link was away.
    pub fn reset_on_reconnect(&mut self) -> bool {
        self.chance(self.cfg.reset_on_reconnect)
    }

    /// Add counts carried over from an earlier injector.
    pub fn add_counts(&mut self, c: FaultCounts) {
        self.counts.dropped += c.dropped;
        self.counts.garbled += c.garbled;
        self.counts.delayed += c.delayed;
        self.counts.resets += c.resets;
        self.counts.disconnects += c.disconnects;
    }

    /// Count a reboot that was injected.
    pub fn count_reset(&mut self) {
        self.counts.resets += 1;
    }
}
