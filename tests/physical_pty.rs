//! The real turntable driver on the real `SerialTransport` against the simulated firmware
//! behind a pseudo-terminal pair (kernel tty layer included), on real time sped up 40×. Short
//! sessions, each fault kind and a mix; the same exactly-once oracle as the in-memory tests.
#![cfg(unix)]

mod physical_support;

use cac::physical::{Axis, SerialTransport, Turntable, TurntableConfig};
use cac::sim::{DeviceConfig, FaultConfig, LinkConfig, PtySim, SimWorld};
use physical_support::{fast, print, run_moves, SessionReport};
use std::time::Duration;

const SPEEDUP: f64 = 40.0;

fn config() -> TurntableConfig {
    TurntableConfig {
        attempt_timeout: Duration::from_millis(60),
        boot_wait: Duration::from_millis(150),
        reconnect_backoff: Duration::from_millis(20),
        done_slack: Duration::from_millis(150),
        // The device reports ETAs in simulated time, which runs SPEEDUP times faster.
        done_factor: 1.5 / SPEEDUP,
        ..TurntableConfig::default()
    }
}

fn session(name: &str, faults: FaultConfig, link: LinkConfig, moves: usize) -> SessionReport {
    let seed = faults.seed;
    let sim = PtySim::spawn(
        SimWorld::new(DeviceConfig::default(), link, faults),
        SPEEDUP,
    )
    .unwrap();
    let port = SerialTransport::open(sim.path().to_str().unwrap(), 115_200).unwrap();
    let mut tt = Turntable::open(port, config()).unwrap_or_else(|e| panic!("[{name}] open: {e}"));
    fast(&mut tt);
    let r = run_moves(&mut tt, sim.world(), moves, seed ^ 0xbeef);
    print(name, &r);
    r
}

#[test]
fn pty_clean_with_dtr_reset_on_open() {
    let link = LinkConfig {
        reset_on_open: true,
        ..LinkConfig::default()
    };
    let r = session("pty clean", FaultConfig::none(), link, 20);
    assert_eq!(r.faults.total(), 0);
    assert_eq!(
        r.boots, 2,
        "power-on, then the reset when the host opened the port"
    );
    assert_eq!(r.stats.redone_moves, 0);
}

#[test]
fn pty_bytes_dropped_and_garbled() {
    let f = FaultConfig {
        garble_byte: 0.004,
        ..FaultConfig::drops(21, 0.004)
    };
    let r = session("pty drops+garbles", f, LinkConfig::default(), 40);
    assert!(r.faults.dropped + r.faults.garbled > 5, "{}", r.faults);
}

#[test]
fn pty_delays() {
    let r = session(
        "pty delays",
        FaultConfig::delays(22, 0.2, Duration::from_millis(2000)),
        LinkConfig::default(),
        30,
    );
    assert!(r.faults.delayed > 3, "{}", r.faults);
}

#[test]
fn pty_resets_mid_move() {
    let r = session(
        "pty resets",
        FaultConfig::resets(23, 0.25),
        LinkConfig::default(),
        30,
    );
    assert!(r.faults.resets >= 2, "{}", r.faults);
    assert!(r.stats.redone_moves > 0, "{:?}", r.stats);
}

#[test]
fn pty_disconnects_port_vanishes_and_comes_back() {
    let r = session(
        "pty disconnects",
        FaultConfig::disconnects(24, 0.05, Duration::from_millis(2000)),
        LinkConfig::default(),
        30,
    );
    assert!(r.faults.disconnects >= 2, "{}", r.faults);
    assert!(r.stats.reconnects >= r.faults.disconnects, "{:?}", r.stats);
}

#[test]
fn pty_mix() {
    let r = session("pty mix", FaultConfig::mix(25), LinkConfig::default(), 40);
    assert!(r.faults.total() > 0, "{}", r.faults);
}

#[test]
fn pty_rail_axis_moves() {
    let sim = PtySim::spawn(
        SimWorld::new(
            DeviceConfig::default(),
            LinkConfig::default(),
            FaultConfig::none(),
        ),
        SPEEDUP,
    )
    .unwrap();
    let port = SerialTransport::open(sim.path().to_str().unwrap(), 115_200).unwrap();
    let mut tt = Turntable::open(port, config()).unwrap();
    fast(&mut tt);
    assert_eq!(tt.move_to(Axis::Rail, 250_000).unwrap().position, 250_000);
    assert_eq!(
        sim.world().lock().device().position(Axis::Rail),
        Some(250_000)
    );
    let st = tt.status(Axis::Rail).unwrap();
    assert!(st.homed && !st.moving && st.pos == 250_000);
}
