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
