//! Line level of the turntable driver: one command with retries under the same sequence
//! number, resynchronisation, reopening a vanished link, waiting for BOOT, reading lines and
//! applying events to the driver's state.

use super::{Result, Turntable, TurntableError};
use crate::transport::Transport;
use firmware_protocol::{
    encode_command, Command, ErrorCode, Event, FaultCode, Frame, LineBuf, Reply, Seq, SeqField,
    StatusInfo,
};
use std::io;
use std::time::Duration;

#[derive(Debug, Clone, PartialEq)]
pub(super) enum OwnedReply {
    Ok,
    Hello {
        proto: u16,
        fw: String,
        rail: Option<(i32, i32)>,
    },
    Moving(u32),
    Status(StatusInfo),
    Err(ErrorCode),
}

pub(super) enum Msg {
    Reply(Seq, String),
    Event,
}

impl<T: Transport> Turntable<T> {
    pub(super) fn next_seq(&mut self) -> Seq {
        self.seq = self.seq.next();
        self.done.remove(&self.seq.get());
        self.stats.commands += 1;
        self.seq
    }

    pub(super) fn transact(
        &mut self,
        cmd: Command,
        deadline: Duration,
    ) -> Result<(Seq, OwnedReply)> {
        loop {
            if self.needs_hello && !cmd.kind().allowed_before_hello() {
                self.hello(deadline)?;
            }
            let seq = self.next_seq();
            match self.transact_seq(seq, cmd, deadline) {
                // The device rebooted meanwhile: ask again under a new number.
                Err(TurntableError::DeviceReset { .. }) => continue,
                // It rebooted and the BOOT banner was lost: greet it, then ask again.
                Ok(OwnedReply::Err(ErrorCode::Booted)) if self.t.now() < deadline => {
                    self.note_reset();
                }
                r => return Ok((seq, r?)),
            }
        }
    }

    /// Send `cmd` as `seq` until its reply arrives, resending the identical line on silence.
    pub(super) fn transact_seq(
        &mut self,
        seq: Seq,
        cmd: Command,
        deadline: Duration,
    ) -> Result<OwnedReply> {
        let mut line = LineBuf::new();
        encode_command(seq, &cmd, &mut line)
            .map_err(|e| TurntableError::Protocol(format!("cannot encode {cmd:?}: {e}")))?;
        let start = self.t.now();
        let deadline = deadline.min(start + self.cfg.command_deadline);
        let boots = self.boots;
        let mut attempts = 0u32;
        loop {
            // After a BOOT the device's reply cache is empty: resending this line could run the
            // command a second time, so it is abandoned (the caller re-evaluates).
            if self.boots != boots {
                return Err(TurntableError::DeviceReset {
                    cmd: cmd.kind().word(),
                });
            }
            if self.t.now() >= deadline {
                return Err(TurntableError::Timeout {
                    cmd: cmd.kind().word(),
                    waited: self.t.now() - start,
                });
            }
            if attempts > 0 {
                self.stats.retries += 1;
                if attempts % self.cfg.resync_after.max(1) == 0 {
                    self.soft_resync();
                }
            }
            attempts += 1;
            if let Err(e) = self.t.write_all(line.as_bytes()) {
                self.link_failed(e, deadline)?;
                continue;
            }
            let until = (self.t.now() + self.cfg.attempt_timeout).min(deadline);
            loop {
                match self.next_message(until) {
                    Err(e) => {
                        self.link_failed(e, deadline)?;
                        break;
                    }
                    Ok(None) => break,
                    Ok(Some(Msg::Event)) if self.boots != boots => break,
                    Ok(Some(Msg::Reply(s, body))) if s == seq => {
                        match Reply::parse(cmd.kind(), &body) {
                            Ok(r) => return Ok(own(r)),
                            Err(_) => self.stats.bad_lines += 1,
                        }
                    }
                    Ok(Some(_)) => {}
                }
            }
        }
    }

    /// Newline (ends any partial line at the device), short pause, drop pending input.
    pub(super) fn soft_resync(&mut self) {
        self.stats.resyncs += 1;
        if self.t.write_all(b"\n").is_ok() {
            self.t.pause(Duration::from_millis(20));
            let _ = self.t.discard_input();
        }
        self.pending.clear();
        self.asm.clear();
    }

    /// Full resynchronisation: newline, flush, PING until answered.
    pub(super) fn resync(&mut self, deadline: Duration) -> Result<()> {
        self.soft_resync();
        match self.transact(Command::Ping, deadline)?.1 {
            OwnedReply::Ok => Ok(()),
            r => Err(unexpected("PING", r)),
        }
    }

    /// The link failed: reopen it (until the reconnect deadline), then wait for a BOOT banner.
    pub(super) fn link_failed(&mut self, mut err: io::Error, deadline: Duration) -> Result<()> {
        let start = self.t.now();
        let until = deadline.min(start + self.cfg.reconnect_deadline).max(start);
        loop {
            self.stats.reconnects += 1;
            self.pending.clear();
            self.asm.clear();
            loop {
                match self.t.reopen() {
                    Ok(()) => break,
                    Err(e) if self.t.now() < until => {
                        err = e;
                        self.t.pause(self.cfg.reconnect_backoff);
                    }
                    Err(e) => {
                        return Err(TurntableError::Disconnected {
                            waited: self.t.now() - start,
                            source: e,
                        })
                    }
                }
            }
            match self.wait_for_boot(self.cfg.boot_wait) {
                Ok(_) => {
                    let _ = self.t.write_all(b"\n");
                    return Ok(());
                }
                Err(e) if self.t.now() < until => err = e,
                Err(e) => {
                    let _ = err;
                    return Err(TurntableError::Disconnected {
                        waited: self.t.now() - start,
                        source: e,
                    });
                }
            }
        }
    }

    /// Read until a BOOT event arrives or `wait` passes. Returns whether one came.
    pub(super) fn wait_for_boot(&mut self, wait: Duration) -> io::Result<bool> {
        let boots = self.boots;
        let until = self.t.now() + wait;
        while self.boots == boots {
            if self.next_message(until)?.is_none() {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// The next well-framed line before `until`; events are applied to the driver state.
    pub(super) fn next_message(&mut self, until: Duration) -> io::Result<Option<Msg>> {
        let mut buf = [0u8; 256];
        loop {
            while let Some(b) = self.pending.pop_front() {
                let line = match self.asm.push(b) {
                    None => continue,
                    Some(Err(_)) => {
                        self.stats.bad_lines += 1;
                        continue;
                    }
                    Some(Ok(l)) => l.to_vec(),
                };
                match Frame::parse(&line) {
                    Ok(Frame {
                        seq: SeqField::Seq(s),
                        body,
                    }) => return Ok(Some(Msg::Reply(s, body.to_string()))),
                    Ok(Frame {
                        seq: SeqField::Event,
                        body,
                    }) => match Event::parse(body) {
                        Ok(ev) => {
                            self.apply_event(ev);
                            return Ok(Some(Msg::Event));
                        }
                        Err(_) => self.stats.bad_lines += 1,
                    },
                    Err(_) => self.stats.bad_lines += 1,
                }
            }
            let now = self.t.now();
            if now >= until {
                return Ok(None);
            }
            let n = self.t.read(&mut buf, until - now)?;
            self.pending.extend(&buf[..n]);
        }
    }

    pub(super) fn note_reset(&mut self) {
        self.boots += 1;
        self.needs_hello = true;
        self.stats.resets_seen += 1;
        for a in &mut self.axes {
            a.homed = false;
            a.pos = None;
            a.settings_lost = true;
        }
    }

    pub(super) fn apply_event(&mut self, ev: Event<'_>) {
        match ev {
            Event::Boot { .. } => {
                self.note_reset();
                self.fault = FaultCode::None;
            }
            Event::Done {
                seq,
                axis,
                pos,
                end,
            } => {
                self.done.insert(seq.get(), (axis, pos, end));
            }
            Event::Fault { code, .. } => {
                self.fault = code;
                for a in &mut self.axes {
                    a.homed = false;
                }
            }
        }
    }
}

pub(super) fn own(r: Reply<'_>) -> OwnedReply {
    match r {
        Reply::Ok => OwnedReply::Ok,
        Reply::Hello(h) => OwnedReply::Hello {
            proto: h.proto,
            fw: h.fw.to_string(),
            rail: h.rail,
        },
        Reply::Moving { eta_ms } => OwnedReply::Moving(eta_ms),
        Reply::Status(s) => OwnedReply::Status(s),
        Reply::Err(c) => OwnedReply::Err(c),
    }
}

pub(super) fn unexpected(cmd: &str, r: OwnedReply) -> TurntableError {
    TurntableError::Protocol(format!("unexpected reply to {cmd}: {r:?}"))
}
