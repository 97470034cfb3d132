//! Shared by the tests that run the `cac` binary in a child process under an address-space
//! limit (`setrlimit(RLIMIT_AS)` before `exec`, as `ulimit -v` does), so that a runaway stage
//! fails the test instead of taking the machine, and read the child's peak resident memory from
//! the kernel (`wait4`'s `ru_maxrss`). The peak is an upper bound: Linux carries the spawning
//! process's own peak (a test's, ~180 MB) into the child at `exec`, so a child that stays under
//! a bound here stays under it anywhere.
#![allow(dead_code)]

use std::io::Read;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::process::{Command, ExitStatus, Stdio};

/// A finished child: status, its outputs, peak resident bytes.
pub struct Run {
    pub status: ExitStatus,
    pub stdout: String,
    pub stderr: String,
    /// stdout followed by stderr.
    pub text: String,
    pub peak: u64,
}

/// Runs `cac args...` with `envs` under an address-space limit of `address_space` bytes.
pub fn run(args: &[&str], address_space: u64, envs: &[(&str, &str)]) -> Run {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_cac"));
    cmd.args(args)
        .envs(envs.iter().copied())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            let lim = libc::rlimit {
                rlim_cur: address_space,
                rlim_max: address_space,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    // Reaped by `wait4` below (which also reads its peak memory), not by `Child::wait`.
    #[allow(clippy::zombie_processes)]
    let mut child = cmd.spawn().expect("cac starts");
    let (mut so, mut se) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
    let t = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = so.read_to_string(&mut s);
        s
    });
    let mut stderr = String::new();
    let _ = se.read_to_string(&mut stderr);
    let stdout = t.join().unwrap();
    let mut status = 0i32;
    // SAFETY: an all-zero rusage is a valid value; wait4 fills it for our own child's pid.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = child.id() as libc::pid_t;
    // SAFETY: pid is our child, not yet reaped (Child::wait is never called on it).
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(r, pid, "wait4 on cac failed");
    Run {
        status: ExitStatus::from_raw(status),
        text: format!("{stdout}{stderr}"),
        stdout,
        stderr,
        peak: usage.ru_maxrss as u64 * 1024,
    }
}
