//! Fuzz target: arbitrary bytes through the whole receive path (line assembly, framing and CRC,
//! command/reply/event parsing), then re-encoding whatever parsed and checking it parses back.
#![no_main]

use firmware_protocol::*;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut asm = LineAssembler::new();
    for &b in data {
        let Some(Ok(line)) = asm.push(b) else { continue };
        let Ok(frame) = Frame::parse(line) else { continue };
        let mut out = LineBuf::new();
        if let Ok(cmd) = Command::parse(frame.body) {
            if let SeqField::Seq(seq) = frame.seq {
                encode_command(seq, &cmd, &mut out).expect("a parsed command re-encodes");
                let again = Frame::parse(&out.as_bytes()[..out.len() - 1]).expect("re-framed");
                assert_eq!(Command::parse(again.body), Ok(cmd));
            }
        }
        if let Ok(ev) = Event::parse(frame.body) {
            // Events with unknown words parse to `Other`; re-encoding those is allowed to differ.
            let _ = encode_event(&ev, &mut out);
        }
        for kind in CommandKind::ALL {
            if let (Ok(r), SeqField::Seq(seq)) = (Reply::parse(kind, frame.body), frame.seq) {
                let _ = encode_reply(seq, &r, &mut out);
            }
        }
    }
});
