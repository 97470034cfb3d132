//! The shared protocol test vectors (`tests/vectors.txt`), also read by the AVR firmware's host
//! unit test (`avr/test/test_proto.c`): both implementations agree on CRCs, framing, command
//! parsing, line assembly and the encoding of replies and events.

use firmware_protocol::*;

fn unescape(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if b[i] != b'\\' {
            out.push(b[i]);
            i += 1;
            continue;
        }
        let c = b[i + 1];
        i += 2;
        out.push(match c {
            b'n' => b'\n',
            b'r' => b'\r',
            b't' => b'\t',
            b'\\' => b'\\',
            b'x' => {
                let v = u8::from_str_radix(&s[i..i + 2], 16).expect("\\xNN escape");
                i += 2;
                v
            }
            other => panic!("bad escape \\{}", other as char),
        });
    }
    out
}

fn frame_err(e: FrameError) -> &'static str {
    match e {
        FrameError::NotAscii => "NOTASCII",
        FrameError::MissingCrc => "MISSINGCRC",
        FrameError::CrcMismatch { .. } => "CRC",
        FrameError::BadSeq => "BADSEQ",
        FrameError::EmptyBody => "EMPTYBODY",
    }
}

fn canonical(c: &Command) -> String {
    let mut s = c.kind().word().to_string();
    if let Some(a) = c.axis() {
        s += &format!(" {a}");
    }
    match c {
        Command::MoveAbs(_, v) | Command::MoveRel(_, v) => s += &format!(" {v}"),
        Command::Speed(_, v) | Command::Accel(_, v) => s += &format!(" {v}"),
        _ => {}
    }
    s
}

fn kind_by_word(w: &str) -> CommandKind {
    CommandKind::ALL
        .into_iter()
        .find(|k| k.word() == w)
        .unwrap_or_else(|| panic!("unknown command {w}"))
}

#[test]
fn shared_vectors() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/vectors.txt");
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut counts = std::collections::BTreeMap::new();
    let mut failures = Vec::new();
    for (n, raw) in text.lines().enumerate() {
        let lineno = n + 1;
        if raw.is_empty() || raw.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = raw.split('\t').collect();
        *counts.entry(f[0]).or_insert(0) += 1;
        let mut check = |what: &str, got: String, want: String| {
            if got != want {
                failures.push(format!(
                    "vectors.txt:{lineno}: {what}: got {got:?}, want {want:?}"
                ));
            }
        };
        match (f[0], f.len()) {
            ("crc", 3) => check(
                "crc",
                format!("{:04X}", crc16(&unescape(f[1]))),
                f[2].into(),
            ),
            ("frame", 3) => {
                let line = unescape(f[1]);
                let got = match Frame::parse(&line) {
                    Ok(fr) => {
                        let seq = match fr.seq {
                            SeqField::Seq(s) => s.to_string(),
                            SeqField::Event => "!".into(),
                        };
                        format!("OK {seq} {}", fr.body)
                    }
                    Err(e) => format!("ERR {}", frame_err(e)),
                };
                check("frame", got, f[2].into());
            }
            ("command", 3) => {
                let body = String::from_utf8(unescape(f[1])).expect("ASCII body");
                let got = match Command::parse(&body) {
                    Ok(c) => {
                        // Parsed commands also re-encode to the same body.
                        let mut buf = LineBuf::new();
                        encode_command(Seq::FIRST, &c, &mut buf).unwrap();
                        let enc = Frame::parse(&buf.as_bytes()[..buf.len() - 1]).unwrap();
                        assert_eq!(enc.body, canonical(&c), "vectors.txt:{lineno}: re-encoding");
                        canonical(&c)
                    }
                    Err(e) => format!("ERR {}", ErrorCode::for_parse_error(e).word()),
                };
                check("command", got, f[2].into());
            }
            ("stream", 2 | 3) => {
                let mut asm = LineAssembler::new();
                let mut lines = Vec::new();
                for b in unescape(f[1]) {
                    match asm.push(b) {
                        Some(Ok(l)) => lines.push(String::from_utf8_lossy(l).into_owned()),
                        Some(Err(LineError::TooLong)) => lines.push("TOOLONG".into()),
                        None => {}
                    }
                }
                let want = f.get(2).map(|w| unescape(w)).unwrap_or_default();
                check(
                    "stream",
                    lines.join("|"),
                    String::from_utf8_lossy(&want).into(),
                );
            }
            ("reply", 3) => {
                let fr = Frame::parse(f[2].as_bytes()).expect("reply vector frames");
                let SeqField::Seq(seq) = fr.seq else {
                    panic!("vectors.txt:{lineno}: a reply needs a sequence number")
                };
                let reply = Reply::parse(kind_by_word(f[1]), fr.body)
                    .unwrap_or_else(|e| panic!("vectors.txt:{lineno}: {e}"));
                let mut buf = LineBuf::new();
                encode_reply(seq, &reply, &mut buf).unwrap();
                check(
                    "reply",
                    String::from_utf8_lossy(buf.as_bytes()).into(),
                    format!("{}\n", f[2]),
                );
            }
            ("event", 2) => {
                let fr = Frame::parse(f[1].as_bytes()).expect("event vector frames");
                assert_eq!(fr.seq, SeqField::Event, "vectors.txt:{lineno}");
                let ev =
                    Event::parse(fr.body).unwrap_or_else(|e| panic!("vectors.txt:{lineno}: {e}"));
                let mut buf = LineBuf::new();
                encode_event(&ev, &mut buf).unwrap();
                check(
                    "event",
                    String::from_utf8_lossy(buf.as_bytes()).into(),
                    format!("{}\n", f[1]),
                );
            }
            _ => panic!("vectors.txt:{lineno}: unknown vector kind or field count: {raw:?}"),
        }
    }
    println!("vectors: {counts:?}");
    for k in ["crc", "frame", "command", "stream", "reply", "event"] {
        assert!(counts.get(k).copied().unwrap_or(0) > 0, "no {k} vectors");
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
