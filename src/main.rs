//! The `cac` command line: one small file per subcommand under `cli/`; each parses its
//! arguments, calls the library and prints. The compute device is chosen here, at the edge.

mod cli;

use clap::Parser;

/// The CPU backend allocates every op's output (megabytes per activation) and frees its inputs.
/// glibc serves blocks over its dynamic mmap threshold with fresh mappings and returns freed
/// heap tops to the system, so every op paid page faults and TLB shootdowns: about a quarter of
/// CenterNet's forward time and a third of its backward (docs/detectors.md, "Speed"). Keep such
/// blocks in the heap for reuse instead.
fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    unsafe {
        // 32 MiB is the largest mmap threshold glibc accepts on 64-bit targets.
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

/// `cac detect ... | head`: once the reader of standard output is gone, `println!` panics with
/// "failed printing to stdout: Broken pipe". Exit quietly with the status a filter killed by
/// SIGPIPE has (128 + 13) instead of printing a panic. Restoring SIGPIPE's default action would
/// do the same, but it would also kill cac without a word where it writes video frames into an
/// ffmpeg that exited, where the write error now says what happened.
fn quiet_when_stdout_closes() {
    #[cfg(unix)]
    let epipe = format!("(os error {})", libc::EPIPE);
    #[cfg(not(unix))]
    let epipe = String::from("\u{0}never");
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let p = info.payload();
        let msg = p
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| p.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.starts_with("failed printing to stdout") && msg.contains(&epipe) {
            std::process::exit(141); // 128 + SIGPIPE (13)
        }
        default(info)
    }));
}

/// The memory guard under every stage's estimate: counts the heap and stops the process with
/// one line when it would go over `--max-memory` (docs/memory.md).
#[global_allocator]
static GUARD: cac::memory::GuardedAllocator = cac::memory::GuardedAllocator;

fn main() {
    tune_allocator();
    // Safety: no other thread exists yet (it sets a process environment variable).
    #[cfg(feature = "tch")]
    unsafe {
        cac::detect::torch_env::prefer_huge_pages()
    };
    quiet_when_stdout_closes();
    // Per-op timings of every detector graph run, on stderr (docs/detectors.md).
    cac::detect::exec::set_profiling(std::env::var_os("CAC_PROFILE_GRAPH").is_some());
    // Where fetched models are cached (default: the user's cache folder).
    if let Some(d) = std::env::var_os("CAC_CACHE_DIR").filter(|d| !d.is_empty()) {
        cac::detect::fetch::set_cache_root(d.into());
    }
    let args = cli::Cli::parse();
    // onnxruntime for users' ONNX detectors' forward passes that need no gradient: the path of
    // its shared library, `auto` for the one of python3's onnxruntime package, or `off`.
    // After parsing, so that `--help` answers whatever the variable holds.
    if let Some(v) = std::env::var_os("CAC_ONNXRUNTIME").filter(|v| !v.is_empty() && v != "off") {
        match cac::detect::onnx::runtime::enable(&v.to_string_lossy()) {
            Ok(lib) => eprintln!(
                "ONNX detectors' forward passes without gradient run on onnxruntime ({})",
                lib.display()
            ),
            Err(e) => {
                eprintln!("error: CAC_ONNXRUNTIME: {e:#}");
                std::process::exit(2);
            }
        }
    }
    if let Err(e) = cli::run(args) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
