//! The memory budget: a stage whose memory grows with its work (the bake's triangles, the
//! solid's grid, the rendered pixels, the detector's activations) estimates the bytes it will
//! hold *before* it allocates them and refuses, naming the knob that makes the work smaller,
//! when the estimate is over the budget. A user on a laptop gets an error, never an allocation
//! abort or the kernel's OOM killer.
//!
//! The budget is 4 GiB by default. The `cac` binary sets the process's budget once, at the edge,
//! from its global `--max-memory` flag ([`set_process_budget`], like the compute device);
//! library code reads it with [`MemoryBudget::current`] or takes one as a parameter. Estimates
//! are built from each stage's own data structures and calibrated against measured peaks (see
//! `docs/memory.md`). This module also reads the process's peak resident memory (Linux `VmHWM`)
//! for the benchmarks' "peak MB" columns.
//!
//! Under the estimates lies a guard no stage can slip past ([`GuardedAllocator`], in
//! `memory/guard.rs`: the counting global allocator that stops the process with one line when
//! the heap would go over the budget).

mod guard;

pub use guard::{
    current_stage, heap_bytes, remove_on_stop, stage, stage_with, GuardedAllocator, RemoveOnStop,
};

use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicU64, Ordering};

/// The process's budget in bytes (0: the default).
static PROCESS_BUDGET: AtomicU64 = AtomicU64::new(0);

/// Sets the budget that [`MemoryBudget::current`] returns (the binary does it once, at start),
/// and arms the [`GuardedAllocator`] with it where the binary installed one.
pub fn set_process_budget(b: MemoryBudget) {
    PROCESS_BUDGET.store(b.bytes, Ordering::Relaxed);
    guard::arm(b.bytes);
}

/// Bytes in one MiB / GiB.
pub(crate) const MIB: u64 = 1 << 20;
pub(crate) const GIB: u64 = 1 << 30;

/// The most memory a job may plan to hold, in bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct MemoryBudget {
    pub bytes: u64,
}

impl Default for MemoryBudget {
    fn default() -> Self {
        MemoryBudget { bytes: 4 * GIB }
    }
}

/// An estimate over the budget: what would need how much, and what to turn down.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "{what} would need about {need} of memory, over the memory budget of {budget}: {knob} (or raise --max-memory)",
    need = human(*.need),
    budget = human(*.budget)
)]
pub struct OverBudget {
    pub what: String,
    pub need: u64,
    pub budget: u64,
    pub knob: String,
}

impl MemoryBudget {
    pub fn new(bytes: u64) -> Self {
        MemoryBudget { bytes }
    }

    /// The process's budget: what [`set_process_budget`] set, else the default (4 GiB).
    pub fn current() -> Self {
        match PROCESS_BUDGET.load(Ordering::Relaxed) {
            0 => MemoryBudget::default(),
            bytes => MemoryBudget { bytes },
        }
    }

    /// `Ok` when `need` bytes fit the budget; otherwise an [`OverBudget`] naming `what` is being
    /// estimated and the `knob` that makes it smaller.
    pub fn check(&self, what: &str, need: u64, knob: &str) -> Result<(), OverBudget> {
        if need <= self.bytes {
            Ok(())
        } else {
            Err(OverBudget {
                what: what.to_string(),
                need,
                budget: self.bytes,
                knob: knob.to_string(),
            })
        }
    }

    /// How many items of `bytes_each` fit after `fixed` bytes are set aside (at least 1).
    pub fn items(&self, fixed: u64, bytes_each: u64) -> u64 {
        (self.bytes.saturating_sub(fixed) / bytes_each.max(1)).max(1)
    }
}

impl fmt::Display for MemoryBudget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&human(self.bytes))
    }
}

/// Parses `4G`, `4GB`, `4GiB`, `512M`, `800MB`, `1.5G`, `1T` or a plain number of bytes (units
/// are binary: `1G` is 2^30 bytes).
impl FromStr for MemoryBudget {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        let split = t
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(t.len());
        let (num, unit) = t.split_at(split);
        let x: f64 = num.parse().map_err(|_| {
            format!("memory size '{s}' is not a number with a unit (e.g. 4G, 512M)")
        })?;
        let scale = match unit.trim().to_ascii_uppercase().as_str() {
            "" | "B" => 1,
            "K" | "KB" | "KIB" => 1 << 10,
            "M" | "MB" | "MIB" => MIB,
            "G" | "GB" | "GIB" => GIB,
            "T" | "TB" | "TIB" => 1 << 40,
            u => {
                return Err(format!(
                    "memory size '{s}': unknown unit '{u}' (use K, M, G or T)"
                ))
            }
        };
        let bytes = x * scale as f64;
        if !(bytes.is_finite() && bytes >= 64.0 * MIB as f64) {
            return Err(format!("memory size '{s}' is too small: give at least 64M"));
        }
        Ok(MemoryBudget {
            bytes: bytes.min(u64::MAX as f64) as u64,
        })
    }
}

/// `1.5 GB`, `320 MB`, `12 KB` (binary units, one decimal above 1 GB).
pub fn human(bytes: u64) -> String {
    let mut s = String::new();
    let _ = write_human(&mut s, bytes);
    s
}

/// [`human`] into any writer (the guard's failure path writes into a stack buffer).
pub(crate) fn write_human(w: &mut impl fmt::Write, bytes: u64) -> fmt::Result {
    let b = bytes as f64;
    if bytes >= GIB {
        write!(w, "{:.1} GB", b / GIB as f64)
    } else if bytes >= MIB {
        write!(w, "{:.0} MB", b / MIB as f64)
    } else {
        write!(w, "{:.0} KB", b / 1024.0)
    }
}

/// Peak resident set size of this process (`VmHWM`, Linux), `None` where unknown.
pub(crate) fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let kb: u64 = s
        .lines()
        .find(|l| l.starts_with("VmHWM:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()?;
    Some(kb * 1024)
}

/// Peak resident memory in MB (0 where unknown), for the benchmarks' tables.
pub fn peak_rss_mb() -> f64 {
    peak_rss_bytes().map_or(0.0, |b| b as f64 / MIB as f64)
}

/// Resets the peak so that the next [`peak_rss_bytes`] measures from now (Linux: writing 5 to
/// `/proc/self/clear_refs`). Returns whether it could.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_in_binary_units_and_bad_ones_are_refused() {
        let p = |s: &str| s.parse::<MemoryBudget>().map(|b| b.bytes);
        assert_eq!(p("4G"), Ok(4 * GIB));
        assert_eq!(p("4GiB"), Ok(4 * GIB));
        assert_eq!(p("512m"), Ok(512 * MIB));
        assert_eq!(p("1.5G"), Ok(3 * GIB / 2));
        assert_eq!(p("134217728"), Ok(128 * MIB));
        assert!(p("lots").unwrap_err().contains("not a number"));
        assert!(p("4Q").unwrap_err().contains("unknown unit"));
        assert!(p("1M").unwrap_err().contains("too small"));
        assert!(p("").is_err());
    }

    #[test]
    fn an_estimate_over_the_budget_names_the_work_and_the_knob() {
        let b = MemoryBudget::new(GIB);
        assert!(b.check("the bake", GIB, "x").is_ok());
        let e = b
            .check("the bake", 3 * GIB, "raise --max-edge-texels")
            .unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains("the bake would need about 3.0 GB"), "{msg}");
        assert!(msg.contains("budget of 1.0 GB"), "{msg}");
        assert!(msg.contains("raise --max-edge-texels"), "{msg}");
        assert!(msg.contains("--max-memory"), "{msg}");
        assert_eq!(b.items(GIB / 2, 1024), GIB / 2 / 1024);
        assert_eq!(b.items(2 * GIB, 1024), 1);
    }

    #[test]
    fn the_peak_is_read_and_grows_with_what_is_touched() {
        let Some(before) = peak_rss_bytes() else {
            return; // not Linux
        };
        let v = vec![1u8; 64 * MIB as usize];
        std::hint::black_box(&v);
        let after = peak_rss_bytes().unwrap();
        assert!(after >= before.max(64 * MIB), "{before} -> {after}");
    }
}
