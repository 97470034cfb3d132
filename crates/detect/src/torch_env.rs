//! libtorch's process-wide settings that cac picks at the edge (`main`), and the benchmarks'
//! Python peers (PyTorch, onnxruntime) run as their users run them, without those settings.

use std::ffi::OsStr;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};

/// The variable libtorch's CPU allocator reads once, at its first allocation: set, it advises
/// transparent huge pages (`madvise(MADV_HUGEPAGE)`) for every block of 2 MiB or more.
pub const TORCH_HUGE_PAGES_VAR: &str = "THP_MEM_ALLOC_ENABLE";

static HUGE_PAGES_SET_HERE: AtomicBool = AtomicBool::new(false);

/// Asks libtorch's CPU allocator for transparent huge pages unless the user's environment already
/// says (`THP_MEM_ALLOC_ENABLE`). Each op's output is fresh memory, so with 4 KiB pages the
/// detectors spent a tenth of their time in page faults (3.1 million in a `cac bench detect` on
/// libtorch, 0.38 million with huge pages; CenterNet and NanoDet forward+backward 5–9 % faster,
/// the attack's iteration 6 %; docs/detectors.md). Flex allocates through Rust's allocator, which
/// the binary tunes apart. Nothing else changes without the `tch` feature.
///
/// # Safety
/// It sets a process environment variable: call it before any other thread exists (first thing
/// in `main`), as `std::env::set_var` requires.
pub unsafe fn prefer_huge_pages() {
    if std::env::var_os(TORCH_HUGE_PAGES_VAR).is_none() {
        std::env::set_var(TORCH_HUGE_PAGES_VAR, "1");
        HUGE_PAGES_SET_HERE.store(true, Ordering::Relaxed);
    }
}

/// A Python peer (PyTorch, onnxruntime) as its users run it: without the huge-page setting cac
/// gave its own libtorch, unless the user set it (then both have it).
pub fn peer_command(python: impl AsRef<OsStr>) -> Command {
    let mut c = Command::new(python);
    if HUGE_PAGES_SET_HERE.load(Ordering::Relaxed) {
        c.env_remove(TORCH_HUGE_PAGES_VAR);
    }
    c
}
