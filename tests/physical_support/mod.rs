//! Shared oracle for the physical-rig tests: drive many moves through the real turntable driver
//! against the simulated firmware and check that every move happened exactly once.

#![allow(dead_code)]

use cac::physical::{Axis, Transport, Turntable, TurntableConfig};
use cac::sim::{FaultCounts, MotionKind, SimHandle};
use firmware_protocol::DoneEnd;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What one session went through.
#[derive(Debug, Clone, Copy)]
pub struct SessionReport {
    pub moves: usize,
    pub faults: FaultCounts,
    pub boots: u32,
    pub stats: cac::physical::DriverStats,
    pub orphaned_completions: usize,
}

/// Fast motion settings so simulated sessions stay short.
pub fn fast(tt: &mut Turntable<impl Transport>) {
    tt.set_speed(Axis::Turntable, 360_000).unwrap();
    tt.set_accel(Axis::Turntable, 1_440_000).unwrap();
    if tt.has_rail() {
        tt.set_speed(Axis::Rail, 200_000).unwrap();
        tt.set_accel(Axis::Rail, 800_000).unwrap();
    }
}

/// Run `moves` random moves (turntable in 15° steps, every fourth on the rail) and check each
/// one against the simulator. Panics with a description on any violation.
pub fn run_moves<T: Transport>(
    tt: &mut Turntable<T>,
    world: &SimHandle,
    moves: usize,
    seed: u64,
) -> SessionReport {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut accepted = Vec::new();
    for i in 0..moves {
        let rail = tt.has_rail() && i % 4 == 3;
        let (axis, target) = if rail {
            (Axis::Rail, rng.random_range(0..=40) * 10_000)
        } else {
            (Axis::Turntable, rng.random_range(-24..=24) * 15_000)
        };
        let rep = tt.move_to(axis, target).unwrap_or_else(|e| {
            panic!("move {i} ({axis} → {target}) failed: {e}; {:?}", tt.stats())
        });
        assert_eq!(
            rep.position, target,
            "move {i}: driver reports the wrong position"
        );
        let w = world.lock();
        let dev = w.device();
        let recs: Vec<_> = dev
            .log()
            .iter()
            .filter(|r| r.seq == rep.seq.get())
            .collect();
        // The driver's belief equals the device's, except right after a reset that followed the
        // DONE and whose BOOT banner has not reached the driver yet.
        let reset_since = recs.first().is_some_and(|r| r.boot < dev.boots());
        if !(reset_since && dev.position(axis).is_none()) {
            assert_eq!(
                tt.position(axis),
                dev.position(axis),
                "move {i}: driver and device disagree"
            );
        }
        // The command that completed the move ran exactly once and reached the target.
        assert_eq!(
            recs.len(),
            1,
            "move {i}: seq {} started {} times",
            rep.seq,
            recs.len()
        );
        assert_eq!(recs[0].kind, MotionKind::Move);
        assert_eq!(recs[0].axis, axis);
        assert_eq!(
            recs[0].end,
            Some((DoneEnd::Reached, target)),
            "move {i}: {:?}",
            recs[0]
        );
        accepted.push(rep.seq.get());
    }
    let w = world.lock();
    let dev = w.device();
    // A retried command never runs twice: within a boot the reply cache replays it, and after a
    // reboot the device refuses it (ERR BOOTED) until the driver has said HELLO.
    assert_eq!(
        dev.max_starts_per_seq(),
        1,
        "a retried command was executed twice"
    );
    // Completed moves the driver did not accept must have been wiped out by a later reset and
    // commanded again: each reset can orphan at most one completed move per axis.
    let orphans: Vec<_> = dev
        .log()
        .iter()
        .filter(|r| r.kind == MotionKind::Move && !accepted.contains(&r.seq))
        .filter(|r| matches!(r.end, Some((DoneEnd::Reached, _))))
        .collect();
    for o in &orphans {
        assert!(
            o.boot < dev.boots(),
            "completed move {o:?} neither accepted nor followed by a reset"
        );
    }
    assert!(
        orphans.len() <= 2 * (dev.boots() as usize - 1),
        "too many orphaned moves: {orphans:?}"
    );
    // No move ended other than REACHED or by a reset (nobody sent STOP/ESTOP).
    for r in dev.log() {
        assert!(
            r.end.is_none_or(|(end, _)| end == DoneEnd::Reached)
                && (r.end.is_some() || r.boot < dev.boots()),
            "motion {r:?} ended abnormally"
        );
    }
    SessionReport {
        moves,
        faults: w.fault_counts(),
        boots: dev.boots(),
        stats: tt.stats(),
        orphaned_completions: orphans.len(),
    }
}

/// Driver settings for simulated links.
pub fn test_config() -> TurntableConfig {
    TurntableConfig {
        boot_wait: std::time::Duration::from_millis(600),
        ..TurntableConfig::default()
    }
}

pub fn print(name: &str, r: &SessionReport) {
    println!(
        "[{name}] {} moves OK; injected {}; device boots {}; driver: {} retries, {} resyncs, {} reconnects, {} resets seen, {} homings, {} redone moves, {} lost DONE recovered, {} bad lines; {} orphaned completions",
        r.moves, r.faults, r.boots, r.stats.retries, r.stats.resyncs, r.stats.reconnects,
        r.stats.resets_seen, r.stats.homings, r.stats.redone_moves, r.stats.lost_done_recovered,
        r.stats.bad_lines, r.orphaned_completions
    );
}
