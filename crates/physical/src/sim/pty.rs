//! Runs a [`SimWorld`] behind a pseudo-terminal pair, so the real [`SerialTransport`] and driver
//! talk to the simulated firmware through the kernel's tty layer. The simulator owns the master
//! end on its own thread; the host opens the slave through a stable symlink (like
//! `/dev/serial/by-id/...`), which is re-pointed when a simulated disconnect re-creates the pair.
//!
//! [`SerialTransport`]: crate::SerialTransport

use super::world::{SimHandle, SimWorld};
use serialport::{SerialPort, TTYPort};
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// `TTYPort::pair` is not thread-safe on every platform (`ptsname`): one pair at a time.
static PAIR_LOCK: Mutex<()> = Mutex::new(());

fn new_pair(link: &Path) -> io::Result<TTYPort> {
    let _guard = PAIR_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let (master, slave) = TTYPort::pair().map_err(io::Error::from)?;
    let name = slave
        .name()
        .ok_or_else(|| io::Error::other("pseudo-terminal slave has no name"))?;
    // Close our slave handle: the host opens it by name, and its close is then seen as a hangup.
    drop(slave);
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(&name, &tmp)?;
    std::fs::rename(&tmp, link)?;
    Ok(master)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Plug {
    Up,
    Unplugged,
    Replugged,
}

/// A simulated turntable on a pseudo-terminal. Dropping it stops the simulator thread.
#[derive(Debug)]
pub struct PtySim {
    path: PathBuf,
    world: SimHandle,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    _dir: tempfile::TempDir,
}

impl PtySim {
    /// Start `world` on a new pty pair; simulated time runs `speedup` times faster than real time
    /// (motion, boot and link durations shrink accordingly).
    pub fn spawn(world: SimWorld, speedup: f64) -> io::Result<Self> {
        let dir = tempfile::tempdir()?;
        let path = dir.path().join("turntable");
        let master = new_pair(&path)?;
        let world = SimHandle::new(world);
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (world, stop, path) = (world.clone(), stop.clone(), path.clone());
            std::thread::Builder::new()
                .name("cac-sim-pty".into())
                .spawn(move || run(master, world, stop, path, speedup.max(1e-3)))?
        };
        Ok(Self {
            path,
            world,
            stop,
            thread: Some(thread),
            _dir: dir,
        })
    }

    /// The path the host opens (a symlink to the current slave device).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The simulated world, for inspection.
    pub fn world(&self) -> &SimHandle {
        &self.world
    }
}

impl Drop for PtySim {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn run(master: TTYPort, world: SimHandle, stop: Arc<AtomicBool>, link: PathBuf, speedup: f64) {
    let start = Instant::now();
    let sim_now = || Duration::from_secs_f64(start.elapsed().as_secs_f64() * speedup);
    let mut master = Some(master);
    let mut plug = Plug::Up;
    let mut connected = false;
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        {
            let mut w = world.lock();
            let now = sim_now().max(w.now());
            w.advance_to(now);
            match (plug, w.down_until()) {
                (Plug::Up, Some(_)) => {
                    master = None; // the host's port hangs up
                    connected = false;
                    plug = Plug::Unplugged;
                }
                (Plug::Unplugged, Some(until)) if now >= until => match new_pair(&link) {
                    Ok(m) => {
                        master = Some(m);
                        plug = Plug::Replugged;
                    }
                    Err(e) => eprintln!("sim pty: cannot re-create the port: {e}"),
                },
                _ => {}
            }
            let out = w.host_take(usize::MAX);
            if let (Some(m), true, false) = (master.as_mut(), connected, out.is_empty()) {
                let _ = m.write_all(&out);
            }
        }
        let Some(m) = master.as_mut() else {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        };
        let _ = m.set_timeout(Duration::from_millis(1));
        let got = m.read(&mut buf);
        let host_present = match &got {
            Ok(_) => true,
            Err(e) => e.kind() == io::ErrorKind::TimedOut,
        };
        let mut w = world.lock();
        if host_present && !connected {
            // The host opened the slave: a plugged-in board sees the port open (DTR).
            if w.host_open().is_ok() {
                connected = true;
                plug = Plug::Up;
            }
        } else if !host_present {
            connected = false;
            drop(w);
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        if let Ok(n) = got {
            if n > 0 && connected {
                let now = sim_now().max(w.now());
                w.advance_to(now);
                // An injected disconnect is acted on at the top of the loop.
                let _ = w.host_write(&buf[..n]);
            }
        }
    }
}
