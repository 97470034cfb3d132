//! Support for the tests of the compiled AVR firmware (`firmware-protocol/avr/`): builds the
//! firmware and the simavr harness `ttsim` with make, runs the harness (the firmware as an
//! ATmega328P at 16 MHz, its UART on a pseudo-terminal), reads its pin counters, and can put a
//! fault-injecting link (cac's `FaultInjector`) between the harness's pty and the driver.

#![allow(dead_code)]

#[path = "../support/mod.rs"]
pub mod support;

use cac::physical::{Transport, TurntableConfig};
use cac::sim::{FaultConfig, FaultCounts, FaultInjector};
use serialport::{SerialPort, TTYPort};
use std::collections::{HashMap, VecDeque};
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Steps per table revolution and per rail mm in `config.h` (checked against HELLO/moves).
pub const TABLE_STEPS_PER_REV: i64 = 12_800;
pub const RAIL_STEPS_PER_MM: i64 = 80;

/// Tests share two CPU cores with everything else: one emulator at a time.
pub static SERIAL: Mutex<()> = Mutex::new(());

pub fn avr_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-protocol/avr")
}

/// Built artefacts.
#[derive(Debug, Clone)]
pub struct Built {
    pub elf: PathBuf,
    pub ttsim: PathBuf,
    pub build: PathBuf,
}

/// `None` after tests/support's [`support::missing`] (a failure under `CI=true`).
fn missing(what: &str) -> Option<Built> {
    support::missing(
        what,
        "the AVR firmware tests need gcc-avr, avr-libc, simavr, libsimavr-dev and libelf-dev \
         (apt-get install gcc-avr avr-libc simavr libsimavr-dev libelf-dev)",
    );
    None
}

fn make(dir: &Path, build: &Path, target: &str) -> Result<String, String> {
    let out = Command::new("make")
        .arg("-C")
        .arg(dir)
        .arg(format!("BUILD={}", build.display()))
        .arg(target)
        .output()
        .map_err(|e| format!("cannot run make: {e}"))?;
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    if out.status.success() {
        Ok(text)
    } else {
        Err(format!(
            "make {target} in {} failed:\n{text}",
            dir.display()
        ))
    }
}

/// Build the firmware (`make`), the harness (`make sim`) once per test process. `None` (after a
/// SKIP message) when the tools are missing, except under `CI=true` where that fails the test.
pub fn built() -> Option<Built> {
    static B: OnceLock<Option<Built>> = OnceLock::new();
    B.get_or_init(|| {
        for tool in ["make", "avr-gcc", "pkg-config"] {
            if Command::new("which")
                .arg(tool)
                .output()
                .map_or(true, |o| !o.status.success())
            {
                return missing(&format!("`{tool}`"));
            }
        }
        if !Path::new("/usr/include/simavr/sim_avr.h").exists()
            && !Command::new("pkg-config")
                .args(["--exists", "simavr"])
                .status()
                .is_ok_and(|s| s.success())
        {
            return missing("simavr's headers (libsimavr-dev)");
        }
        let build = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("avr-firmware");
        let dir = avr_dir();
        let size = make(&dir, &build, "all").unwrap_or_else(|e| panic!("{e}"));
        println!(
            "{}",
            size.lines()
                .filter(|l| l.contains("Program") || l.contains("Data"))
                .collect::<Vec<_>>()
                .join("\n")
        );
        make(&dir, &build, "sim").unwrap_or_else(|e| panic!("{e}"));
        Some(Built {
            elf: build.join("turntable.elf"),
            ttsim: build.join("ttsim"),
            build,
        })
    })
    .clone()
}

/// The harness's pin counters.
#[derive(Debug, Clone, Default)]
pub struct Counts(pub HashMap<String, i64>);

impl Counts {
    pub fn get(&self, k: &str) -> i64 {
        *self
            .0
            .get(k)
            .unwrap_or_else(|| panic!("no {k} in the harness counters {:?}", self.0))
    }
}

/// A running harness.
pub struct Avr {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    pub link: PathBuf,
    pub table_start: i64,
    pub rail_start: i64,
    _dir: tempfile::TempDir,
}

impl Avr {
    /// Start the firmware with the table `table_start` steps past an index mark and the rail
    /// `rail_start` steps from its near-end switch.
    pub fn spawn(b: &Built, table_start: i64, rail_start: i64) -> Avr {
        Self::spawn_with_pose(b, table_start, rail_start, None)
    }

    /// [`Avr::spawn`] that also keeps the physical position in `pose` ("<table steps> <rail
    /// steps>", rewritten after every step: what the emulated camera shows).
    pub fn spawn_with_pose(
        b: &Built,
        table_start: i64,
        rail_start: i64,
        pose: Option<&Path>,
    ) -> Avr {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("ttyAVR");
        let mut cmd = Command::new(&b.ttsim);
        if let Some(p) = pose {
            cmd.arg("--pose-file").arg(p);
        }
        let mut child = cmd
            .arg("--elf")
            .arg(&b.elf)
            .arg("--link")
            .arg(&link)
            .args(["--speed", "0"])
            .args(["--table-rev", &TABLE_STEPS_PER_REV.to_string()])
            .args(["--index-width", "36"])
            .args(["--table-start", &table_start.to_string()])
            .args(["--rail-start", &rail_start.to_string()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", b.ttsim.display()));
        let stdin = child.stdin.take().unwrap();
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        loop {
            line.clear();
            assert!(
                stdout.read_line(&mut line).unwrap() > 0,
                "ttsim exited at start"
            );
            if line.starts_with("READY") {
                break;
            }
        }
        Avr {
            child,
            stdin,
            stdout,
            link,
            table_start,
            rail_start,
            _dir: dir,
        }
    }

    pub fn ctl(&mut self, cmd: &str) -> String {
        writeln!(self.stdin, "{cmd}").expect("ttsim control channel");
        let mut line = String::new();
        self.stdout.read_line(&mut line).expect("ttsim answer");
        assert!(!line.is_empty(), "ttsim exited (after {cmd})");
        line.trim().to_string()
    }

    pub fn counts(&mut self) -> Counts {
        let l = self.ctl("COUNTS");
        Counts(
            l.split(' ')
                .skip(1)
                .filter_map(|kv| kv.split_once('='))
                .map(|(k, v)| (k.to_string(), v.parse().expect("numeric counter")))
                .collect(),
        )
    }

    /// Physical table position in steps (start offset + net counted steps).
    pub fn table_phys(&mut self) -> i64 {
        self.table_start + self.counts().get("tpos")
    }

    pub fn rail_phys(&mut self) -> i64 {
        self.rail_start + self.counts().get("rpos")
    }

    pub fn path(&self) -> &str {
        self.link.to_str().unwrap()
    }
}

impl Drop for Avr {
    fn drop(&mut self) {
        let _ = writeln!(self.stdin, "QUIT");
        let deadline = Instant::now() + Duration::from_secs(2);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Driver timing for the emulated board: the emulator runs at roughly real time or slower on a
/// loaded machine, so DONE waits are stretched (the driver polls STATUS meanwhile anyway).
pub fn driver_config() -> TurntableConfig {
    TurntableConfig {
        attempt_timeout: Duration::from_millis(300),
        command_deadline: Duration::from_secs(20),
        done_factor: 3.0,
        done_slack: Duration::from_millis(1500),
        move_deadline: Duration::from_secs(240),
        ..TurntableConfig::default()
    }
}

/// Table steps for a position in millidegrees (the firmware's rounding: half away from zero).
pub fn table_steps(mdeg: i64) -> i64 {
    let n = mdeg * TABLE_STEPS_PER_REV;
    if n >= 0 {
        (n + 180_000) / 360_000
    } else {
        -((-n + 180_000) / 360_000)
    }
}

/// Rail steps for a position in µm (the firmware's rounding: half away from zero).
pub fn rail_steps(um: i64) -> i64 {
    let n = um * RAIL_STEPS_PER_MM;
    if n >= 0 {
        (n + 500) / 1000
    } else {
        -((-n + 500) / 1000)
    }
}

// ---- raw protocol client -------------------------------------------------------------------

/// Lines in and out over any transport, without the driver's retries (for STOP/ESTOP/RESET in
/// the middle of a move, retry replays and fuzzing).
pub struct Raw<T: Transport> {
    pub t: T,
    asm: firmware_protocol::LineAssembler,
    pub lines: VecDeque<String>,
    pub bad: u64,
}

impl<T: Transport> Raw<T> {
    pub fn new(t: T) -> Self {
        Raw {
            t,
            asm: firmware_protocol::LineAssembler::new(),
            lines: VecDeque::new(),
            bad: 0,
        }
    }

    pub fn line(seq: u16, body: &str) -> Vec<u8> {
        let content = format!("{seq} {body}");
        format!(
            "{content} *{:04X}\n",
            firmware_protocol::crc16(content.as_bytes())
        )
        .into_bytes()
    }

    pub fn send(&mut self, seq: u16, body: &str) {
        self.t.write_all(&Self::line(seq, body)).unwrap();
    }

    /// Read for up to `d`, keeping well-framed lines; counts bad ones.
    pub fn pump(&mut self, d: Duration) {
        let end = Instant::now() + d;
        let mut buf = [0u8; 512];
        while Instant::now() < end {
            let n = self.t.read(&mut buf, Duration::from_millis(5)).unwrap_or(0);
            for &b in &buf[..n] {
                match self.asm.push(b) {
                    Some(Ok(l)) => match firmware_protocol::Frame::parse(l) {
                        Ok(_) => self
                            .lines
                            .push_back(String::from_utf8_lossy(l).into_owned()),
                        Err(_) => self.bad += 1,
                    },
                    Some(Err(_)) => self.bad += 1,
                    None => {}
                }
            }
        }
    }

    /// Wait up to `d` for a line starting with `prefix`; returns it and drops earlier lines.
    pub fn expect(&mut self, prefix: &str, d: Duration) -> String {
        let end = Instant::now() + d;
        loop {
            while let Some(l) = self.lines.pop_front() {
                if l.starts_with(prefix) {
                    return l;
                }
            }
            assert!(
                Instant::now() < end,
                "no line starting with {prefix:?} within {d:?}"
            );
            self.pump(Duration::from_millis(20));
        }
    }

    /// Send and wait for the reply to `seq`; returns its body.
    pub fn cmd(&mut self, seq: u16, body: &str) -> String {
        self.send(seq, body);
        let l = self.expect(&format!("{seq} "), Duration::from_secs(10));
        let body = l.split_once(' ').unwrap().1;
        body[..body.len() - 6].to_string()
    }
}

// ---- fault-injecting link ------------------------------------------------------------------

fn new_pair(link: &Path) -> TTYPort {
    let (master, slave) = TTYPort::pair().expect("pty pair");
    let name = slave.name().expect("pty name");
    drop(slave);
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(&name, &tmp).unwrap();
    std::fs::rename(&tmp, link).unwrap();
    master
}

/// A link between the harness's pty and a new pty (the driver's end, at `path()`), dropping,
/// garbling and delaying bytes in both directions and going away now and then, as configured.
/// A reconnect may also reset the chip (a USB-powered board), through `on_reconnect_reset`.
pub struct FaultyLink {
    path: PathBuf,
    stop: Arc<AtomicBool>,
    counts: Arc<Mutex<FaultCounts>>,
    pub resets_requested: Arc<Mutex<u64>>,
    thread: Option<JoinHandle<()>>,
    _dir: tempfile::TempDir,
}

impl FaultyLink {
    pub fn spawn(device_path: &str, faults: FaultConfig, avr: Arc<Mutex<Avr>>) -> FaultyLink {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ttyFAULTY");
        let master = new_pair(&path);
        let mut dev: TTYPort = serialport::new(device_path, 115_200)
            .timeout(Duration::from_millis(1))
            .open_native()
            .unwrap_or_else(|e| panic!("{device_path}: {e}"));
        let stop = Arc::new(AtomicBool::new(false));
        let counts = Arc::new(Mutex::new(FaultCounts::default()));
        let resets = Arc::new(Mutex::new(0u64));
        let (s2, c2, r2, p2) = (stop.clone(), counts.clone(), resets.clone(), path.clone());
        let thread = std::thread::spawn(move || {
            let mut inj = FaultInjector::new(faults);
            let mut host = Some(master);
            let mut down_until: Option<Instant> = None;
            // (release time, bytes), per direction, released in order
            let mut to_dev: VecDeque<(Instant, Vec<u8>)> = VecDeque::new();
            let mut to_host: VecDeque<(Instant, Vec<u8>)> = VecDeque::new();
            let mut buf = [0u8; 1024];
            let mut host_seen = false;
            while !s2.load(Ordering::Relaxed) {
                let now = Instant::now();
                if let Some(t) = down_until {
                    if now >= t {
                        down_until = None;
                        host = Some(new_pair(&p2));
                        host_seen = false;
                        if inj.reset_on_reconnect() {
                            inj.count_reset();
                            avr.lock().unwrap().ctl("RESET");
                            *r2.lock().unwrap() += 1;
                        }
                    }
                }
                if let Some(h) = host.as_mut() {
                    let _ = h.set_timeout(Duration::from_millis(1));
                    match h.read(&mut buf) {
                        Ok(n) if n > 0 => {
                            host_seen = true;
                            if let Some(d) = inj.disconnect() {
                                host = None;
                                down_until = Some(now + d);
                                to_host.clear();
                            } else {
                                let bytes = inj.corrupt(&buf[..n]);
                                let at = to_dev.back().map_or(now, |b| b.0.max(now)) + inj.delay();
                                to_dev.push_back((at, bytes));
                            }
                        }
                        Ok(_) => {}
                        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => host_seen = true,
                        Err(_) => {} // no host has the port open
                    }
                }
                if let Ok(n) = dev.read(&mut buf) {
                    if n > 0 && host.is_some() && host_seen {
                        let bytes = inj.corrupt(&buf[..n]);
                        let at = to_host.back().map_or(now, |b| b.0.max(now)) + inj.delay();
                        to_host.push_back((at, bytes));
                    }
                }
                while to_dev.front().is_some_and(|c| c.0 <= now) {
                    let (_, b) = to_dev.pop_front().unwrap();
                    let _ = dev.write_all(&b);
                }
                while to_host.front().is_some_and(|c| c.0 <= now) {
                    let (_, b) = to_host.pop_front().unwrap();
                    if let Some(h) = host.as_mut() {
                        let _ = h.write_all(&b);
                    }
                }
                *c2.lock().unwrap() = inj.counts();
            }
        });
        FaultyLink {
            path,
            stop,
            counts,
            resets_requested: resets,
            thread: Some(thread),
            _dir: dir,
        }
    }

    pub fn path(&self) -> &str {
        self.path.to_str().unwrap()
    }

    pub fn counts(&self) -> FaultCounts {
        *self.counts.lock().unwrap()
    }
}

impl Drop for FaultyLink {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
