//! Conformance of the simulated firmware to docs/protocol.md, line by line: boot banner, HELLO,
//! homing and moves with their ETAs, the reply cache, error codes, STOP/ESTOP/CLEAR/RESET, and
//! silence on corrupt lines.

use cac::sim::{DeviceConfig, SimDevice};
use firmware_protocol::{
    encode_command, Axis, Command, CommandKind, DoneEnd, ErrorCode, Event, FaultCode, Frame,
    LineBuf, Reply, Seq, SeqField,
};
use std::time::Duration;

const MS: Duration = Duration::from_millis(1);

fn booted(cfg: DeviceConfig) -> SimDevice {
    let boot = cfg.boot_time;
    let mut d = SimDevice::new(cfg, Duration::ZERO, 1234.0);
    assert!(d.take_output().is_empty(), "nothing before the banner");
    d.advance(boot);
    let out = lines(&mut d);
    assert_eq!(out.len(), 1);
    assert!(
        out[0].starts_with("! BOOT PROTO=1 FW=cacsim-0.1 REASON=POWERON *"),
        "{out:?}"
    );
    assert!(matches!(
        send(&mut d, 60_000, Command::Hello).0,
        Reply::Hello(_)
    ));
    d
}

fn lines(d: &mut SimDevice) -> Vec<String> {
    let out = String::from_utf8(d.take_output()).unwrap();
    out.lines().map(str::to_string).collect()
}

fn line(seq: u16, cmd: &Command) -> Vec<u8> {
    let mut b = LineBuf::new();
    encode_command(Seq::new(seq).unwrap(), cmd, &mut b).unwrap();
    b.as_bytes().to_vec()
}

/// Send `cmd` as `seq`; return the parsed reply and the events that followed immediately.
fn send(d: &mut SimDevice, seq: u16, cmd: Command) -> (Reply<'static>, Vec<String>) {
    d.receive(&line(seq, &cmd));
    let out = lines(d);
    assert!(!out.is_empty(), "no reply to {cmd:?}");
    let f = Frame::parse(out[0].as_bytes()).unwrap();
    assert_eq!(f.seq, SeqField::Seq(Seq::new(seq).unwrap()));
    let body: &'static str = Box::leak(f.body.to_string().into_boxed_str());
    (Reply::parse(cmd.kind(), body).unwrap(), out[1..].to_vec())
}

fn event(l: &str) -> Event<'static> {
    let f = Frame::parse(l.as_bytes()).unwrap();
    assert_eq!(f.seq, SeqField::Event);
    Event::parse(Box::leak(f.body.to_string().into_boxed_str())).unwrap()
}

fn eta(r: Reply<'_>) -> Duration {
    match r {
        Reply::Moving { eta_ms } => Duration::from_millis(u64::from(eta_ms)),
        r => panic!("expected OK ETA=, got {r:?}"),
    }
}

/// Advance until just before and just after `eta`, expecting the DONE exactly then.
fn expect_done(d: &mut SimDevice, eta: Duration, seq: u16, axis: Axis, pos: i32) {
    let start = d.now();
    d.advance(start + eta.saturating_sub(2 * MS));
    assert!(d.take_output().is_empty(), "DONE too early");
    d.advance(start + eta + MS);
    let out = lines(d);
    assert_eq!(out.len(), 1, "{out:?}");
    assert_eq!(
        event(&out[0]),
        Event::Done {
            seq: Seq::new(seq).unwrap(),
            axis,
            pos,
            end: DoneEnd::Reached
        }
    );
}

#[test]
fn input_during_boot_is_ignored_and_hello_describes_the_device() {
    let mut d = SimDevice::new(DeviceConfig::default(), Duration::ZERO, 0.0);
    d.receive(&line(1, &Command::Ping));
    assert!(d.take_output().is_empty());
    assert!(d.counters().ignored_while_booting > 0);
    d.advance(Duration::from_secs(1));
    lines(&mut d);
    let (r, _) = send(&mut d, 2, Command::Hello);
    match r {
        Reply::Hello(h) => {
            assert_eq!(
                (h.proto, h.fw, h.rail, h.axes()),
                (1, "cacsim-0.1", Some((0, 400_000)), 2)
            )
        }
        r => panic!("{r:?}"),
    }
}

#[test]
fn homing_and_moves_follow_the_trapezoid_and_report_done() {
    let mut d = booted(DeviceConfig::default());
    assert_eq!(
        send(&mut d, 1, Command::MoveAbs(Axis::Turntable, 1000)).0,
        Reply::Err(ErrorCode::NotHomed)
    );
    let (r, _) = send(&mut d, 2, Command::Home(Axis::Turntable));
    // Homing from 1.234° runs to the next index mark at 360°: at most a full turn.
    let worst = eta(r);
    let start = d.now();
    d.advance(start + worst);
    let out = lines(&mut d);
    assert_eq!(
        event(&out[0]),
        Event::Done {
            seq: Seq::new(2).unwrap(),
            axis: Axis::Turntable,
            pos: 0,
            end: DoneEnd::Reached
        }
    );
    // 90° at the default 90°/s and 180°/s²: 1.5 s.
    let (r, _) = send(&mut d, 3, Command::MoveAbs(Axis::Turntable, 90_000));
    assert_eq!(eta(r), Duration::from_millis(1500));
    // Busy while moving, but the rail is independent.
    assert_eq!(
        send(&mut d, 4, Command::MoveRel(Axis::Turntable, 5)).0,
        Reply::Err(ErrorCode::Busy)
    );
    let (r, _) = send(&mut d, 5, Command::Home(Axis::Rail));
    assert!(matches!(r, Reply::Moving { .. }));
    expect_done(
        &mut d,
        Duration::from_millis(1500),
        3,
        Axis::Turntable,
        90_000,
    );
    d.advance(d.now() + Duration::from_secs(30));
    lines(&mut d);
    let (r, _) = send(&mut d, 6, Command::Status(Axis::Turntable));
    match r {
        Reply::Status(s) => {
            assert_eq!(
                (s.pos, s.target, s.moving, s.homed, s.fault),
                (90_000, 90_000, false, true, FaultCode::None)
            );
            assert_eq!(s.seq, Seq::new(3));
        }
        r => panic!("{r:?}"),
    }
    // Relative move, short enough to be triangular: 2·√(d/a).
    let (r, _) = send(&mut d, 7, Command::MoveRel(Axis::Turntable, -1800));
    let expect = Duration::from_secs_f64(2.0 * (1800.0f64 / 180_000.0).sqrt());
    assert_eq!(
        eta(r),
        Duration::from_millis(expect.as_secs_f64().mul_add(1000.0, 0.0).ceil() as u64)
    );
    expect_done(&mut d, eta(r), 7, Axis::Turntable, 88_200);
    // Zero-length move: OK ETA=0, DONE right behind it.
    let (r, ev) = send(&mut d, 8, Command::MoveAbs(Axis::Turntable, 88_200));
    assert_eq!(r, Reply::Moving { eta_ms: 0 });
    assert_eq!(ev.len(), 1);
    assert!(matches!(
        event(&ev[0]),
        Event::Done {
            pos: 88_200,
            end: DoneEnd::Reached,
            ..
        }
    ));
}

#[test]
fn retried_line_replays_the_cached_reply_and_never_moves_twice() {
    let mut d = booted(DeviceConfig::default());
    send(&mut d, 1, Command::Home(Axis::Turntable));
    d.advance(Duration::from_secs(30));
    lines(&mut d);
    let l = line(2, &Command::MoveRel(Axis::Turntable, 10_000));
    d.receive(&l);
    let first = d.take_output();
    d.advance(d.now() + 10 * MS);
    d.receive(&l);
    let second = d.take_output();
    assert_eq!(first, second, "replayed reply must be byte-identical");
    assert_eq!(d.starts_for(2), 1);
    assert_eq!(d.counters().replays, 1);
    d.advance(d.now() + Duration::from_secs(5));
    lines(&mut d);
    assert_eq!(d.position(Axis::Turntable), Some(10_000));
    // Same sequence number but a different command is a new command (documented).
    let (r, _) = send(&mut d, 2, Command::Status(Axis::Turntable));
    assert!(matches!(r, Reply::Status(_)));
}

#[test]
fn error_codes() {
    let mut d = booted(DeviceConfig::default());
    d.receive(b"1 FLY 1 *\n");
    d.receive(format!("{}\n", with_crc("1 FLY 1")).as_bytes());
    let out = lines(&mut d);
    assert_eq!(out.len(), 1, "the unframed line got no reply: {out:?}");
    assert!(out[0].starts_with("1 ERR BADCMD *"));
    d.receive(format!("{}\n", with_crc("2 MOVE_ABS 1")).as_bytes());
    assert!(lines(&mut d)[0].starts_with("2 ERR BADARG *"));
    d.receive(format!("{}\n", with_crc("3 HOME 7")).as_bytes());
    assert!(lines(&mut d)[0].starts_with("3 ERR NOAXIS *"));
    assert_eq!(
        send(&mut d, 4, Command::Speed(Axis::Rail, 0)).0,
        Reply::Err(ErrorCode::Range)
    );
    assert_eq!(
        send(&mut d, 5, Command::Accel(Axis::Rail, u32::MAX)).0,
        Reply::Err(ErrorCode::Range)
    );
    send(&mut d, 6, Command::Home(Axis::Rail));
    d.advance(Duration::from_secs(60));
    lines(&mut d);
    assert_eq!(
        send(&mut d, 7, Command::MoveAbs(Axis::Rail, -1)).0,
        Reply::Err(ErrorCode::Limit)
    );
    assert_eq!(
        send(&mut d, 8, Command::MoveRel(Axis::Rail, 400_001)).0,
        Reply::Err(ErrorCode::Limit)
    );
    send(&mut d, 9, Command::Home(Axis::Turntable));
    d.advance(d.now() + Duration::from_secs(60));
    lines(&mut d);
    send(&mut d, 10, Command::MoveAbs(Axis::Turntable, i32::MAX - 5));
    d.advance(d.now() + Duration::from_secs(1));
    assert_eq!(send(&mut d, 11, Command::Stop(None)).0, Reply::Ok);
    d.advance(d.now() + Duration::from_secs(60));
    lines(&mut d);
    let p = d.position(Axis::Turntable).unwrap();
    assert_eq!(
        send(&mut d, 12, Command::MoveRel(Axis::Turntable, i32::MAX)).0,
        Reply::Err(ErrorCode::Range),
        "{p}"
    );
    let no_rail = DeviceConfig {
        rail: None,
        ..DeviceConfig::default()
    };
    let mut d = booted(no_rail);
    assert_eq!(
        send(&mut d, 1, Command::Status(Axis::Rail)).0,
        Reply::Err(ErrorCode::NoAxis)
    );
    match send(&mut d, 2, Command::Hello).0 {
        Reply::Hello(h) => assert_eq!((h.rail, h.axes()), (None, 1)),
        r => panic!("{r:?}"),
    }
}

fn with_crc(s: &str) -> String {
    format!("{s} *{:04X}", firmware_protocol::crc16(s.as_bytes()))
}

#[test]
fn after_boot_only_safe_commands_work_until_hello() {
    let mut d = SimDevice::new(DeviceConfig::default(), Duration::ZERO, 0.0);
    d.advance(Duration::from_secs(1));
    lines(&mut d);
    for cmd in [
        Command::Home(Axis::Turntable),
        Command::MoveAbs(Axis::Turntable, 0),
        Command::MoveRel(Axis::Rail, 1),
        Command::Speed(Axis::Turntable, 1),
        Command::Accel(Axis::Turntable, 1),
        Command::Clear,
        Command::Reset,
    ] {
        assert_eq!(
            send(&mut d, 1, cmd).0,
            Reply::Err(ErrorCode::Booted),
            "{cmd:?}"
        );
        // A different command under a new number each time (not a cache replay).
        assert_eq!(send(&mut d, 2, Command::Ping).0, Reply::Ok);
    }
    assert!(matches!(
        send(&mut d, 3, Command::Status(Axis::Rail)).0,
        Reply::Status(_)
    ));
    assert_eq!(send(&mut d, 4, Command::Stop(None)).0, Reply::Ok);
    assert!(matches!(send(&mut d, 5, Command::Hello).0, Reply::Hello(_)));
    assert!(matches!(
        send(&mut d, 6, Command::Home(Axis::Turntable)).0,
        Reply::Moving { .. }
    ));
    assert!(d.log().len() == 1 && d.starts_for(6) == 1);
    // A reboot locks it again.
    assert_eq!(send(&mut d, 7, Command::Estop).0, Reply::Ok);
    assert_eq!(send(&mut d, 8, Command::Clear).0, Reply::Ok);
    assert_eq!(send(&mut d, 9, Command::Reset).0, Reply::Ok);
    d.advance(d.now() + Duration::from_secs(1));
    lines(&mut d);
    assert_eq!(
        send(&mut d, 10, Command::Home(Axis::Turntable)).0,
        Reply::Err(ErrorCode::Booted)
    );
}

#[test]
fn corrupt_or_overlong_lines_get_silence() {
    let mut d = booted(DeviceConfig::default());
    let mut l = line(1, &Command::Ping);
    l[2] = b'Q';
    d.receive(&l);
    d.receive(&[b'A'; 200]);
    d.receive(b"\n");
    d.receive(b"1 PING *abcd\n");
    d.receive(b"! PING *0000\n");
    assert!(d.take_output().is_empty());
    assert_eq!(d.counters().framing_errors, 4);
    // And the next good line is answered.
    assert_eq!(send(&mut d, 2, Command::Ping).0, Reply::Ok);
}

#[test]
fn stop_estop_clear_reset() {
    let mut d = booted(DeviceConfig::default());
    send(&mut d, 1, Command::Home(Axis::Turntable));
    d.advance(Duration::from_secs(30));
    lines(&mut d);
    send(&mut d, 2, Command::MoveAbs(Axis::Turntable, 360_000));
    d.advance(d.now() + Duration::from_secs(1));
    assert_eq!(
        send(&mut d, 3, Command::Stop(Some(Axis::Turntable))).0,
        Reply::Ok
    );
    d.advance(d.now() + Duration::from_secs(2));
    let out = lines(&mut d);
    match event(&out[0]) {
        Event::Done {
            seq,
            end: DoneEnd::Stopped,
            pos,
            ..
        } => {
            assert_eq!(seq.get(), 2);
            assert!(pos > 0 && pos < 360_000, "{pos}");
        }
        e => panic!("{e:?}"),
    }
    assert!(d.position(Axis::Turntable).is_some(), "STOP keeps homing");
    send(&mut d, 4, Command::MoveAbs(Axis::Turntable, 0));
    let (r, ev) = send(&mut d, 5, Command::Estop);
    assert_eq!(r, Reply::Ok);
    assert!(matches!(
        event(&ev[0]),
        Event::Done {
            end: DoneEnd::Aborted,
            ..
        }
    ));
    assert_eq!(
        event(&ev[1]),
        Event::Fault {
            code: FaultCode::Estop,
            axis: None
        }
    );
    assert_eq!(
        send(&mut d, 6, Command::Home(Axis::Turntable)).0,
        Reply::Err(ErrorCode::Estop)
    );
    assert_eq!(send(&mut d, 7, Command::Ping).0, Reply::Ok);
    assert_eq!(send(&mut d, 8, Command::Clear).0, Reply::Ok);
    assert_eq!(
        send(&mut d, 9, Command::MoveAbs(Axis::Turntable, 0)).0,
        Reply::Err(ErrorCode::NotHomed)
    );
    let (r, ev) = send(&mut d, 10, Command::Reset);
    assert_eq!((r, ev.len()), (Reply::Ok, 0));
    d.advance(d.now() + Duration::from_secs(1));
    let out = lines(&mut d);
    assert!(matches!(
        event(&out[0]),
        Event::Boot {
            reason: firmware_protocol::BootReason::Reset,
            ..
        }
    ));
    assert_eq!(d.boots(), 2);
    // The reply cache is empty after boot: the old RESET line runs again (hosts must not retry
    // across a BOOT, as the spec says).
    let _ = CommandKind::Reset;
}
