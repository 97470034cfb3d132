//! Motion profiles of one simulated axis: a trapezoidal (or triangular) move from speed and
//! acceleration, and a controlled deceleration to rest for `STOP`.

/// One motion segment, positions in axis units (m° or µm), times in seconds from its start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Profile {
    /// Rest-to-rest move from `from` to `to` with cruise speed `v` and acceleration `a`.
    Trapezoid {
        /// Start position.
        from: f64,
        /// End position.
        to: f64,
        /// Cruise speed (> 0), units/s.
        v: f64,
        /// Acceleration (> 0), units/s².
        a: f64,
    },
    /// Deceleration from `from` at speed `v0` (signed) with `a` until rest.
    Decel {
        /// Start position.
        from: f64,
        /// Signed start velocity.
        v0: f64,
        /// Deceleration (> 0).
        a: f64,
    },
}

impl Profile {
    /// Total duration in seconds.
    pub fn duration(&self) -> f64 {
        match *self {
            Profile::Trapezoid { from, to, v, a } => {
                let d = (to - from).abs();
                if d == 0.0 {
                    0.0
                } else if d >= v * v / a {
                    d / v + v / a
                } else {
                    2.0 * (d / a).sqrt()
                }
            }
            Profile::Decel { v0, a, .. } => v0.abs() / a,
        }
    }

    /// Where the segment ends.
    pub fn end(&self) -> f64 {
        match *self {
            Profile::Trapezoid { to, .. } => to,
            Profile::Decel { from, v0, a } => from + v0.signum() * v0 * v0 / (2.0 * a),
        }
    }

    /// Position and signed velocity `t` seconds after the start (clamped to the segment).
    pub fn at(&self, t: f64) -> (f64, f64) {
        let total = self.duration();
        let t = t.clamp(0.0, total);
        match *self {
            Profile::Trapezoid { from, to, v, a } => {
                let d = (to - from).abs();
                let dir = (to - from).signum();
                if d == 0.0 {
                    return (from, 0.0);
                }
                // Peak speed (lower than v for a triangular profile).
                let vp = v.min((d * a).sqrt());
                let ta = vp / a;
                let (s, vel) = if t < ta {
                    (0.5 * a * t * t, a * t)
                } else if t <= total - ta {
                    (0.5 * a * ta * ta + vp * (t - ta), vp)
                } else {
                    let r = total - t;
                    (d - 0.5 * a * r * r, a * r)
                };
                (from + dir * s.min(d), dir * vel)
            }
            Profile::Decel { from, v0, a } => {
                let dir = v0.signum();
                let s = v0.abs() * t - 0.5 * a * t * t;
                (from + dir * s, dir * (v0.abs() - a * t))
            }
        }
    }
}

/// Motion time in whole milliseconds, rounded up (the `ETA` a device reports).
pub fn eta_ms(p: &Profile) -> u32 {
    let ms = (p.duration() * 1000.0).ceil();
    if ms >= f64::from(u32::MAX) {
        u32::MAX
    } else {
        ms as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_and_triangle() {
        // 90° at 90°/s, 180°/s²: accelerate 0.5 s (22.5°), cruise 0.5 s, decelerate 0.5 s.
        let p = Profile::Trapezoid {
            from: 0.0,
            to: 90_000.0,
            v: 90_000.0,
            a: 180_000.0,
        };
        assert!((p.duration() - 1.5).abs() < 1e-9);
        assert_eq!(eta_ms(&p), 1500);
        let (x, v) = p.at(0.5);
        assert!((x - 22_500.0).abs() < 1e-6 && (v - 90_000.0).abs() < 1e-6);
        assert_eq!(p.at(9.0), (90_000.0, 0.0));
        // Short move never reaches cruise speed.
        let t = Profile::Trapezoid {
            from: 10.0,
            to: 0.0,
            v: 90_000.0,
            a: 180_000.0,
        };
        assert!((t.duration() - 2.0 * (10.0f64 / 180_000.0).sqrt()).abs() < 1e-12);
        let (mid, vm) = t.at(t.duration() / 2.0);
        assert!((mid - 5.0).abs() < 1e-6 && vm < 0.0);
    }

    #[test]
    fn deceleration() {
        let d = Profile::Decel {
            from: 100.0,
            v0: -20.0,
            a: 10.0,
        };
        assert!((d.duration() - 2.0).abs() < 1e-12);
        assert!((d.end() - 80.0).abs() < 1e-12);
        assert!((d.at(2.0).0 - 80.0).abs() < 1e-12);
    }
}
