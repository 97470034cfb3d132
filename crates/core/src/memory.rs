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
//! Under the estimates lies a guard no stage can slip past: [`GuardedAllocator`], a counting
//! wrapper over the system allocator that the binary installs as its `#[global_allocator]`.
//! It counts the bytes the process holds on the heap and, once [`set_process_budget`] has armed
//! it, stops the process with one line naming the current [`stage`], the budget and
//! `--max-memory` when an allocation would take the heap over the budget (exit status 1; files
//! already written stay as they are: every writer renames a finished file into place).

use std::alloc::{GlobalAlloc, Layout, System};
use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicU64, AtomicUsize, Ordering};
use std::sync::Mutex;

/// The process's budget in bytes (0: the default).
static PROCESS_BUDGET: AtomicU64 = AtomicU64::new(0);

/// Sets the budget that [`MemoryBudget::current`] returns (the binary does it once, at start),
/// and arms the [`GuardedAllocator`] with it where the binary installed one.
pub fn set_process_budget(b: MemoryBudget) {
    PROCESS_BUDGET.store(b.bytes, Ordering::Relaxed);
    GUARD_LIMIT.store(
        usize::try_from(b.bytes).unwrap_or(usize::MAX),
        Ordering::Relaxed,
    );
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
fn write_human(w: &mut impl fmt::Write, bytes: u64) -> fmt::Result {
    let b = bytes as f64;
    if bytes >= GIB {
        write!(w, "{:.1} GB", b / GIB as f64)
    } else if bytes >= MIB {
        write!(w, "{:.0} MB", b / MIB as f64)
    } else {
        write!(w, "{:.0} KB", b / 1024.0)
    }
}

/// Bytes the process holds on the heap (sizes asked for), counted by the [`GuardedAllocator`].
static GUARD_LIVE: AtomicUsize = AtomicUsize::new(0);
/// The most [`GUARD_LIVE`] has been.
static GUARD_PEAK: AtomicUsize = AtomicUsize::new(0);
/// The guard's limit in bytes (0: not armed).
static GUARD_LIMIT: AtomicUsize = AtomicUsize::new(0);
/// Set when the guard has stopped the process: allocations then pass while it exits.
static GUARD_FIRED: AtomicBool = AtomicBool::new(false);
/// The current stage ([`stage`]); null: none set.
static STAGE: AtomicPtr<Stage> = AtomicPtr::new(std::ptr::null_mut());
/// Every stage set so far, each stored once where [`STAGE`] can point at it.
static STAGE_NAMES: Mutex<Vec<&'static Stage>> = Mutex::new(Vec::new());

/// A stage as the guard names it: its name and what makes its work smaller.
#[derive(PartialEq)]
struct Stage {
    name: &'static str,
    knob: &'static str,
}

/// Unfinished output files (temporaries being written) that the guard removes when it stops
/// the process, so that a stop leaves no half-written file behind.
static ON_STOP: Mutex<Vec<std::path::PathBuf>> = Mutex::new(Vec::new());

/// Registers `path` (a temporary being written) for removal should the guard stop the process
/// before the returned value is dropped (on drop it is forgotten again).
pub fn remove_on_stop(path: &std::path::Path) -> RemoveOnStop {
    let p = path.to_path_buf();
    ON_STOP
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .push(p.clone());
    RemoveOnStop(p)
}

/// See [`remove_on_stop`].
pub struct RemoveOnStop(std::path::PathBuf);

impl Drop for RemoveOnStop {
    fn drop(&mut self) {
        let mut list = ON_STOP.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = list.iter().position(|p| *p == self.0) {
            list.swap_remove(i);
        }
    }
}

/// The guard's cleanup: removes the registered temporaries (`remove_file` converts a path under
/// 384 bytes on the stack, allocating nothing); skipped when the list is locked by the thread
/// that hit the budget.
fn remove_unfinished() {
    if let Ok(list) = ON_STOP.try_lock() {
        for p in list.iter() {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// Names the stage now running (`"paste-on sheets"`, `"bake"`), for the guard's message.
pub fn stage(name: &'static str) {
    stage_with(name, "make the stage's work smaller");
}

/// [`stage`], with what makes its work smaller (`"lower --dpi"`), which the guard's message
/// gives before `--max-memory`.
pub fn stage_with(name: &'static str, knob: &'static str) {
    let want = Stage { name, knob };
    let mut names = STAGE_NAMES.lock().unwrap_or_else(|e| e.into_inner());
    let slot = match names.iter().find(|n| ***n == want) {
        Some(n) => *n,
        None => {
            let n: &'static Stage = Box::leak(Box::new(want));
            names.push(n);
            n
        }
    };
    STAGE.store(slot as *const Stage as *mut Stage, Ordering::Relaxed);
}

/// The stage last named with [`stage`] (`"cac"` before any).
pub fn current_stage() -> &'static str {
    current().name
}

fn current() -> &'static Stage {
    let p = STAGE.load(Ordering::Relaxed);
    if p.is_null() {
        &Stage {
            name: "cac",
            knob: "make the command's work smaller",
        }
    } else {
        // Safety: STAGE only ever points at a leaked `Stage` of STAGE_NAMES.
        unsafe { &*p }
    }
}

/// Bytes on the heap now and at most so far, as the [`GuardedAllocator`] counts them (0 where
/// the binary did not install it).
pub fn heap_bytes() -> (u64, u64) {
    (
        GUARD_LIVE.load(Ordering::Relaxed) as u64,
        GUARD_PEAK.load(Ordering::Relaxed) as u64,
    )
}

/// The memory guard: the system allocator, counting the bytes held. Once armed (by
/// [`set_process_budget`]), an allocation that would take the heap over the budget stops the
/// process with one line on stderr and exit status 1, instead of an allocation abort or the
/// kernel's OOM killer; so does an allocation the system refuses (an address-space limit below
/// the budget). Relaxed atomics only: one `fetch_add` per allocation and one `fetch_sub` per
/// free. Install it in a binary with `#[global_allocator] static A: GuardedAllocator =
/// GuardedAllocator;`.
pub struct GuardedAllocator;

impl GuardedAllocator {
    /// Counts `size` more bytes; over the armed limit, stops the process.
    #[inline]
    fn take(size: usize) {
        let live = GUARD_LIVE.fetch_add(size, Ordering::Relaxed) + size;
        if live > GUARD_PEAK.load(Ordering::Relaxed) {
            GUARD_PEAK.fetch_max(live, Ordering::Relaxed);
            let limit = GUARD_LIMIT.load(Ordering::Relaxed);
            if limit != 0 && live > limit {
                stop(Stop::OverBudget, size, live, limit);
            }
        }
    }

    #[inline]
    fn give(size: usize) {
        GUARD_LIVE.fetch_sub(size, Ordering::Relaxed);
    }

    /// What the system returned; null (refused) stops the process when the guard is armed.
    #[inline]
    fn got(p: *mut u8, size: usize) -> *mut u8 {
        if p.is_null() {
            Self::give(size);
            let limit = GUARD_LIMIT.load(Ordering::Relaxed);
            if limit != 0 {
                stop(
                    Stop::Refused,
                    size,
                    GUARD_LIVE.load(Ordering::Relaxed),
                    limit,
                );
            }
        }
        p
    }
}

unsafe impl GlobalAlloc for GuardedAllocator {
    #[inline]
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        Self::take(layout.size());
        Self::got(System.alloc(layout), layout.size())
    }

    #[inline]
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        Self::take(layout.size());
        Self::got(System.alloc_zeroed(layout), layout.size())
    }

    #[inline]
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        Self::give(layout.size());
    }

    #[inline]
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let old = layout.size();
        if new_size > old {
            Self::take(new_size - old);
        }
        let p = System.realloc(ptr, layout, new_size);
        if p.is_null() {
            if new_size > old {
                Self::got(p, new_size - old);
            }
            return p; // the old block is still held
        }
        if new_size < old {
            Self::give(old - new_size);
        }
        p
    }
}

/// Why the guard stops the process.
#[derive(Clone, Copy)]
enum Stop {
    OverBudget,
    Refused,
}

/// Writes the guard's one line and exits with status 1. Runs inside the allocator: it formats
/// into a stack buffer and writes it straight to file descriptor 2, allocating nothing; the
/// allocations other threads (and the exit itself) make meanwhile pass unchecked.
#[cold]
#[inline(never)]
fn stop(why: Stop, size: usize, live: usize, limit: usize) {
    if GUARD_FIRED.swap(true, Ordering::Relaxed) {
        return;
    }
    let mut line = StackLine::default();
    let _ = guard_line(&mut line, why, size as u64, live as u64, limit as u64);
    line.write_to_stderr();
    remove_unfinished();
    std::process::exit(1);
}

/// The guard's message (see `docs/memory.md`).
fn guard_line(w: &mut impl fmt::Write, why: Stop, size: u64, live: u64, limit: u64) -> fmt::Result {
    let stage = current();
    write!(w, "error: the {} stage ", stage.name)?;
    match why {
        Stop::OverBudget => w.write_str("went over the memory budget of ")?,
        Stop::Refused => w.write_str("ran out of system memory under the memory budget of ")?,
    }
    write_human(w, limit)?;
    w.write_str(" (at ")?;
    write_human(w, live)?;
    w.write_str(", asking for ")?;
    write_human(w, size)?;
    w.write_str(" more): ")?;
    match why {
        Stop::OverBudget => write!(
            w,
            "stopped before the machine runs out; {}, or raise --max-memory",
            stage.knob
        )?,
        Stop::Refused => write!(
            w,
            "the system (or an address-space limit) gives less than the budget; lower \
             --max-memory to what the machine has, or {}",
            stage.knob
        )?,
    }
    w.write_str("; files already written are kept\n")
}

/// A line formatted without allocating (cut at 512 bytes).
struct StackLine {
    buf: [u8; 512],
    len: usize,
}

impl Default for StackLine {
    fn default() -> Self {
        StackLine {
            buf: [0; 512],
            len: 0,
        }
    }
}

impl fmt::Write for StackLine {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let n = s.len().min(self.buf.len() - self.len);
        self.buf[self.len..self.len + n].copy_from_slice(&s.as_bytes()[..n]);
        self.len += n;
        Ok(())
    }
}

impl StackLine {
    /// Straight to file descriptor 2 (no lock, no buffer, no allocation).
    fn write_to_stderr(&self) {
        use std::io::Write;
        #[cfg(unix)]
        {
            use std::os::fd::FromRawFd;
            // Safety: fd 2 is the process's stderr; ManuallyDrop never closes it.
            let mut f = std::mem::ManuallyDrop::new(unsafe { std::fs::File::from_raw_fd(2) });
            let _ = f.write_all(&self.buf[..self.len]);
        }
        #[cfg(not(unix))]
        let _ = std::io::stderr().write_all(&self.buf[..self.len]);
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
    fn the_guard_line_names_the_stage_budget_and_knob_without_allocating() {
        stage("bake");
        stage_with("paste-on sheets", "lower --dpi");
        assert_eq!(current_stage(), "paste-on sheets");
        stage("bake");
        stage_with("paste-on sheets", "lower --dpi");
        assert_eq!(STAGE_NAMES.lock().unwrap().len(), 2);
        let mut line = StackLine::default();
        guard_line(
            &mut line,
            Stop::OverBudget,
            26 * MIB,
            4 * GIB + MIB,
            4 * GIB,
        )
        .unwrap();
        let text = std::str::from_utf8(&line.buf[..line.len]).unwrap();
        assert!(
            text.starts_with(
                "error: the paste-on sheets stage went over the memory budget of 4.0 GB (at \
                 4.0 GB, asking for 26 MB more)"
            ),
            "{text}"
        );
        assert!(
            text.contains("runs out; lower --dpi, or raise --max-memory; files already written")
                && text.ends_with("kept\n"),
            "{text}"
        );
        assert_eq!(text.lines().count(), 1);
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
