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

fn main() {
    tune_allocator();
    let args = cli::Cli::parse();
    if let Err(e) = cli::run(args) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
