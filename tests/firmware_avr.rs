//! The compiled AVR firmware (`firmware-protocol/avr/`, ATmega328P at 16 MHz) in simavr, driven
//! over a pseudo-terminal by cac's own `SerialTransport` and `Turntable` driver, with every step
//! counted on the STEP/DIR pins by the harness (`ttsim`), not taken from the firmware's word.
//! Skips (with a message) when gcc-avr/simavr are missing, except under `CI=true`.
#![cfg(unix)]

mod fakecam_support;
mod firmware_avr_support;

use cac::physical::{Axis, SerialTransport, Transport, Turntable, TurntableError};
use cac::sim::FaultConfig;
use firmware_avr_support::*;
use firmware_protocol::{ErrorCode, FaultCode, LineAssembler};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const S: Duration = Duration::from_secs(10);

fn lock() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

#[test]
fn c_unit_test_of_the_parser_on_the_shared_vectors() {
    let Some(b) = built() else { return };
    let out = std::process::Command::new("make")
        .arg("-C")
        .arg(avr_dir())
        .arg(format!("BUILD={}", b.build.display()))
        .arg("test")
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    println!("{text}");
    assert!(
        out.status.success() && text.contains(", 0 failures"),
        "{text}"
    );
}

/// Moves `axis` with the driver and checks the pins: the pulses during the move equal the
/// commanded distance in steps, all in the commanded direction.
fn checked_move(tt: &mut Turntable<SerialTransport>, avr: &mut Avr, target: i32, home_phys: i64) {
    let before = avr.counts();
    let from = tt.position(Axis::Turntable).expect("homed");
    let r = tt
        .move_to(Axis::Turntable, target)
        .unwrap_or_else(|e| panic!("move to {target}: {e}"));
    assert_eq!(r.position, target);
    let after = avr.counts();
    let want = table_steps(target.into()) - table_steps(from.into());
    let pulses = after.get("tpulses") - before.get("tpulses");
    let net = after.get("tpos") - before.get("tpos");
    assert_eq!(
        net, want,
        "move {from} -> {target} m°: net steps on the pins"
    );
    assert_eq!(
        pulses,
        want.abs(),
        "move {from} -> {target} m°: every pulse in the commanded direction"
    );
    assert_eq!(
        avr.table_start + after.get("tpos") - home_phys,
        table_steps(target.into())
    );
    assert_eq!(after.get("bad"), 0, "steps while the drivers were disabled");
}

#[test]
fn driver_scenarios_counted_on_the_pins() {
    let Some(b) = built() else { return };
    let _g = lock();
    let t0 = Instant::now();
    let mut avr = Avr::spawn(&b, 5_000, 9_000);
    let port = SerialTransport::open(avr.path(), 115_200).unwrap();
    let mut tt = Turntable::open(port, driver_config()).expect("open the emulated board");
    assert_eq!(tt.info().fw, "cac-avr-1.0");
    assert_eq!(tt.info().rail, Some((0, 400_000)));
    tt.set_speed(Axis::Turntable, 180_000).unwrap();
    tt.set_accel(Axis::Turntable, 720_000).unwrap();
    // Homing runs forward to the next index mark: 12800 - 5000 steps.
    assert_eq!(tt.home(Axis::Turntable).unwrap(), 0);
    let home = avr.table_phys();
    assert_eq!(home, TABLE_STEPS_PER_REV, "homed on the index mark");
    for target in [90_000, 15_000, -45_000, 123_457, 359_999, 0] {
        checked_move(&mut tt, &mut avr, target, home);
    }
    let r = tt.move_by(Axis::Turntable, -30_000).unwrap();
    assert_eq!(r.position, -30_000);
    assert_eq!(avr.table_phys() - home, table_steps(-30_000));
    let st = tt.status(Axis::Turntable).unwrap();
    assert!(
        st.homed && !st.moving && st.pos == -30_000 && st.target == -30_000,
        "{st:?}"
    );
    assert_eq!(st.fault, FaultCode::None);
    // Speed/acceleration limits.
    for (r, what) in [
        (tt.set_speed(Axis::Turntable, 0), "speed 0"),
        (tt.set_speed(Axis::Turntable, 720_001), "speed above max"),
        (tt.set_accel(Axis::Rail, 1_000_001), "rail accel above max"),
    ] {
        assert!(
            matches!(
                r,
                Err(TurntableError::Refused {
                    code: ErrorCode::Range,
                    ..
                })
            ),
            "{what}: {r:?}"
        );
    }
    // Rail: homes onto the near-end switch, then moves by 80 steps/mm.
    assert_eq!(tt.home(Axis::Rail).unwrap(), 0);
    assert_eq!(avr.rail_phys(), 0, "rail homed at the near-end switch");
    tt.set_speed(Axis::Rail, 200_000).unwrap();
    tt.move_to(Axis::Rail, 250_000).unwrap();
    assert_eq!(avr.rail_phys(), 250 * RAIL_STEPS_PER_MM);
    let rp = avr.counts().get("rpulses");
    let r = tt.move_to(Axis::Rail, 400_001);
    assert!(
        matches!(
            r,
            Err(TurntableError::Refused {
                code: ErrorCode::Limit,
                ..
            })
        ),
        "{r:?}"
    );
    assert_eq!(
        avr.counts().get("rpulses"),
        rp,
        "a refused move does not step"
    );
    // ESTOP: drivers disabled, homing lost, motion refused until CLEAR, then homes again.
    tt.estop().unwrap();
    assert_eq!(avr.counts().get("en"), 0, "drivers disabled after ESTOP");
    let st = tt.status(Axis::Turntable).unwrap();
    assert!(!st.homed && st.fault == FaultCode::Estop, "{st:?}");
    assert!(matches!(
        tt.move_to(Axis::Turntable, 0),
        Err(TurntableError::Fault(FaultCode::Estop))
    ));
    tt.clear_fault().unwrap();
    tt.move_to(Axis::Turntable, 45_000).unwrap();
    let phys = avr.table_phys();
    assert_eq!(
        (phys - table_steps(45_000)).rem_euclid(TABLE_STEPS_PER_REV),
        0,
        "re-homed, at 45°"
    );
    // Hardware e-stop button: the fault latches; CLEAR is refused while it is held.
    assert_eq!(avr.ctl("ESTOP 1"), "OK");
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(tt.status(Axis::Turntable).unwrap().fault, FaultCode::Estop);
    assert!(matches!(
        tt.clear_fault(),
        Err(TurntableError::Refused {
            code: ErrorCode::Estop,
            ..
        })
    ));
    assert_eq!(avr.ctl("ESTOP 0"), "OK");
    tt.clear_fault().unwrap();
    let c = avr.counts();
    assert_eq!((c.get("bad"), c.get("resets"), c.get("wdt")), (0, 0, 0));
    println!(
        "driver scenarios: {:.1} s wall, {:.1} s emulated, {:?}",
        t0.elapsed().as_secs_f64(),
        c.get("us") as f64 * 1e-6,
        tt.stats()
    );
}

/// The value of `KEY=` in a reply or event line.
fn field(line: &str, key: &str) -> i64 {
    line.split(' ')
        .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('='))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no numeric {key}= in {line:?}"))
}

/// Polls `STATUS 1` (sequence numbers from `*seq` on) until the firmware reports the table's move
/// from `from` to `to` (m°) under way: `MOV=1`, at least a quarter of the way and short of `to`.
/// Event-driven, so that a STOP sent next lands mid-move however fast the emulator runs.
fn wait_under_way<T: Transport>(r: &mut Raw<T>, seq: &mut u16, from: i64, to: i64) {
    let end = Instant::now() + Duration::from_secs(120);
    loop {
        let st = r.cmd(*seq, "STATUS 1");
        *seq += 1;
        let pos = field(&st, "POS");
        assert_eq!(field(&st, "TGT"), to, "{st}");
        assert_eq!(
            field(&st, "MOV"),
            1,
            "the move to {to} ended before the check: {st}"
        );
        if (pos - from).abs() * 4 >= (to - from).abs() {
            assert!((pos - to).signum() == (from - to).signum(), "{st}");
            return;
        }
        assert!(
            Instant::now() < end,
            "the move from {from} to {to} stuck: {st}"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn raw_stop_estop_reset_and_retry_replay_on_the_pins() {
    let Some(b) = built() else { return };
    let _g = lock();
    let mut avr = Avr::spawn(&b, 100, 2_000);
    let mut r = Raw::new(SerialTransport::open(avr.path(), 115_200).unwrap());
    r.t.write_all(b"\n").unwrap();
    r.pump(Duration::from_millis(300));
    r.lines.clear();
    assert_eq!(r.cmd(1, "HOME 1"), "ERR BOOTED", "locked until HELLO");
    assert!(r
        .cmd(2, "HELLO")
        .starts_with("OK PROTO=1 FW=cac-avr-1.0 AXES=2 RAIL=0:400000"));
    assert_eq!(r.cmd(3, "MOVE_ABS 1 0"), "ERR NOTHOMED");
    assert_eq!(r.cmd(4, "MOVE_ABS 2 400001"), "ERR NOTHOMED");
    assert_eq!(r.cmd(5, "FLY"), "ERR BADCMD");
    assert_eq!(r.cmd(6, "HOME 3"), "ERR NOAXIS");
    assert_eq!(r.cmd(7, "SPEED 1 360000"), "OK");
    assert_eq!(r.cmd(8, "ACCEL 1 720000"), "OK");
    assert!(r.cmd(9, "HOME 1").starts_with("OK ETA="));
    r.expect("! DONE SEQ=9 AXIS=1 POS=0 END=REACHED", S);
    let home = avr.table_phys();
    assert_eq!(home, TABLE_STEPS_PER_REV);
    // A retried MOVE_REL (the identical line three times) moves once: the reply cache.
    let p0 = avr.counts().get("tpulses");
    for _ in 0..3 {
        r.send(10, "MOVE_REL 1 15000");
    }
    let replies: Vec<String> = (0..3).map(|_| r.expect("10 ", S)).collect();
    assert!(
        replies.iter().all(|l| l == &replies[0]) && replies[0].starts_with("10 OK ETA="),
        "{replies:?}"
    );
    r.expect("! DONE SEQ=10 AXIS=1 POS=15000 END=REACHED", S);
    r.pump(Duration::from_millis(200));
    assert!(
        !r.lines.iter().any(|l| l.contains("DONE")),
        "one DONE only: {:?}",
        r.lines
    );
    assert_eq!(
        avr.counts().get("tpulses") - p0,
        table_steps(15_000),
        "moved once"
    );
    // Maximum step rate: a fast long move at 720°/s = 25600 steps/s.
    assert_eq!(r.cmd(11, "SPEED 1 720000"), "OK");
    assert_eq!(r.cmd(12, "ACCEL 1 2000000"), "OK");
    assert_eq!(avr.ctl("MINRESET"), "OK");
    assert_eq!(r.cmd(13, "MOVE_REL 1 720000"), "OK ETA=1360");
    r.expect(
        "! DONE SEQ=13 AXIS=1 POS=735000 END=REACHED",
        Duration::from_secs(30),
    );
    let c = avr.counts();
    let rate = c.get("trate");
    println!(
        "step rate: {rate} steps/s over the busiest 5 ms; shortest step interval {} cycles",
        c.get("tmin")
    );
    assert!(rate >= 24_000, "step rate {rate} steps/s");
    assert_eq!(avr.table_phys() - home, table_steps(735_000));
    // STOP mid-move (sent once STATUS reports the move under way): decelerates (steps after the
    // STOP reply), ends STOPPED between start and target where the pins say, and STATUS agrees.
    // The polls take sequence numbers from 1000 on, apart from the numbered commands.
    let mut poll = 1000;
    assert_eq!(r.cmd(14, "SPEED 1 180000"), "OK");
    assert_eq!(r.cmd(15, "ACCEL 1 180000"), "OK");
    assert!(r.cmd(16, "MOVE_ABS 1 0").starts_with("OK ETA="));
    wait_under_way(&mut r, &mut poll, 735_000, 0);
    assert_eq!(r.cmd(17, "STOP"), "OK");
    let at_stop = avr.counts().get("tpulses");
    let done = r.expect("! DONE SEQ=16 AXIS=1 ", S);
    assert!(done.contains("END=STOPPED"), "{done}");
    let pos = field(&done, "POS");
    assert!(
        avr.counts().get("tpulses") > at_stop,
        "controlled stop: it decelerated"
    );
    let phys = avr.table_phys() - home;
    assert!(
        (table_steps(pos) - phys).abs() <= 1,
        "POS={pos} but the pins say {phys} steps"
    );
    assert!(pos > 0 && pos < 735_000, "stopped on the way: {pos}");
    assert_eq!(
        r.cmd(poll, "STATUS 1"),
        format!("OK POS={pos} TGT=0 MOV=0 HOMED=1 FAULT=NONE SEQ=16"),
        "STATUS after the STOP"
    );
    poll += 1;
    // ESTOP mid-move: halts at once between start and target, drivers off, DONE ABORTED then
    // FAULT.
    assert!(r.cmd(18, "MOVE_ABS 1 0").starts_with("OK ETA="));
    wait_under_way(&mut r, &mut poll, pos, 0);
    assert_eq!(r.cmd(19, "ESTOP"), "OK");
    let done = r.expect("! DONE SEQ=18 AXIS=1 ", S);
    assert!(done.contains("END=ABORTED"), "{done}");
    let aborted = field(&done, "POS");
    assert!(aborted > 0 && aborted < pos, "aborted on the way: {done}");
    r.expect("! FAULT CODE=ESTOP", S);
    let c1 = avr.counts();
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(
        avr.counts().get("tpulses"),
        c1.get("tpulses"),
        "no step after ESTOP"
    );
    assert_eq!(c1.get("en"), 0);
    assert_eq!(r.cmd(20, "HOME 1"), "ERR ESTOP");
    assert_eq!(r.cmd(21, "CLEAR"), "OK");
    assert_eq!(r.cmd(22, "MOVE_ABS 1 0"), "ERR NOTHOMED");
    // RESET mid-move: OK, then BOOT; the pins stop; the device is locked and unhomed.
    assert!(r.cmd(23, "HOME 1").starts_with("OK ETA="));
    r.expect("! DONE SEQ=23", S);
    assert!(r.cmd(24, "MOVE_REL 1 360000").starts_with("OK ETA="));
    wait_under_way(&mut r, &mut poll, 0, 360_000);
    assert_eq!(r.cmd(25, "RESET"), "OK");
    r.expect("! BOOT PROTO=1 FW=cac-avr-1.0 REASON=RESET", S);
    let c2 = avr.counts();
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(
        avr.counts().get("tpulses"),
        c2.get("tpulses"),
        "no step after the reboot"
    );
    assert_eq!(
        r.cmd(26, "STATUS 1"),
        "OK POS=0 TGT=0 MOV=0 HOMED=0 FAULT=NONE SEQ=0"
    );
    assert_eq!(
        r.cmd(24, "MOVE_REL 1 360000"),
        "ERR BOOTED",
        "a stale retry after the reboot"
    );
    assert!(r.cmd(27, "HELLO").starts_with("OK PROTO=1"));
    // External reset (DTR auto-reset when a port opens).
    assert_eq!(avr.ctl("RESET"), "OK");
    r.expect("! BOOT PROTO=1 FW=cac-avr-1.0 REASON=RESET", S);
    let c = avr.counts();
    assert_eq!(
        (c.get("bad"), c.get("resets")),
        (0, 2),
        "the RESET command and the external one"
    );
}

#[test]
fn link_faults_each_move_once_on_the_step_pin() {
    let Some(b) = built() else { return };
    let _g = lock();
    let t0 = Instant::now();
    let avr = Arc::new(Mutex::new(Avr::spawn(&b, 3_000, 0)));
    let dev_path = avr.lock().unwrap().path().to_string();
    let faults = FaultConfig {
        seed: 5,
        drop_byte: 0.004,
        garble_byte: 0.004,
        delay_chunk: 0.05,
        max_delay: Duration::from_millis(500),
        disconnect_per_write: 0.01,
        disconnect_for: Duration::from_millis(800),
        reset_on_reconnect: 0.5,
        ..FaultConfig::none()
    };
    let link = FaultyLink::spawn(&dev_path, faults, avr.clone());
    let port = SerialTransport::open(link.path(), 115_200).unwrap();
    let mut tt = Turntable::open(port, driver_config()).expect("open through the faulty link");
    tt.set_speed(Axis::Turntable, 360_000).unwrap();
    tt.set_accel(Axis::Turntable, 1_440_000).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let moves = 16;
    let mut exact = 0;
    // Move 8 is a long one, and the chip is reset (RESET on the harness) 0.4 s into it.
    let reset_move = 8;
    let mut reset_recoveries = 0;
    for i in 0..moves {
        let mut target = rng.random_range(-12..=12) * 15_000;
        let from = tt.position(Axis::Turntable);
        let (c0, redone0) = (
            avr.lock().unwrap().counts(),
            tt.stats().redone_moves + tt.stats().homings,
        );
        let resetter = (i == reset_move).then(|| {
            target = if from.unwrap_or(0) >= 0 {
                -180_000
            } else {
                180_000
            };
            let a2 = avr.clone();
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(400));
                assert_eq!(a2.lock().unwrap().ctl("RESET"), "OK");
            })
        });
        let rep = tt
            .move_to(Axis::Turntable, target)
            .unwrap_or_else(|e| panic!("move {i}: {e}"));
        if let Some(t) = resetter {
            t.join().unwrap();
            reset_recoveries = rep.recoveries;
        }
        assert_eq!(rep.position, target);
        let c1 = avr.lock().unwrap().counts();
        let phys = avr.lock().unwrap().table_start + c1.get("tpos");
        assert_eq!(
            (phys - table_steps(target.into())).rem_euclid(TABLE_STEPS_PER_REV),
            0,
            "move {i}: the table is not at {target} m° by the pins"
        );
        // Without a reboot or homing on the way, the pins saw exactly this move, once.
        if c1.get("resets") == c0.get("resets")
            && tt.stats().redone_moves + tt.stats().homings == redone0
        {
            if let Some(from) = from {
                let want = (table_steps(target.into()) - table_steps(from.into())).abs();
                assert_eq!(
                    c1.get("tpulses") - c0.get("tpulses"),
                    want,
                    "move {i}: pulses"
                );
                exact += 1;
            }
        }
    }
    let c = avr.lock().unwrap().counts();
    assert_eq!(c.get("bad"), 0);
    assert_eq!(c.get("wdt"), 0, "no watchdog reset");
    let f = link.counts();
    println!(
        "link faults: {moves} moves ({exact} with exact pulse counts), injected {f}; chip resets {} (1 mid-move, {reset_recoveries} recoveries); driver {:?}; {:.1} s",
        c.get("resets"),
        tt.stats(),
        t0.elapsed().as_secs_f64()
    );
    assert!(f.dropped + f.garbled > 3 && f.delayed > 0, "{f}");
    assert_eq!(
        c.get("resets") as u64,
        *link.resets_requested.lock().unwrap() + 1,
        "the reset mid-move and the link's reboots on reconnect, nothing else"
    );
    assert!(
        reset_recoveries >= 1,
        "move {reset_move}: the driver recovered from the reset mid-move"
    );
    assert!(exact >= moves / 2, "too few moves checked exactly: {exact}");
}

#[test]
fn fuzz_random_and_mutated_lines() {
    let Some(b) = built() else { return };
    let _g = lock();
    let secs: u64 = std::env::var("CAC_AVR_FUZZ_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let mut avr = Avr::spawn(&b, 0, 0);
    let mut r = Raw::new(SerialTransport::open(avr.path(), 115_200).unwrap());
    r.t.write_all(b"\n").unwrap();
    r.pump(Duration::from_millis(300));
    r.lines.clear();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let words = [
        "HELLO",
        "PING",
        "HOME",
        "MOVE_ABS",
        "MOVE_REL",
        "SPEED",
        "ACCEL",
        "STATUS",
        "STOP",
        "ESTOP",
        "CLEAR",
        "1",
        "2",
        "3",
        "0",
        "-5",
        "90000",
        "4294967296",
        "x",
        "",
        "move_abs",
        "-0",
        "01",
    ];
    let bases = [
        "1 HELLO *7DF0",
        "4 MOVE_ABS 1 90000 *8B97",
        "8 STATUS 1 *D4A5",
        "6 SPEED 1 45000 *4D04",
        "3 HOME 1 *4371",
    ];
    let (mut sent, mut bytes, mut expected_total, mut replies, mut events, mut unexpected) =
        (0u64, 0u64, 0u64, 0u64, 0u64, Vec::new());
    let mut seq: u16 = 100;
    let end = Instant::now() + Duration::from_secs(secs);
    while Instant::now() < end {
        let mut batch = Vec::new();
        for _ in 0..8 {
            let line: Vec<u8> = match rng.random_range(0..3) {
                0 => (0..rng.random_range(0..130))
                    .map(|_| rng.random::<u8>())
                    .collect(),
                1 => {
                    let mut l = bases[rng.random_range(0..bases.len())].as_bytes().to_vec();
                    for _ in 0..rng.random_range(1..4) {
                        let i = rng.random_range(0..l.len());
                        match rng.random_range(0..3) {
                            0 => l[i] = rng.random(),
                            1 => l.insert(i, rng.random()),
                            _ => {
                                l.remove(i);
                            }
                        }
                    }
                    l
                }
                _ => {
                    seq = if seq >= 60_000 { 100 } else { seq + 1 };
                    let body: Vec<&str> = (0..rng.random_range(1..6))
                        .map(|_| words[rng.random_range(0..words.len())])
                        .collect();
                    let mut l = Raw::<SerialTransport>::line(seq, &body.join(" "));
                    l.pop();
                    l
                }
            };
            batch.extend_from_slice(&line);
            batch.push(b'\n');
            sent += 1;
        }
        // The oracle: the crate's own receive path says which lines a device must answer.
        let mut asm = LineAssembler::new();
        let mut expected = Vec::new();
        for &byte in &batch {
            if let Some(Ok(l)) = asm.push(byte) {
                if let Ok(f) = firmware_protocol::Frame::parse(l) {
                    if let firmware_protocol::SeqField::Seq(s) = f.seq {
                        assert!(
                            !f.body.starts_with("RESET"),
                            "the fuzzer must not reboot the board"
                        );
                        expected.push(s.get());
                    }
                }
            }
        }
        seq = if seq >= 60_000 { 100 } else { seq + 1 };
        let sentinel = seq;
        batch.extend_from_slice(&Raw::<SerialTransport>::line(sentinel, "PING"));
        bytes += batch.len() as u64;
        r.t.write_all(&batch).unwrap();
        let t = Instant::now();
        let mut got = Vec::new();
        'wait: loop {
            assert!(
                t.elapsed() < Duration::from_secs(10),
                "the firmware hung: no answer to PING {sentinel} after {sent} lines"
            );
            r.pump(Duration::from_millis(10));
            while let Some(l) = r.lines.pop_front() {
                if l.starts_with("! ") {
                    events += 1;
                    assert!(!l.starts_with("! BOOT"), "the firmware rebooted: {l}");
                    continue;
                }
                let s: u16 = l.split(' ').next().unwrap().parse().unwrap();
                if s == sentinel {
                    break 'wait;
                }
                got.push(s);
                replies += 1;
            }
        }
        expected_total += expected.len() as u64;
        if got != expected {
            unexpected.push(format!("expected replies to {expected:?}, got {got:?}"));
        }
    }
    let c = avr.counts();
    println!(
        "fuzz: {sent} lines ({bytes} bytes) in {secs} s; {expected_total} well-framed, {replies} replies, {events} events, {} bad lines from the device; hangs 0, watchdog resets {}, resets {}, unexpected {}",
        r.bad, c.get("wdt"), c.get("resets"), unexpected.len()
    );
    assert!(unexpected.is_empty(), "{}", unexpected.join("\n"));
    assert_eq!(r.bad, 0, "the device sent malformed lines");
    assert_eq!((c.get("wdt"), c.get("resets")), (0, 0));
    assert!(expected_total > 0 && sent > 100);
}

/// A rig file for the emulated board: 96×72 frames of the repository's lens, the firmware's
/// 400 mm rail starting 0.25 m from the axis.
fn avr_rig_file(dir: &std::path::Path) -> std::path::PathBuf {
    let p = dir.join("rig.toml");
    let calib = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("calib/camera_opencv.yaml");
    let text = format!(
        r#"ratios = [1.5, 2.0]
[camera]
intrinsics = "{}"
resolution = [96, 72]
height_m = 0.10
elevation_deg = 5.0
[turntable]
axis_m = [0.0, 0.0]
settle_ms = 20
speed_deg_s = 180.0
[rail]
present = true
near_m = 0.25
length_m = 0.4
[object]
mesh = "pickup"
length_m = 0.22
"#,
        calib.display()
    );
    std::fs::write(&p, text).unwrap();
    p
}

fn cac_cmd(args: &[&str]) -> std::process::Output {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_cac"))
        .args(args)
        .output()
        .expect("run cac");
    assert!(
        o.status.success(),
        "cac {}: {}\n{}",
        args.join(" "),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

/// `cac capture --port PTY --twin-camera` against the firmware in simavr (2 distance ratios on
/// the rail × 3 table angles × 1 repeat), then `cac score`: the manifest holds exactly the
/// commanded frames, the twin was posed where the driver says the rig is, and the pulses on the
/// STEP pins are exactly the homings plus the commanded moves.
#[test]
fn capture_session_with_twin_camera_on_the_firmware_then_scored() {
    use cac::physical::rig::Rig;
    use cac::physical::score::SessionScore;
    use cac::physical::session::{SessionInfo, SessionPlan};
    let Some(b) = built() else { return };
    let _g = lock();
    let t0 = Instant::now();
    let (table_start, rail_start) = (10_000, 4_000);
    let mut avr = Avr::spawn(&b, table_start, rail_start);
    let dir = tempfile::tempdir().unwrap();
    let rig_path = avr_rig_file(dir.path());
    let out = dir.path().join("session");
    let (rig_s, out_s) = (rig_path.to_str().unwrap(), out.to_str().unwrap());
    let angles = "0,120,240";
    let o = cac_cmd(&[
        "capture",
        "--rig",
        rig_s,
        "--ratios",
        "1.5,2",
        "--angles",
        angles,
        "--repeats",
        "1",
        "--out",
        out_s,
        "--port",
        avr.path(),
        "--twin-camera",
        "--seed",
        "3",
    ]);
    let t_capture = t0.elapsed().as_secs_f64();
    println!("{}", String::from_utf8_lossy(&o.stdout).trim());
    let rig = Rig::load(&rig_path).unwrap();
    let info = SessionInfo::load(&out).unwrap();
    let plan = SessionPlan::new(
        vec![1.5, 2.0],
        SessionPlan::parse_angles(angles).unwrap(),
        1,
    )
    .unwrap();
    assert_eq!(info.plan, plan);
    assert!(
        info.simulated && info.camera.starts_with("digital twin 96x72"),
        "{info:?}"
    );
    // The manifest: the planned frames in order, each where the driver says the rig was.
    let entries = cac::physical::manifest::read(&out.join("manifest.jsonl")).unwrap();
    let planned = plan.frames();
    assert_eq!(entries.len(), planned.len());
    let mut seqs = Vec::new();
    for (e, f) in entries.iter().zip(&planned) {
        assert_eq!(
            (&e.frame, e.angle, e.ratio, e.repeat),
            (&f.file, f.angle, f.ratio, f.repeat)
        );
        let img = image::open(out.join(&e.frame)).unwrap();
        assert_eq!((img.width(), img.height()), (96, 72), "{}", e.frame);
        let mdeg = (f.angle * 1000.0).round() as i64;
        assert_eq!(e.device["turntable_mdeg"].as_i64(), Some(mdeg), "{e:?}");
        let rail_um = i64::from(rig.rail_target(f.ratio).unwrap());
        assert_eq!(e.device["rail_um"].as_i64(), Some(rail_um), "{e:?}");
        let want = format!(
            "twin angle={:.3} distance={:.4}",
            f.angle,
            0.25 + rail_um as f64 * 1e-6
        );
        assert_eq!(e.camera, want, "{}", e.frame);
        seqs.push(e.device["move_seq"].as_u64().expect("move_seq"));
    }
    seqs.sort_unstable();
    seqs.dedup();
    assert_eq!(seqs.len(), entries.len(), "one move per frame");
    // The pins: homing forward to the index mark, then exactly the commanded moves.
    let c = avr.counts();
    let mut table_want = TABLE_STEPS_PER_REV - table_start;
    let mut rail_want = rail_start;
    let (mut tprev, mut rprev) = (0, 0);
    for (i, f) in planned.iter().enumerate() {
        if i == 0 || planned[i - 1].ratio != f.ratio {
            let r = rail_steps(rig.rail_target(f.ratio).unwrap().into());
            rail_want += (r - rprev).abs();
            rprev = r;
        }
        let t = table_steps((f.angle * 1000.0).round() as i64);
        table_want += (t - tprev).abs();
        tprev = t;
    }
    assert_eq!(c.get("tpulses"), table_want, "table pulses: homing + moves");
    assert_eq!(
        table_start + c.get("tpos"),
        TABLE_STEPS_PER_REV + tprev,
        "table at the last angle"
    );
    assert_eq!(c.get("rpulses"), rail_want, "rail pulses: homing + moves");
    assert_eq!(rail_start + c.get("rpos"), rprev, "rail at the last ratio");
    assert_eq!((c.get("bad"), c.get("resets"), c.get("wdt")), (0, 0, 0));
    // Scored by `cac score`: the projected ground truth at the planned pose for every frame.
    let o = cac_cmd(&["score", out_s, "--models", "nanodet"]);
    println!("{}", String::from_utf8_lossy(&o.stdout).trim());
    let s: SessionScore =
        serde_json::from_str(&std::fs::read_to_string(out.join("score/scores.json")).unwrap())
            .unwrap();
    assert_eq!(s.models, ["nanodet"]);
    assert_eq!(s.frames.len(), planned.len());
    for f in &s.frames {
        let gt = cac::physical::truth::ground_truth_box(
            &rig,
            f.angle,
            rig.horizontal_distance(f.ratio).unwrap(),
        )
        .unwrap();
        assert!(gt.is_some(), "{}: the object is in view", f.frame);
        assert_eq!(f.gt, gt, "{}", f.frame);
        assert_eq!(f.hit.len(), 1);
    }
    assert_eq!(s.by_ratio.len(), 2);
    for r in &s.by_ratio {
        let hits = s
            .frames
            .iter()
            .filter(|f| f.ratio == r.ratio && f.hit[0])
            .count();
        assert_eq!(r.per_repeat.len(), 1);
        assert!((r.mean - hits as f64 / 3.0).abs() < 1e-12, "{r:?}");
    }
    assert_eq!(s.by_angle.len(), 3);
    support::score_report::check(&out.join("score"), &s, &entries, out_s);
    println!(
        "twin-camera session: 6 frames, {} table pulses, {} rail pulses, {:.1} s emulated; capture {t_capture:.1} s, with scoring {:.1} s wall",
        c.get("tpulses"),
        c.get("rpulses"),
        c.get("us") as f64 * 1e-6,
        t0.elapsed().as_secs_f64()
    );
}

/// `cac capture --port PTY --camera /dev/video7`: the firmware in simavr drives the table and
/// the rail, an emulated UVC webcam (tools/fakecam) shows the twin's picture of the pose the
/// mechanics hold at each moment (ttsim's pose file). The link drops, garbles and delays bytes;
/// the camera stalls in the first run, which is killed mid-session; the `--resume` run meets a
/// corrupt frame and an unplugged camera. Every planned frame is in the manifest exactly once,
/// each is the picture of its planned pose (frames the camera filled while the table was still
/// turning are not taken), what was recovered is on the frame it delayed, the camera's settings
/// are recorded and held again on resume, and `cac score` scores the session.
#[test]
fn capture_session_with_an_emulated_webcam_on_the_firmware_killed_resumed_then_scored() {
    use cac::physical::rig::Rig;
    use cac::physical::session::{SessionInfo, SessionPlan};
    use cac::physical::twin::{DigitalTwin, Pose};
    let Some(b) = built() else { return };
    let shim = match fakecam_support::shim() {
        Ok(s) => s,
        Err(what) => {
            support::missing(&what, "apt-get install gcc");
            return;
        }
    };
    let _g = lock();
    let t0 = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let pose = dir.path().join("pose");
    let avr = Arc::new(Mutex::new(Avr::spawn_with_pose(
        &b,
        10_000,
        4_000,
        Some(&pose),
    )));
    let rig_path = avr_rig_file(dir.path());
    let rig = Arc::new(Rig::load(&rig_path).unwrap());
    let (ratios, angles) = (vec![1.5, 2.0], "0,90,180,270");
    let plan = SessionPlan::new(
        ratios.clone(),
        SessionPlan::parse_angles(angles).unwrap(),
        2,
    )
    .unwrap();
    // The camera's bank: the twin's picture of every planned pose, keyed by the steps the
    // mechanics hold there (table within a revolution from the index mark, rail from its switch).
    let atlas = rig
        .renderer
        .scene
        .initial_atlas(rig.renderer.settings.atlas_res);
    let twin = DigitalTwin::new(rig.clone(), &atlas, Box::new(|| Err("unused".into())), 3);
    let mut shots = Vec::new();
    let mut keys = Vec::new();
    for &ratio in &ratios {
        let rail_um = i64::from(rig.rail_target(ratio).unwrap());
        for &angle in &plan.angles {
            let mdeg = (angle * 1000.0).round() as i64;
            let p = Pose {
                angle_deg: angle,
                horizontal_m: rig.horizontal_distance(ratio).unwrap(),
            };
            let img = twin.render(p, 0).unwrap().image;
            let t = table_steps(mdeg).rem_euclid(TABLE_STEPS_PER_REV);
            shots.push((t, rail_steps(rail_um), img));
            keys.push(cac::physical::manifest::key_of(ratio, angle));
        }
    }
    let bank = fakecam_support::write_bank(&dir.path().join("bank"), TABLE_STEPS_PER_REV, &shots);
    let camera = |run: &str, faults: &str| fakecam_support::Camera {
        bank: dir.path().join("bank"),
        pose: Some(pose.clone()),
        faults: faults.into(),
        formats: String::new(),
        log: dir.path().join(format!("{run}.log")),
    };
    let link_faults = |seed| FaultConfig {
        seed,
        drop_byte: 0.003,
        garble_byte: 0.003,
        delay_chunk: 0.05,
        max_delay: Duration::from_millis(300),
        ..FaultConfig::none()
    };
    let out = dir.path().join("session");
    let capture = |cam: &fakecam_support::Camera, port: &str, resume: bool| {
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_cac"));
        cmd.arg("capture")
            .arg("--rig")
            .arg(&rig_path)
            .args([
                "--ratios",
                "1.5,2",
                "--angles",
                angles,
                "--repeats",
                "2",
                "--seed",
                "3",
            ])
            .arg("--out")
            .arg(&out)
            .args(["--port", port, "--camera", fakecam_support::DEV]);
        if resume {
            cmd.arg("--resume");
        }
        cam.apply(&shim, &mut cmd);
        cmd.stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped());
        cmd.spawn().expect("start cac capture")
    };
    let manifest = out.join("manifest.jsonl");
    let lines = || {
        std::fs::read_to_string(&manifest)
            .map(|t| t.matches('\n').count())
            .unwrap_or(0)
    };

    // Run 1: a stall (frames 0-9 are the warm-ups), killed once 5 frames are in.
    let dev = avr.lock().unwrap().path().to_string();
    let cam1 = camera("run1", "stall@12");
    let link = FaultyLink::spawn(&dev, link_faults(11), avr.clone());
    let mut child = capture(&cam1, link.path(), false);
    let deadline = Instant::now() + Duration::from_secs(240);
    while lines() < 5 {
        if let Some(st) = child.try_wait().unwrap() {
            let o = child.wait_with_output().unwrap();
            panic!(
                "cac capture ended ({st}) before the kill:\n{}",
                String::from_utf8_lossy(&o.stderr)
            );
        }
        assert!(Instant::now() < deadline, "no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    drop(link);
    let killed_at = lines();
    assert!(killed_at < plan.frames().len(), "killed mid-session");
    assert_eq!(cam1.fired(), ["stall@12"]);
    let info = SessionInfo::load(&out).unwrap();
    let settings = info
        .camera_settings
        .clone()
        .expect("the camera's settings recorded");
    assert!(
        !info.simulated && info.camera.contains("uvcvideo"),
        "{info:?}"
    );
    assert_eq!(
        (settings.format.as_str(), settings.width, settings.height),
        ("MJPG", 96, 72)
    );
    let exposure = settings
        .controls
        .iter()
        .find(|c| c.name == "exposure")
        .unwrap();
    assert!(
        exposure.auto_off && exposure.value.is_some(),
        "{settings:?}"
    );

    // Run 2: resumed; a corrupt frame and the camera unplugged for 0.3 s.
    let cam2 = camera("run2", "corrupt@11,unplug@14:300");
    let link = FaultyLink::spawn(&dev, link_faults(12), avr.clone());
    let o = capture(&cam2, link.path(), true)
        .wait_with_output()
        .unwrap();
    assert!(
        o.status.success(),
        "cac capture --resume:\n{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    println!("{}", String::from_utf8_lossy(&o.stdout).trim());
    let fired2 = cam2.fired();
    assert!(fired2.contains(&"unplug@14:300".to_string()), "{fired2:?}");
    // Resumed at the session's values, not where this run's auto exposure would have settled.
    assert!(
        cam2.log_lines()
            .contains(&format!("s_ctrl 0x9a0902 {}", exposure.value.unwrap())),
        "exposure held at the session's value on resume"
    );

    // The manifest: every planned frame once, in plan order, each the picture of its pose.
    let entries = cac::physical::manifest::read(&manifest).unwrap();
    let planned = plan.frames();
    assert_eq!(entries.len(), planned.len());
    for (e, f) in entries.iter().zip(&planned) {
        assert_eq!(
            (&e.frame, e.angle, e.ratio, e.repeat),
            (&f.file, f.angle, f.ratio, f.repeat)
        );
        let got = image::open(out.join(&e.frame)).unwrap().to_rgb8();
        let k = keys
            .iter()
            .position(|k| *k == cac::physical::manifest::key_of(f.ratio, f.angle))
            .unwrap();
        let want = bank[k].mjpeg_rgb();
        assert!(
            got == want,
            "{}: not the camera's picture of its planned pose",
            e.frame
        );
        assert!(
            e.camera.starts_with("/dev/video7 MJPG 96x72 frame"),
            "{}",
            e.camera
        );
    }
    let events: Vec<&String> = entries.iter().flat_map(|e| &e.camera_events).collect();
    let count = |what: &str| events.iter().filter(|e| e.contains(what)).count();
    assert_eq!(count("no frame within"), 1, "the stall: {events:?}");
    assert_eq!(count("device lost"), 1, "the unplug: {events:?}");
    // A corrupt frame the camera filled while the table turned is discarded unseen.
    let corrupt_fired = fired2.iter().any(|f| f.starts_with("corrupt"));
    assert!(
        count("corrupt frame dropped") <= usize::from(corrupt_fired),
        "{events:?}"
    );
    assert_eq!(
        events.len(),
        2 + count("corrupt frame dropped"),
        "{events:?}"
    );
    let c = avr.lock().unwrap().counts();
    assert_eq!((c.get("bad"), c.get("wdt")), (0, 0));

    // Scored.
    let out_s = out.to_str().unwrap();
    let o = cac_cmd(&["score", out_s, "--models", "nanodet"]);
    println!("{}", String::from_utf8_lossy(&o.stdout).trim());
    let s: cac::physical::score::SessionScore =
        serde_json::from_str(&std::fs::read_to_string(out.join("score/scores.json")).unwrap())
            .unwrap();
    assert_eq!(s.frames.len(), planned.len());
    support::score_report::check(&out.join("score"), &s, &entries, out_s);
    println!(
        "webcam session: {} frames ({killed_at} before the kill), events {events:?}, {:.1} s wall",
        planned.len(),
        t0.elapsed().as_secs_f64()
    );
}

/// Moves the rail with the driver; the pins must show exactly the commanded distance.
fn checked_rail_move(tt: &mut Turntable<SerialTransport>, avr: &Mutex<Avr>, target: i32) {
    let from = tt.position(Axis::Rail).expect("rail homed");
    let before = avr.lock().unwrap().counts();
    let r = tt
        .move_to(Axis::Rail, target)
        .unwrap_or_else(|e| panic!("rail to {target} µm: {e}"));
    assert_eq!(r.position, target);
    let after = avr.lock().unwrap().counts();
    let want = rail_steps(target.into()) - rail_steps(from.into());
    assert_eq!(
        after.get("rpos") - before.get("rpos"),
        want,
        "rail {from} -> {target} µm: net steps on the pins"
    );
    assert_eq!(
        after.get("rpulses") - before.get("rpulses"),
        want.abs(),
        "rail {from} -> {target} µm: every pulse in the commanded direction"
    );
    let phys = avr.lock().unwrap().rail_start + after.get("rpos");
    assert_eq!(
        phys,
        rail_steps(target.into()),
        "rail at {target} µm by the pins"
    );
}

/// Rail homing and moves counted on the rail's STEP pin (80 steps/mm, rounding), then the
/// near-end switch found pressed mid-move far from the near end (lost steps): the firmware halts
/// the pins, latches `FAULT CODE=LIMIT AXIS=2`, refuses motion until CLEAR, then homes again.
#[test]
fn rail_moves_counted_on_the_pins_and_limit_fault() {
    let Some(b) = built() else { return };
    let _g = lock();
    let t0 = Instant::now();
    let rail_start = 6_000;
    let avr = Arc::new(Mutex::new(Avr::spawn(&b, 0, rail_start)));
    let path = avr.lock().unwrap().path().to_string();
    let port = SerialTransport::open(&path, 115_200).unwrap();
    let mut tt = Turntable::open(port, driver_config()).expect("open the emulated board");
    assert_eq!(tt.home(Axis::Rail).unwrap(), 0);
    let c = avr.lock().unwrap().counts();
    assert_eq!(
        (c.get("rpos"), c.get("rpulses")),
        (-rail_start, rail_start),
        "homed straight back onto the near-end switch"
    );
    assert_eq!(c.get("tpulses"), 0, "the table did not move");
    tt.set_speed(Axis::Rail, 200_000).unwrap();
    tt.set_accel(Axis::Rail, 1_000_000).unwrap();
    // 37 512 µm = 3000.96 steps, 399 994 µm = 31 999.52, 12 346 µm = 987.68: rounded.
    for target in [100_000, 37_512, 399_994, 12_346, 0, 250_000] {
        checked_rail_move(&mut tt, &avr, target);
    }
    let p = avr.lock().unwrap().counts().get("rpos");
    let r = tt.move_by(Axis::Rail, -12_345).unwrap();
    assert_eq!(r.position, 237_655);
    assert_eq!(
        avr.lock().unwrap().counts().get("rpos") - p,
        rail_steps(237_655) - rail_steps(250_000)
    );
    // Lost steps: the near-end switch closes 0.5 s into a 190 mm move at 50 mm/s.
    tt.set_speed(Axis::Rail, 50_000).unwrap();
    let a2 = avr.clone();
    let presser = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(500));
        assert_eq!(a2.lock().unwrap().ctl("NEAR 1"), "OK");
    });
    let r = tt.move_to(Axis::Rail, 47_655);
    presser.join().unwrap();
    let pos = match r {
        Err(TurntableError::Interrupted {
            axis: Axis::Rail,
            pos,
            end: firmware_protocol::DoneEnd::Aborted,
        }) => pos,
        other => panic!("expected the move aborted by the LIMIT fault, got {other:?}"),
    };
    let c1 = avr.lock().unwrap().counts();
    let phys = rail_start + c1.get("rpos");
    assert!(
        (rail_steps(pos.into()) - phys).abs() <= 1,
        "DONE POS={pos} µm but the pins say {phys} steps"
    );
    assert!(
        phys < rail_steps(237_655) && phys > rail_steps(47_655),
        "halted on the way: {phys}"
    );
    assert_eq!(c1.get("en"), 0, "drivers disabled by the fault");
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(
        avr.lock().unwrap().counts().get("rpulses"),
        c1.get("rpulses"),
        "no rail step after the LIMIT fault"
    );
    let st = tt.status(Axis::Rail).unwrap();
    assert!(
        st.fault == FaultCode::Limit && !st.homed && !st.moving,
        "{st:?}"
    );
    assert!(
        matches!(
            tt.move_to(Axis::Rail, 0),
            Err(TurntableError::Fault(FaultCode::Limit))
        ),
        "motion refused while LIMIT is latched"
    );
    assert_eq!(
        avr.lock().unwrap().counts().get("rpulses"),
        c1.get("rpulses")
    );
    // The switch released (the carriage is free again), CLEAR, and the rail homes and moves.
    assert_eq!(avr.lock().unwrap().ctl("NEAR auto"), "OK");
    tt.clear_fault().unwrap();
    tt.set_speed(Axis::Rail, 200_000).unwrap();
    tt.move_to(Axis::Rail, 100_000).unwrap();
    let c = avr.lock().unwrap().counts();
    assert_eq!(
        rail_start + c.get("rpos"),
        rail_steps(100_000),
        "re-homed, at 100 mm"
    );
    assert_eq!(
        c.get("rpulses") - c1.get("rpulses"),
        phys + rail_steps(100_000),
        "homing back to the switch, then 100 mm"
    );
    assert_eq!((c.get("bad"), c.get("resets"), c.get("wdt")), (0, 0, 0));
    println!(
        "rail: {} pulses, LIMIT fault at {pos} µm; {:.1} s",
        c.get("rpulses"),
        t0.elapsed().as_secs_f64()
    );
}

/// The hardware e-stop held while the chip boots: `BOOT` then `FAULT CODE=ESTOP`; the drivers
/// stay off, motion and CLEAR are refused while it is held, and released it clears and homes.
#[test]
fn estop_held_at_boot_latches_fault_estop() {
    let Some(b) = built() else { return };
    let _g = lock();
    let table_start = 500;
    let mut avr = Avr::spawn(&b, table_start, 0);
    let mut r = Raw::new(SerialTransport::open(avr.path(), 115_200).unwrap());
    r.t.write_all(b"\n").unwrap();
    r.pump(Duration::from_millis(300));
    r.lines.clear();
    assert_eq!(avr.ctl("ESTOP 1"), "OK");
    // The event of the press itself first (a reset in the middle of a line would garble it and
    // the banner after it into one bad line), then the chip boots with the button held.
    r.expect("! FAULT CODE=ESTOP", S);
    assert_eq!(avr.ctl("RESET"), "OK");
    r.expect("! BOOT PROTO=1 FW=cac-avr-1.0 REASON=RESET", S);
    r.expect("! FAULT CODE=ESTOP", S);
    assert!(r.cmd(1, "HELLO").starts_with("OK PROTO=1"));
    assert_eq!(
        r.cmd(2, "STATUS 1"),
        "OK POS=0 TGT=0 MOV=0 HOMED=0 FAULT=ESTOP SEQ=0"
    );
    assert_eq!(r.cmd(3, "HOME 1"), "ERR ESTOP");
    assert_eq!(r.cmd(4, "HOME 2"), "ERR ESTOP");
    assert_eq!(
        r.cmd(5, "CLEAR"),
        "ERR ESTOP",
        "refused while the button is held"
    );
    std::thread::sleep(Duration::from_millis(200));
    let c = avr.counts();
    assert_eq!(
        (c.get("en"), c.get("tpulses"), c.get("rpulses")),
        (0, 0, 0),
        "drivers off, nothing moved"
    );
    assert_eq!(avr.ctl("ESTOP 0"), "OK");
    assert_eq!(r.cmd(6, "CLEAR"), "OK");
    assert_eq!(
        r.cmd(7, "STATUS 1"),
        "OK POS=0 TGT=0 MOV=0 HOMED=0 FAULT=NONE SEQ=0"
    );
    assert!(r.cmd(8, "HOME 1").starts_with("OK ETA="));
    r.expect("! DONE SEQ=8 AXIS=1 POS=0 END=REACHED", S);
    let c = avr.counts();
    assert_eq!(c.get("tpulses"), TABLE_STEPS_PER_REV - table_start);
    assert_eq!(
        avr.table_phys(),
        TABLE_STEPS_PER_REV,
        "homed on the index mark"
    );
    assert_eq!((c.get("bad"), c.get("resets"), c.get("wdt")), (0, 1, 0));
}
