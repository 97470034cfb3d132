//! Property tests: the parsers never panic on arbitrary bytes, every message round-trips through
//! encode → line assembly → parse, and any single corrupted byte in a line is detected.

use firmware_protocol::*;
use proptest::prelude::*;

/// Push bytes through the whole receive path, as a device and as a host would. Returns the
/// number of lines that framed correctly (so the work cannot be optimised away).
fn feed_everything(bytes: &[u8]) -> usize {
    let mut asm = LineAssembler::new();
    let mut framed = 0;
    for &b in bytes {
        if let Some(Ok(line)) = asm.push(b) {
            if let Ok(frame) = Frame::parse(line) {
                framed += 1;
                let _ = Command::parse(frame.body);
                let _ = Event::parse(frame.body);
                for kind in CommandKind::ALL {
                    let _ = Reply::parse(kind, frame.body);
                }
            }
            // Also parse bodies that did not frame, to reach the body parsers with raw junk.
            if let Ok(body) = core::str::from_utf8(line) {
                let _ = Command::parse(body);
                let _ = Event::parse(body);
                for kind in CommandKind::ALL {
                    let _ = Reply::parse(kind, body);
                }
            }
        }
    }
    framed
}

fn axis() -> impl Strategy<Value = Axis> {
    prop_oneof![Just(Axis::Turntable), Just(Axis::Rail)]
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Hello),
        Just(Command::Ping),
        Just(Command::Estop),
        Just(Command::Clear),
        Just(Command::Reset),
        axis().prop_map(Command::Home),
        axis().prop_map(Command::Status),
        proptest::option::of(axis()).prop_map(Command::Stop),
        (axis(), any::<i32>()).prop_map(|(a, p)| Command::MoveAbs(a, p)),
        (axis(), any::<i32>()).prop_map(|(a, p)| Command::MoveRel(a, p)),
        (axis(), any::<u32>()).prop_map(|(a, v)| Command::Speed(a, v)),
        (axis(), any::<u32>()).prop_map(|(a, v)| Command::Accel(a, v)),
    ]
}

fn fault() -> impl Strategy<Value = FaultCode> {
    prop_oneof![
        Just(FaultCode::None),
        Just(FaultCode::Estop),
        Just(FaultCode::Limit),
        Just(FaultCode::Stall)
    ]
}

fn error_code() -> impl Strategy<Value = ErrorCode> {
    prop_oneof![
        Just(ErrorCode::BadCmd),
        Just(ErrorCode::BadArg),
        Just(ErrorCode::NoAxis),
        Just(ErrorCode::Range),
        Just(ErrorCode::Limit),
        Just(ErrorCode::NotHomed),
        Just(ErrorCode::Busy),
        Just(ErrorCode::Estop),
        Just(ErrorCode::Fault),
        Just(ErrorCode::Booted),
    ]
}

const FW: &str = "[!-)+-<>-~]{1,24}"; // printable, no space, '*' or '='

/// Assemble one encoded line and return its framed body (asserting exactly one line comes out).
fn reassemble(buf: &LineBuf) -> (SeqField, String) {
    let mut asm = LineAssembler::new();
    let mut out = None;
    for &b in buf.as_bytes() {
        if let Some(r) = asm.push(b) {
            assert!(out.is_none(), "two lines from one encoding");
            let f = Frame::parse(r.expect("fits")).expect("frames");
            out = Some((f.seq, f.body.to_string()));
        }
    }
    out.expect("one line")
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(4096)
    ))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        feed_everything(&bytes);
    }

    #[test]
    fn near_valid_text_never_panics(
        words in proptest::collection::vec(
            "(HELLO|PING|MOVE_ABS|MOVE_REL|SPEED|ACCEL|STATUS|STOP|ESTOP|OK|ERR|BOOT|DONE|FAULT|[0-9!-]{1,12}|[A-Z]{1,6}=[-0-9:A-Z]{0,12}| )",
            0..12,
        ),
        seq in "(!|[0-9]{1,6})",
    ) {
        // Well-framed lines (valid CRC) whose bodies are random word salad.
        let body = words.concat();
        let mut line = format!("{seq} {body}");
        let crc = crc16(line.as_bytes());
        line.push_str(&format!(" *{crc:04X}\n"));
        feed_everything(line.as_bytes());
    }

    #[test]
    fn commands_round_trip(cmd in command(), seq in 1u16..) {
        let seq = Seq::new(seq).unwrap();
        let mut buf = LineBuf::new();
        encode_command(seq, &cmd, &mut buf).unwrap();
        prop_assert!(buf.len() <= MAX_LINE + 1);
        let (s, body) = reassemble(&buf);
        prop_assert_eq!(s, SeqField::Seq(seq));
        prop_assert_eq!(Command::parse(&body), Ok(cmd));
    }

    #[test]
    fn replies_round_trip(
        seq in 1u16..,
        pick in 0u8..5,
        fw in FW,
        rail in proptest::option::of((any::<i32>(), any::<i32>())),
        (pos, target, eta) in (any::<i32>(), any::<i32>(), any::<u32>()),
        (moving, homed, fault, s) in (any::<bool>(), any::<bool>(), fault(), any::<u16>()),
        code in error_code(),
    ) {
        let rail = rail.map(|(a, b)| (a.min(b), a.max(b)));
        let (kind, reply) = match pick {
            0 => (CommandKind::Ping, Reply::Ok),
            1 => (CommandKind::Hello, Reply::Hello(HelloInfo { proto: 1, fw: &fw, rail })),
            2 => (CommandKind::MoveRel, Reply::Moving { eta_ms: eta }),
            3 => (CommandKind::Status, Reply::Status(StatusInfo {
                pos, target, moving, homed, fault, seq: Seq::new(s),
            })),
            _ => (CommandKind::MoveAbs, Reply::Err(code)),
        };
        let mut buf = LineBuf::new();
        encode_reply(Seq::new(seq).unwrap(), &reply, &mut buf).unwrap();
        let (f, body) = reassemble(&buf);
        prop_assert_eq!(f, SeqField::Seq(Seq::new(seq).unwrap()));
        prop_assert_eq!(Reply::parse(kind, &body), Ok(reply));
    }

    #[test]
    fn events_round_trip(
        pick in 0u8..3,
        fw in FW,
        seq in 1u16..,
        pos in any::<i32>(),
        ax in axis(),
        code in fault(),
        with_axis in any::<bool>(),
    ) {
        let ev = match pick {
            0 => Event::Boot { proto: PROTOCOL_VERSION, fw: &fw, reason: BootReason::Watchdog },
            1 => Event::Done { seq: Seq::new(seq).unwrap(), axis: ax, pos, end: DoneEnd::Stopped },
            _ => Event::Fault { code, axis: with_axis.then_some(ax) },
        };
        let mut buf = LineBuf::new();
        encode_event(&ev, &mut buf).unwrap();
        let (f, body) = reassemble(&buf);
        prop_assert_eq!(f, SeqField::Event);
        prop_assert_eq!(Event::parse(&body), Ok(ev));
    }

    #[test]
    fn any_single_corrupted_byte_is_detected(
        cmd in command(), seq in 1u16.., at in any::<prop::sample::Index>(), new in any::<u8>(),
    ) {
        let mut buf = LineBuf::new();
        encode_command(Seq::new(seq).unwrap(), &cmd, &mut buf).unwrap();
        let mut line = buf.as_bytes()[..buf.len() - 1].to_vec();
        let i = at.index(line.len());
        prop_assume!(line[i] != new && new != b'\n');
        line[i] = new;
        prop_assert!(Frame::parse(&line).is_err(), "corruption at {} undetected: {:?}", i, line);
    }
}

#[test]
fn crc_test_vector() {
    assert_eq!(crc16(b"123456789"), 0x29B1);
}

/// The examples printed in docs/protocol.md, byte for byte (keeps the spec honest).
#[test]
fn spec_examples_are_valid() {
    let spec = include_str!("../../docs/protocol.md");
    let mut checked = 0;
    for line in spec.lines() {
        let is_example = |l: &&str| {
            let b = l.as_bytes();
            b.len() > 6 && &b[b.len() - 6..b.len() - 4] == b" *" && !l.contains('<')
        };
        let Some(ex) = line.strip_prefix("    ").filter(is_example) else {
            continue;
        };
        let ex = ex.trim_start_matches("→ ").trim_start_matches("← ");
        let f = Frame::parse(ex.as_bytes()).unwrap_or_else(|e| panic!("{ex}: {e}"));
        match f.seq {
            SeqField::Event => {
                Event::parse(f.body).unwrap_or_else(|e| panic!("{ex}: {e}"));
            }
            SeqField::Seq(_) => {
                let ok = Command::parse(f.body).is_ok()
                    || CommandKind::ALL
                        .iter()
                        .any(|&k| Reply::parse(k, f.body).is_ok());
                assert!(ok, "{ex}: neither a command nor a reply");
            }
        }
        checked += 1;
    }
    assert!(
        checked >= 20,
        "only {checked} examples found in docs/protocol.md"
    );
}

/// A deterministic brute-force sweep: every line made of up to three bytes from an alphabet of
/// protocol-significant characters, plus random long streams from a seeded generator.
#[test]
fn brute_force_short_lines() {
    let alphabet = b" *!0129AFOKER=-:\r\n\x00\xff";
    let mut n = 0usize;
    let mut line = Vec::new();
    for a in alphabet {
        for b in alphabet {
            for c in alphabet {
                line.clear();
                line.extend_from_slice(&[*a, *b, *c, b'\n']);
                feed_everything(&line);
                n += 1;
            }
        }
    }
    assert_eq!(n, alphabet.len().pow(3));
}
