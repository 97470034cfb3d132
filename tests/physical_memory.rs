//! The real turntable driver against the simulated firmware over the in-memory link on virtual
//! time, under each fault kind and a mix: every move reaches its target exactly once.

mod physical_support;

use cac::physical::{Axis, Turntable, TurntableError};
use cac::sim::{DeviceConfig, FaultConfig, LinkConfig, MemoryTransport, SimHandle, SimWorld};
use physical_support::{fast, print, run_moves, test_config, SessionReport};
use std::time::Duration;

fn session(name: &str, faults: FaultConfig, moves: usize) -> SessionReport {
    let seed = faults.seed;
    let world = SimHandle::new(SimWorld::new(
        DeviceConfig::default(),
        LinkConfig::default(),
        faults,
    ));
    let t = MemoryTransport::open(world.clone()).unwrap();
    let mut tt = Turntable::open(t, test_config()).unwrap_or_else(|e| panic!("[{name}] open: {e}"));
    assert_eq!(tt.info().fw, "cacsim-0.1");
    assert_eq!(tt.info().rail, Some((0, 400_000)));
    fast(&mut tt);
    let r = run_moves(&mut tt, &world, moves, seed ^ 0x5eed);
    print(name, &r);
    r
}

#[test]
fn clean_link_needs_no_recovery() {
    let r = session("clean", FaultConfig::none(), 200);
    assert_eq!(r.faults.total(), 0);
    assert_eq!(r.stats.retries, 0);
    assert_eq!(r.stats.redone_moves, 0);
    assert_eq!(r.stats.reconnects, 0);
    assert_eq!(r.boots, 1);
    // Turntable and rail each homed once.
    assert_eq!(r.stats.homings, 2);
}

#[test]
fn dropped_bytes() {
    let r = session("drops", FaultConfig::drops(11, 0.004), 300);
    assert!(r.faults.dropped > 50, "{}", r.faults);
    assert!(
        r.stats.retries > 0 && r.stats.lost_done_recovered > 0,
        "{:?}",
        r.stats
    );
}

#[test]
fn garbled_bytes() {
    let r = session("garbles", FaultConfig::garbles(12, 0.004), 300);
    assert!(r.faults.garbled > 50, "{}", r.faults);
    assert!(
        r.stats.retries > 0 && r.stats.bad_lines > 0,
        "{:?}",
        r.stats
    );
}

#[test]
fn delays_longer_than_the_reply_timeout() {
    let r = session(
        "delays",
        FaultConfig::delays(13, 0.15, Duration::from_millis(600)),
        300,
    );
    assert!(r.faults.delayed > 50, "{}", r.faults);
    assert!(r.stats.retries > 0, "{:?}", r.stats);
}

#[test]
fn spontaneous_resets_mid_move() {
    let r = session("resets", FaultConfig::resets(14, 0.1), 300);
    assert!(r.faults.resets >= 10, "{}", r.faults);
    assert_eq!(u64::from(r.boots), r.faults.resets + 1);
    assert!(
        r.stats.redone_moves > 0 && r.stats.resets_seen >= r.faults.resets,
        "{:?}",
        r.stats
    );
}

#[test]
fn disconnects() {
    let r = session(
        "disconnects",
        FaultConfig::disconnects(15, 0.02, Duration::from_millis(800)),
        300,
    );
    assert!(r.faults.disconnects >= 5, "{}", r.faults);
    assert!(r.stats.reconnects >= r.faults.disconnects, "{:?}", r.stats);
}

#[test]
fn every_fault_kind_at_once_over_many_seeds() {
    let mut total = cac::sim::FaultCounts::default();
    let mut moves = 0;
    for seed in 100..140 {
        let r = session(&format!("mix seed {seed}"), FaultConfig::mix(seed), 200);
        moves += r.moves;
        total.dropped += r.faults.dropped;
        total.garbled += r.faults.garbled;
        total.delayed += r.faults.delayed;
        total.resets += r.faults.resets;
        total.disconnects += r.faults.disconnects;
    }
    println!("[mix total] {moves} moves, all exactly once, surviving {total}");
    assert!(total.dropped > 0 && total.garbled > 0 && total.delayed > 0);
    assert!(total.resets > 0 && total.disconnects > 0);
}

#[test]
fn resets_with_lost_banners_and_lost_lines() {
    // Resets while bytes are lost: some BOOT banners and DONE events never arrive.
    let f = FaultConfig {
        drop_byte: 0.01,
        garble_byte: 0.005,
        ..FaultConfig::resets(16, 0.15)
    };
    let r = session("resets+losses", f, 300);
    assert!(
        r.faults.resets >= 10 && r.faults.dropped > 100,
        "{}",
        r.faults
    );
}

#[test]
fn dtr_reset_on_open_sends_banner_and_driver_waits_for_it() {
    let link = LinkConfig {
        reset_on_open: true,
        ..LinkConfig::default()
    };
    let world = SimHandle::new(SimWorld::new(
        DeviceConfig::default(),
        link,
        FaultConfig::none(),
    ));
    let t = MemoryTransport::open(world.clone()).unwrap();
    let mut tt = Turntable::open(t, test_config()).unwrap();
    assert_eq!(
        world.lock().device().boots(),
        2,
        "power-on boot plus the reset on open"
    );
    assert_eq!(
        tt.stats().retries,
        0,
        "the driver waited for the banner instead of talking over the boot"
    );
    let r = tt.move_to(Axis::Turntable, 45_000).unwrap();
    assert_eq!(r.position, 45_000);
}

#[test]
fn turntable_without_rail() {
    let dev = DeviceConfig {
        rail: None,
        ..DeviceConfig::default()
    };
    let world = SimHandle::new(SimWorld::new(
        dev,
        LinkConfig::default(),
        FaultConfig::none(),
    ));
    let mut tt =
        Turntable::open(MemoryTransport::open(world.clone()).unwrap(), test_config()).unwrap();
    assert!(!tt.has_rail());
    assert!(matches!(
        tt.move_to(Axis::Rail, 0),
        Err(TurntableError::NoAxis(Axis::Rail))
    ));
    let r = tt.move_by(Axis::Turntable, -30_000).unwrap();
    assert_eq!(r.position, -30_000);
    let r = tt.move_by(Axis::Turntable, 45_000).unwrap();
    assert_eq!(r.position, 15_000);
    assert_eq!(
        world.lock().device().position(Axis::Turntable),
        Some(15_000)
    );
}

#[test]
fn rail_limits_and_estop_are_reported_not_retried() {
    let world = SimHandle::new(SimWorld::new(
        DeviceConfig::default(),
        LinkConfig::default(),
        FaultConfig::none(),
    ));
    let mut tt =
        Turntable::open(MemoryTransport::open(world.clone()).unwrap(), test_config()).unwrap();
    let e = tt.move_to(Axis::Rail, 400_001).unwrap_err();
    assert!(
        matches!(
            e,
            TurntableError::Refused {
                code: firmware_protocol::ErrorCode::Limit,
                ..
            }
        ),
        "{e}"
    );
    tt.move_to(Axis::Turntable, 90_000).unwrap();
    tt.estop().unwrap();
    let e = tt.move_to(Axis::Turntable, 0).unwrap_err();
    assert!(
        matches!(
            e,
            TurntableError::Fault(firmware_protocol::FaultCode::Estop)
        ),
        "{e}"
    );
    assert!(e.to_string().contains("ESTOP"));
    tt.clear_fault().unwrap();
    // Homing was lost with the ESTOP: the next move re-homes first.
    let homings = tt.stats().homings;
    assert_eq!(tt.move_to(Axis::Turntable, 0).unwrap().position, 0);
    assert_eq!(tt.stats().homings, homings + 1);
}

#[test]
fn dead_device_gives_a_timeout_not_a_hang() {
    let world = SimHandle::new(SimWorld::new(
        DeviceConfig::default(),
        LinkConfig::default(),
        FaultConfig::drops(1, 1.0),
    ));
    let e =
        Turntable::open(MemoryTransport::open(world.clone()).unwrap(), test_config()).unwrap_err();
    assert!(
        matches!(e, TurntableError::Timeout { cmd: "PING", .. }),
        "{e}"
    );
}
