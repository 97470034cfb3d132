//! The simulated turntable firmware: a device state machine speaking `firmware-protocol`, with a
//! trapezoidal motion model, homing, rail soft limits, STOP/ESTOP, the one-entry reply cache,
//! and the BOOT banner after every start. Time is passed in explicitly, so it runs on a virtual
//! clock (in-memory tests) or on a real one (the pseudo-terminal harness) alike.

use super::motion::{eta_ms, Profile};
use firmware_protocol::{
    crc16, encode_event, encode_reply, Axis, BootReason, Command, DoneEnd, ErrorCode, Event,
    FaultCode, Frame, HelloInfo, LineAssembler, LineBuf, Reply, Seq, SeqField, StatusInfo,
    PROTOCOL_VERSION,
};
use std::collections::HashMap;
use std::time::Duration;

/// One full turn in millidegrees; the turntable's index mark is at every multiple of it.
pub(crate) const TURN_MDEG: i64 = 360_000;

/// What the simulated board is.
#[derive(Debug, Clone)]
pub struct DeviceConfig {
    /// Firmware name/version reported in HELLO and BOOT.
    pub fw: String,
    /// Rail soft limits in µm; `None` for a turntable without rail.
    pub rail: Option<(i32, i32)>,
    /// Default speed per axis (units/s), restored at boot.
    pub default_speed: [u32; 2],
    /// Default acceleration per axis (units/s²), restored at boot.
    pub default_accel: [u32; 2],
    /// Largest accepted speed per axis.
    pub max_speed: [u32; 2],
    /// Largest accepted acceleration per axis.
    pub max_accel: [u32; 2],
    /// Time from reset to the BOOT banner; input is ignored meanwhile.
    pub boot_time: Duration,
}

impl Default for DeviceConfig {
    fn default() -> Self {
        Self {
            fw: "cacsim-0.1".into(),
            rail: Some((0, 400_000)),
            default_speed: [90_000, 50_000],
            default_accel: [180_000, 100_000],
            max_speed: [720_000, 200_000],
            max_accel: [2_000_000, 1_000_000],
            boot_time: Duration::from_millis(300),
        }
    }
}

/// What a motion command was.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionKind {
    /// `HOME`
    Home,
    /// `MOVE_ABS` / `MOVE_REL`
    Move,
}

/// One motion the device started, for the test oracle.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionRecord {
    /// Sequence number of the command.
    pub seq: u16,
    /// Axis.
    pub axis: Axis,
    /// Home or move.
    pub kind: MotionKind,
    /// Commanded target in device coordinates (home position for HOME).
    pub target: i32,
    /// Boot number (1 = first boot) during which it started.
    pub boot: u32,
    /// How and where it ended; `None` while running or when a reset cut it off.
    pub end: Option<(DoneEnd, i32)>,
}

/// Counters of what the device saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeviceCounters {
    /// Well-framed command lines.
    pub lines: u64,
    /// Lines dropped for bad framing, CRC or length (no reply sent).
    pub framing_errors: u64,
    /// Retries answered from the reply cache.
    pub replays: u64,
    /// Bytes ignored because the device was booting.
    pub ignored_while_booting: u64,
}

#[derive(Debug, Clone)]
struct Motion {
    seq: Seq,
    start: Duration,
    profile: Profile,
    kind: MotionKind,
    end: DoneEnd,
    record: usize,
}

#[derive(Debug, Clone)]
struct AxisSim {
    /// Physical position (survives resets: the mechanics do not move when the MCU reboots).
    true_pos: f64,
    /// Device coordinate = physical − offset.
    offset: f64,
    homed: bool,
    target: i32,
    speed: u32,
    accel: u32,
    motion: Option<Motion>,
    last_seq: Option<Seq>,
}

/// The simulated controller.
#[derive(Debug)]
pub struct SimDevice {
    cfg: DeviceConfig,
    now: Duration,
    booting_until: Option<(Duration, BootReason)>,
    boots: u32,
    axes: [AxisSim; 2],
    fault: FaultCode,
    greeted: bool,
    cache: Option<(Seq, u16, Vec<u8>)>,
    asm: LineAssembler,
    out: Vec<u8>,
    log: Vec<MotionRecord>,
    starts: HashMap<u16, u32>,
    counters: DeviceCounters,
}

impl SimDevice {
    /// A device that has just been powered on at time `now` (its BOOT banner follows after
    /// `boot_time`). The turntable sits at a physical angle of `initial_angle` m°.
    pub fn new(cfg: DeviceConfig, now: Duration, initial_angle: f64) -> Self {
        let axis = |i: usize, pos: f64| AxisSim {
            true_pos: pos,
            offset: pos,
            homed: false,
            target: 0,
            speed: cfg.default_speed[i],
            accel: cfg.default_accel[i],
            motion: None,
            last_seq: None,
        };
        let rail_start = cfg
            .rail
            .map_or(0.0, |(lo, hi)| f64::from(lo) + f64::from(hi - lo) / 3.0);
        let mut d = Self {
            axes: [axis(0, initial_angle), axis(1, rail_start)],
            cfg,
            now,
            booting_until: None,
            boots: 0,
            fault: FaultCode::None,
            greeted: false,
            cache: None,
            asm: LineAssembler::new(),
            out: Vec::new(),
            log: Vec::new(),
            starts: HashMap::new(),
            counters: DeviceCounters::default(),
        };
        d.reset(BootReason::PowerOn);
        d
    }

    /// The device's clock.
    pub fn now(&self) -> Duration {
        self.now
    }

    /// Its configuration.
    pub fn config(&self) -> &DeviceConfig {
        &self.cfg
    }

    /// Number of boots so far (1 after power-on).
    pub fn boots(&self) -> u32 {
        self.boots
    }

    /// Every motion started, in order.
    pub fn log(&self) -> &[MotionRecord] {
        &self.log
    }

    /// How many motions were started by command `seq` (more than 1 means a retried command ran
    /// twice; the reply cache exists to prevent that).
    pub fn starts_for(&self, seq: u16) -> u32 {
        self.starts.get(&seq).copied().unwrap_or(0)
    }

    /// Largest number of starts of any one sequence number.
    pub fn max_starts_per_seq(&self) -> u32 {
        self.starts.values().copied().max().unwrap_or(0)
    }

    /// Line counters.
    pub fn counters(&self) -> DeviceCounters {
        self.counters
    }

    /// Whether the device is still booting (ignoring input).
    pub fn is_booting(&self) -> bool {
        self.booting_until.is_some()
    }

    fn has(&self, axis: Axis) -> bool {
        axis == Axis::Turntable || self.cfg.rail.is_some()
    }

    /// Device-coordinate position of `axis` if it is homed, else `None`.
    pub fn position(&self, axis: Axis) -> Option<i32> {
        let a = &self.axes[axis.index()];
        a.homed.then(|| self.reported(axis))
    }

    /// Whether `axis` is moving.
    pub(crate) fn is_moving(&self, axis: Axis) -> bool {
        self.axes[axis.index()].motion.is_some()
    }

    /// The latched fault.
    pub fn fault(&self) -> FaultCode {
        self.fault
    }

    fn physical_now(&self, axis: Axis) -> (f64, f64) {
        let a = &self.axes[axis.index()];
        match &a.motion {
            Some(m) => m.profile.at((self.now - m.start).as_secs_f64()),
            None => (a.true_pos, 0.0),
        }
    }

    fn reported(&self, axis: Axis) -> i32 {
        let p = self.physical_now(axis).0 - self.axes[axis.index()].offset;
        p.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }

    /// Take the bytes the device has sent.
    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }

    /// When something will happen on its own (end of boot, end of a motion).
    pub(crate) fn next_event_time(&self) -> Option<Duration> {
        let boot = self.booting_until.map(|(t, _)| t);
        let motions = self.axes.iter().filter_map(|a| {
            a.motion
                .as_ref()
                .map(|m| m.start + Duration::from_secs_f64(m.profile.duration()))
        });
        boot.into_iter().chain(motions).min()
    }

    /// Run the clock forward to `to`, finishing boots and motions in time order.
    pub fn advance(&mut self, to: Duration) {
        while let Some(t) = self.next_event_time().filter(|&t| t <= to) {
            self.now = self.now.max(t);
            if let Some((bt, reason)) = self.booting_until {
                if bt <= self.now {
                    self.booting_until = None;
                    let fw = self.cfg.fw.clone();
                    self.emit(&Event::Boot {
                        proto: PROTOCOL_VERSION,
                        fw: &fw,
                        reason,
                    });
                    continue;
                }
            }
            for axis in Axis::ALL {
                let due = self.axes[axis.index()].motion.as_ref().is_some_and(|m| {
                    m.start + Duration::from_secs_f64(m.profile.duration()) <= self.now
                });
                if due {
                    self.finish_motion(axis);
                }
            }
        }
        self.now = self.now.max(to);
    }

    fn finish_motion(&mut self, axis: Axis) {
        let Some(m) = self.axes[axis.index()].motion.take() else {
            return;
        };
        let pos = self.complete(axis, &m);
        self.emit(&Event::Done {
            seq: m.seq,
            axis,
            pos,
            end: m.end,
        });
    }

    /// Ends motion `m` of `axis` (already taken off the axis): the axis stands at the profile's
    /// end, homed when it was a homing that reached its switch; the log records how it ended.
    /// Returns the position the device reports.
    fn complete(&mut self, axis: Axis, m: &Motion) -> i32 {
        let home = if axis == Axis::Rail {
            self.cfg.rail.map_or(0, |r| r.0)
        } else {
            0
        };
        let a = &mut self.axes[axis.index()];
        a.true_pos = m.profile.end();
        if m.kind == MotionKind::Home && m.end == DoneEnd::Reached {
            a.offset = a.true_pos - f64::from(home);
            a.homed = true;
        }
        let pos = self.reported(axis);
        self.log[m.record].end = Some((m.end, pos));
        pos
    }

    /// Reboot now: motion halts where it is, homing, settings, fault and reply cache are lost,
    /// the BOOT banner follows after `boot_time`.
    pub fn reset(&mut self, reason: BootReason) {
        for axis in Axis::ALL {
            let (pos, _) = self.physical_now(axis);
            let cfg = &self.cfg;
            let a = &mut self.axes[axis.index()];
            a.motion = None;
            a.true_pos = pos;
            a.offset = pos;
            a.homed = false;
            a.target = 0;
            a.last_seq = None;
            a.speed = cfg.default_speed[axis.index()];
            a.accel = cfg.default_accel[axis.index()];
        }
        self.fault = FaultCode::None;
        self.greeted = false;
        self.cache = None;
        self.asm.clear();
        self.out.clear();
        self.boots += 1;
        self.booting_until = Some((self.now + self.cfg.boot_time, reason));
    }

    /// Bytes arriving from the host at the device's current time.
    pub fn receive(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if self.booting_until.is_some() {
                self.counters.ignored_while_booting += 1;
                continue;
            }
            let line = match self.asm.push(b) {
                None => continue,
                Some(Err(_)) => {
                    self.counters.framing_errors += 1;
                    continue;
                }
                Some(Ok(l)) => l.to_vec(),
            };
            self.handle_line(&line);
        }
    }

    fn handle_line(&mut self, line: &[u8]) {
        let frame = match Frame::parse(line) {
            Ok(Frame {
                seq: SeqField::Seq(s),
                body,
            }) => (s, body),
            _ => {
                self.counters.framing_errors += 1;
                return;
            }
        };
        let (seq, body) = frame;
        self.counters.lines += 1;
        let crc = crc16(&line[..line.len() - 6]);
        if let Some((cs, cc, bytes)) = &self.cache {
            if *cs == seq && *cc == crc {
                self.counters.replays += 1;
                let bytes = bytes.clone();
                self.out.extend_from_slice(&bytes);
                return;
            }
        }
        let mut after = Vec::new();
        let mut reset = false;
        let reply = match Command::parse(body) {
            Err(e) => Reply::Err(ErrorCode::for_parse_error(e)),
            Ok(cmd) => self.execute(seq, cmd, &mut after, &mut reset),
        };
        let fw = self.cfg.fw.clone();
        let reply = match reply {
            Reply::Hello(h) => Reply::Hello(HelloInfo { fw: &fw, ..h }),
            r => r,
        };
        let mut buf = LineBuf::new();
        encode_reply(seq, &reply, &mut buf).expect("device replies fit in a line");
        self.out.extend_from_slice(buf.as_bytes());
        self.cache = Some((seq, crc, buf.as_bytes().to_vec()));
        for ev in after {
            self.emit_owned(ev);
        }
        if reset {
            // The reply leaves the UART before the reboot.
            let reply = std::mem::take(&mut self.out);
            self.reset(BootReason::Reset);
            self.out = reply;
        }
    }

    fn emit(&mut self, ev: &Event<'_>) {
        let mut buf = LineBuf::new();
        encode_event(ev, &mut buf).expect("device events fit in a line");
        self.out.extend_from_slice(buf.as_bytes());
    }

    fn emit_owned(&mut self, ev: OwnedEvent) {
        match ev {
            OwnedEvent::Done(seq, axis, pos, end) => self.emit(&Event::Done {
                seq,
                axis,
                pos,
                end,
            }),
            OwnedEvent::Fault(code) => self.emit(&Event::Fault { code, axis: None }),
        }
    }

    fn execute(
        &mut self,
        seq: Seq,
        cmd: Command,
        after: &mut Vec<OwnedEvent>,
        reset: &mut bool,
    ) -> Reply<'static> {
        if let Some(axis) = cmd.axis() {
            if !self.has(axis) {
                return Reply::Err(ErrorCode::NoAxis);
            }
        }
        if !self.greeted && !cmd.kind().allowed_before_hello() {
            return Reply::Err(ErrorCode::Booted);
        }
        match cmd {
            Command::Hello => {
                self.greeted = true;
                Reply::Hello(HelloInfo {
                    proto: PROTOCOL_VERSION,
                    fw: "",
                    rail: self.cfg.rail,
                })
            }
            Command::Ping => Reply::Ok,
            Command::Speed(axis, v) | Command::Accel(axis, v) => {
                let i = axis.index();
                let is_speed = matches!(cmd, Command::Speed(..));
                let max = if is_speed {
                    self.cfg.max_speed[i]
                } else {
                    self.cfg.max_accel[i]
                };
                if v == 0 || v > max {
                    return Reply::Err(ErrorCode::Range);
                }
                if is_speed {
                    self.axes[i].speed = v;
                } else {
                    self.axes[i].accel = v;
                }
                Reply::Ok
            }
            Command::Status(axis) => {
                let a = &self.axes[axis.index()];
                Reply::Status(StatusInfo {
                    pos: self.reported(axis),
                    target: a.target,
                    moving: a.motion.is_some(),
                    homed: a.homed,
                    fault: self.fault,
                    seq: a.last_seq,
                })
            }
            Command::Home(axis) => self.start_home(seq, axis, after),
            Command::MoveAbs(axis, p) => self.start_move(seq, axis, Some(p), after),
            Command::MoveRel(axis, d) => {
                let target = i64::from(self.reported(axis)) + i64::from(d);
                match i32::try_from(target) {
                    Ok(t) => self.start_move(seq, axis, Some(t), after),
                    Err(_) => self.start_move(seq, axis, None, after),
                }
            }
            Command::Stop(which) => {
                for axis in Axis::ALL {
                    if which.is_none_or(|w| w == axis) {
                        self.stop_axis(axis);
                    }
                }
                Reply::Ok
            }
            Command::Estop => {
                for axis in Axis::ALL {
                    let (pos, _) = self.physical_now(axis);
                    let a = &mut self.axes[axis.index()];
                    a.homed = false;
                    if let Some(mut m) = a.motion.take() {
                        a.true_pos = pos;
                        m.end = DoneEnd::Aborted;
                        let p = self.reported(axis);
                        self.log[m.record].end = Some((DoneEnd::Aborted, p));
                        after.push(OwnedEvent::Done(m.seq, axis, p, DoneEnd::Aborted));
                    }
                }
                self.fault = FaultCode::Estop;
                after.push(OwnedEvent::Fault(FaultCode::Estop));
                Reply::Ok
            }
            Command::Clear => {
                self.fault = FaultCode::None;
                Reply::Ok
            }
            Command::Reset => {
                *reset = true;
                Reply::Ok
            }
        }
    }

    fn motion_refusal(&self, axis: Axis) -> Option<ErrorCode> {
        match self.fault {
            FaultCode::None => {}
            FaultCode::Estop => return Some(ErrorCode::Estop),
            _ => return Some(ErrorCode::Fault),
        }
        self.axes[axis.index()]
            .motion
            .is_some()
            .then_some(ErrorCode::Busy)
    }

    fn start_home(&mut self, seq: Seq, axis: Axis, after: &mut Vec<OwnedEvent>) -> Reply<'static> {
        if let Some(e) = self.motion_refusal(axis) {
            return Reply::Err(e);
        }
        let a = &self.axes[axis.index()];
        let (from, home_target, worst) = match (axis, self.cfg.rail) {
            (Axis::Rail, Some((lo, hi))) => (a.true_pos, f64::from(lo), f64::from(hi - lo)),
            _ => {
                let next_mark = (a.true_pos / TURN_MDEG as f64).ceil() * TURN_MDEG as f64;
                (a.true_pos, next_mark, TURN_MDEG as f64)
            }
        };
        let (v, acc) = (f64::from(a.speed), f64::from(a.accel));
        let profile = Profile::Trapezoid {
            from,
            to: home_target,
            v,
            a: acc,
        };
        let worst = eta_ms(&Profile::Trapezoid {
            from: 0.0,
            to: worst,
            v,
            a: acc,
        });
        let home = if axis == Axis::Rail {
            self.cfg.rail.map_or(0, |r| r.0)
        } else {
            0
        };
        self.begin(seq, axis, MotionKind::Home, home, profile, after);
        Reply::Moving { eta_ms: worst }
    }

    fn start_move(
        &mut self,
        seq: Seq,
        axis: Axis,
        target: Option<i32>,
        after: &mut Vec<OwnedEvent>,
    ) -> Reply<'static> {
        if let Some(e) = self.motion_refusal(axis) {
            return Reply::Err(e);
        }
        let a = &self.axes[axis.index()];
        if !a.homed {
            return Reply::Err(ErrorCode::NotHomed);
        }
        let Some(target) = target else {
            return Reply::Err(ErrorCode::Range);
        };
        if let (Axis::Rail, Some((lo, hi))) = (axis, self.cfg.rail) {
            if target < lo || target > hi {
                return Reply::Err(ErrorCode::Limit);
            }
        }
        let profile = Profile::Trapezoid {
            from: a.true_pos,
            to: f64::from(target) + a.offset,
            v: f64::from(a.speed),
            a: f64::from(a.accel),
        };
        let eta = eta_ms(&profile);
        self.begin(seq, axis, MotionKind::Move, target, profile, after);
        Reply::Moving { eta_ms: eta }
    }

    fn begin(
        &mut self,
        seq: Seq,
        axis: Axis,
        kind: MotionKind,
        target: i32,
        profile: Profile,
        after: &mut Vec<OwnedEvent>,
    ) {
        *self.starts.entry(seq.get()).or_default() += 1;
        self.log.push(MotionRecord {
            seq: seq.get(),
            axis,
            kind,
            target,
            boot: self.boots,
            end: None,
        });
        let a = &mut self.axes[axis.index()];
        a.target = target;
        a.last_seq = Some(seq);
        if kind == MotionKind::Home {
            a.homed = false;
        }
        a.motion = Some(Motion {
            seq,
            start: self.now,
            profile,
            kind,
            end: DoneEnd::Reached,
            record: self.log.len() - 1,
        });
        if profile.duration() == 0.0 {
            // Zero-length: DONE right after the reply.
            let m = self.axes[axis.index()].motion.take().expect("just set");
            let pos = self.complete(axis, &m);
            after.push(OwnedEvent::Done(seq, axis, pos, DoneEnd::Reached));
        }
    }

    fn stop_axis(&mut self, axis: Axis) {
        let (pos, vel) = self.physical_now(axis);
        let acc = f64::from(self.axes[axis.index()].accel);
        let now = self.now;
        let a = &mut self.axes[axis.index()];
        if let Some(m) = a.motion.as_mut() {
            if m.end == DoneEnd::Reached {
                m.end = DoneEnd::Stopped;
                m.start = now;
                m.profile = Profile::Decel {
                    from: pos,
                    v0: vel,
                    a: acc,
                };
            }
        }
    }

    /// Physical (mechanical) position of `axis`, independent of homing: what a camera would see.
    pub(crate) fn physical_position(&self, axis: Axis) -> f64 {
        self.physical_now(axis).0
    }
}

#[derive(Debug, Clone, Copy)]
enum OwnedEvent {
    Done(Seq, Axis, i32, DoneEnd),
    Fault(FaultCode),
}
