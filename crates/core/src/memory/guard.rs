//! The memory guard under the estimates: [`GuardedAllocator`], a counting wrapper over the
//! system allocator that the binary installs as its `#[global_allocator]`. It counts the bytes
//! the process holds on the heap and, once [`super::set_process_budget`] has armed it, stops the
//! process with one line naming the current [`stage`], what makes its work smaller, the budget
//! and `--max-memory` when an allocation would take the heap over the budget (exit status 1;
//! files already written stay as they are: every writer renames a finished file into place, and
//! a temporary being streamed is removed, [`remove_on_stop`]).

use super::write_human;
use std::alloc::{GlobalAlloc, Layout, System};
use std::fmt;
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicUsize, Ordering};
use std::sync::Mutex;

/// Arms the guard with a budget of `bytes` (0 disarms it).
pub(super) fn arm(bytes: u64) {
    GUARD_LIMIT.store(
        usize::try_from(bytes).unwrap_or(usize::MAX),
        Ordering::Relaxed,
    );
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

#[cfg(test)]
mod tests {
    use super::super::{GIB, MIB};
    use super::*;

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
}
