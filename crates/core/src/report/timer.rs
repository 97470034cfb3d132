//! The benchmarks' one timer (the measuring code of `cac bench …` in the library and the
//! binary uses only this): the fastest of some timed runs after untimed warm-up runs (on a
//! shared machine the least disturbed figure, and what the reference runners report too), a
//! stopwatch for one-off spans, and the median for per-iteration times that a run logs itself.

use anyhow::Result;
use std::time::Instant;

/// Calls `f` `warmup` times untimed, then `runs` times timed; returns the fastest timed run in
/// milliseconds (infinity when `runs` is 0) and the last call's output. `f` runs at least once.
pub fn fastest_ms<T>(
    warmup: usize,
    runs: usize,
    mut f: impl FnMut() -> Result<T>,
) -> Result<(f64, T)> {
    let mut out = None;
    for _ in 0..warmup {
        out = Some(f()?);
    }
    let mut best = f64::INFINITY;
    for _ in 0..runs {
        let s = Stopwatch::start();
        out = Some(f()?);
        best = best.min(s.ms());
    }
    let out = match out {
        Some(o) => o,
        None => f()?,
    };
    Ok((best, out))
}

/// Fastest ms of `runs` timed calls of `f`, after one warm-up call.
pub fn time(runs: usize, f: impl FnMut() -> Result<()>) -> Result<f64> {
    Ok(fastest_ms(1, runs, f)?.0)
}

/// Time since it was started.
#[derive(Clone, Copy, Debug)]
pub struct Stopwatch(Instant);

impl Stopwatch {
    pub fn start() -> Self {
        Stopwatch(Instant::now())
    }
    pub fn secs(&self) -> f64 {
        self.0.elapsed().as_secs_f64()
    }
    pub fn ms(&self) -> f64 {
        self.secs() * 1e3
    }
}

/// The median of `v` (the upper one of an even count); `v` must not be empty. For the
/// per-iteration times a training run logs.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Seconds as `1h 2m 3s` or `2m 3s` (rounded to the second).
pub fn format_duration(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    let (h, m, sec) = (s / 3600, s / 60 % 60, s % 60);
    if h > 0 {
        format!("{h}h {m}m {sec}s")
    } else {
        format!("{m}m {sec}s")
    }
}

/// A duration as written by people and slicers, in seconds: parts of a number and a unit
/// (`d`, `h`, `m`, `s`), with or without spaces between them (`10m`, `1h30m`, `1d 2h 3m 4s`);
/// `None` for anything else, a bare number or a negative time.
pub fn parse_duration(s: &str) -> Option<f64> {
    let mut total = 0.0;
    let mut rest = s.trim();
    if rest.is_empty() {
        return None;
    }
    while !rest.is_empty() {
        let at = rest.find(|c: char| c.is_ascii_alphabetic())?;
        let v: f64 = rest[..at].trim().parse().ok()?;
        let unit = rest[at..].chars().next()?;
        total += v * match unit {
            'd' => 86400.0,
            'h' => 3600.0,
            'm' => 60.0,
            's' => 1.0,
            _ => return None,
        };
        rest = rest[at + 1..].trim_start();
    }
    (total >= 0.0 && total.is_finite()).then_some(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_as_people_and_slicers_write_them() {
        assert_eq!(parse_duration("3h 33m 16s"), Some(12796.0));
        assert_eq!(parse_duration("1d 0h 0m 1s"), Some(86401.0));
        assert_eq!(parse_duration("10m"), Some(600.0));
        assert_eq!(parse_duration("1h30m"), Some(5400.0));
        assert_eq!(parse_duration("2.5m"), Some(150.0));
        for bad in ["-2147483648s", "soon", "600", "", "10x", "m"] {
            assert_eq!(parse_duration(bad), None, "{bad:?}");
        }
        assert_eq!(format_duration(12796.0), "3h 33m 16s");
        assert_eq!(format_duration(59.6), "1m 0s");
    }
}
