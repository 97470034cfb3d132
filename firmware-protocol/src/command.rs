//! Host→device commands: parsing (device side) and encoding (host side).

use crate::token::{parse_i32, parse_u32, words, ParseError};
use core::fmt::{self, Write};

/// A motion axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Axis {
    /// Axis 1: the turntable, positions in millidegrees (continuous rotation, no limits).
    Turntable,
    /// Axis 2 (optional, announced in `HELLO`): the camera-distance rail, in micrometres.
    Rail,
}

impl Axis {
    /// Wire number: 1 or 2.
    pub const fn number(self) -> u8 {
        match self {
            Axis::Turntable => 1,
            Axis::Rail => 2,
        }
    }

    /// Both axes, in wire order.
    pub const ALL: [Axis; 2] = [Axis::Turntable, Axis::Rail];

    /// Array index (0 or 1).
    pub const fn index(self) -> usize {
        self.number() as usize - 1
    }

    pub(crate) fn parse(s: &str) -> Result<Axis, ParseError> {
        match s {
            "1" => Ok(Axis::Turntable),
            "2" => Ok(Axis::Rail),
            _ if parse_u32(s).is_some() => Err(ParseError::NoSuchAxis),
            _ => Err(ParseError::BadArgument),
        }
    }
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.number())
    }
}

/// A command and its arguments.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `HELLO`: identify; replies with versions and capabilities.
    Hello,
    /// `PING`: liveness; replies `OK`.
    Ping,
    /// `HOME a`: find the axis' reference switch; replies `OK ETA=ms`, then `DONE`.
    Home(Axis),
    /// `MOVE_ABS a pos`: move to an absolute position; replies `OK ETA=ms`, then `DONE`.
    MoveAbs(Axis, i32),
    /// `MOVE_REL a delta`: move by a signed distance; replies `OK ETA=ms`, then `DONE`.
    MoveRel(Axis, i32),
    /// `SPEED a v`: cruise speed for later moves, units per second (> 0).
    Speed(Axis, u32),
    /// `ACCEL a acc`: acceleration for later moves, units per second² (> 0).
    Accel(Axis, u32),
    /// `STATUS a`: position, target, motion, homing, fault, last motion seq.
    Status(Axis),
    /// `STOP` (all axes) or `STOP a`: decelerate to a halt; the move ends with `DONE ... END=STOPPED`.
    Stop(Option<Axis>),
    /// `ESTOP`: halt at once, latch the `ESTOP` fault, forget homing.
    Estop,
    /// `CLEAR`: clear a latched fault.
    Clear,
    /// `RESET`: reply `OK`, then reboot (a `BOOT` event follows).
    Reset,
}

/// The kind of a [`Command`], without arguments (what a reply parser needs to know).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CommandKind {
    /// `HELLO`
    Hello,
    /// `PING`
    Ping,
    /// `HOME`
    Home,
    /// `MOVE_ABS`
    MoveAbs,
    /// `MOVE_REL`
    MoveRel,
    /// `SPEED`
    Speed,
    /// `ACCEL`
    Accel,
    /// `STATUS`
    Status,
    /// `STOP`
    Stop,
    /// `ESTOP`
    Estop,
    /// `CLEAR`
    Clear,
    /// `RESET`
    Reset,
}

impl CommandKind {
    /// The command word on the wire.
    pub const fn word(self) -> &'static str {
        match self {
            CommandKind::Hello => "HELLO",
            CommandKind::Ping => "PING",
            CommandKind::Home => "HOME",
            CommandKind::MoveAbs => "MOVE_ABS",
            CommandKind::MoveRel => "MOVE_REL",
            CommandKind::Speed => "SPEED",
            CommandKind::Accel => "ACCEL",
            CommandKind::Status => "STATUS",
            CommandKind::Stop => "STOP",
            CommandKind::Estop => "ESTOP",
            CommandKind::Clear => "CLEAR",
            CommandKind::Reset => "RESET",
        }
    }

    /// Every kind.
    pub const ALL: [CommandKind; 12] = [
        CommandKind::Hello,
        CommandKind::Ping,
        CommandKind::Home,
        CommandKind::MoveAbs,
        CommandKind::MoveRel,
        CommandKind::Speed,
        CommandKind::Accel,
        CommandKind::Status,
        CommandKind::Stop,
        CommandKind::Estop,
        CommandKind::Clear,
        CommandKind::Reset,
    ];

    fn from_word(w: &str) -> Option<CommandKind> {
        CommandKind::ALL.into_iter().find(|k| k.word() == w)
    }

    /// Whether a freshly booted device accepts it before the host's `HELLO` (read-only and
    /// safety commands); the others are answered `ERR BOOTED` until then.
    pub const fn allowed_before_hello(self) -> bool {
        matches!(
            self,
            CommandKind::Hello
                | CommandKind::Ping
                | CommandKind::Status
                | CommandKind::Stop
                | CommandKind::Estop
        )
    }

    /// Whether the command starts motion (and so ends with a `DONE` event).
    pub const fn is_motion(self) -> bool {
        matches!(
            self,
            CommandKind::Home | CommandKind::MoveAbs | CommandKind::MoveRel
        )
    }
}

impl Command {
    /// Its kind.
    pub const fn kind(&self) -> CommandKind {
        match self {
            Command::Hello => CommandKind::Hello,
            Command::Ping => CommandKind::Ping,
            Command::Home(_) => CommandKind::Home,
            Command::MoveAbs(..) => CommandKind::MoveAbs,
            Command::MoveRel(..) => CommandKind::MoveRel,
            Command::Speed(..) => CommandKind::Speed,
            Command::Accel(..) => CommandKind::Accel,
            Command::Status(_) => CommandKind::Status,
            Command::Stop(_) => CommandKind::Stop,
            Command::Estop => CommandKind::Estop,
            Command::Clear => CommandKind::Clear,
            Command::Reset => CommandKind::Reset,
        }
    }

    /// Parse a command body such as `MOVE_REL 2 -1500`. Never panics.
    pub fn parse(body: &str) -> Result<Command, ParseError> {
        let (w, n) = words::<4>(body).map_err(|_| match body.split(' ').next() {
            Some(first) if CommandKind::from_word(first).is_none() => ParseError::UnknownCommand,
            _ => ParseError::BadArgument,
        })?;
        let kind = CommandKind::from_word(w[0]).ok_or(ParseError::UnknownCommand)?;
        let args = &w[1..n];
        let num = |s: &str| parse_i32(s).ok_or(ParseError::BadArgument);
        let unum = |s: &str| parse_u32(s).ok_or(ParseError::BadArgument);
        let cmd = match (kind, args) {
            (CommandKind::Hello, []) => Command::Hello,
            (CommandKind::Ping, []) => Command::Ping,
            (CommandKind::Estop, []) => Command::Estop,
            (CommandKind::Clear, []) => Command::Clear,
            (CommandKind::Reset, []) => Command::Reset,
            (CommandKind::Stop, []) => Command::Stop(None),
            (CommandKind::Stop, [a]) => Command::Stop(Some(Axis::parse(a)?)),
            (CommandKind::Home, [a]) => Command::Home(Axis::parse(a)?),
            (CommandKind::Status, [a]) => Command::Status(Axis::parse(a)?),
            (CommandKind::MoveAbs, [a, p]) => Command::MoveAbs(Axis::parse(a)?, num(p)?),
            (CommandKind::MoveRel, [a, p]) => Command::MoveRel(Axis::parse(a)?, num(p)?),
            (CommandKind::Speed, [a, v]) => Command::Speed(Axis::parse(a)?, unum(v)?),
            (CommandKind::Accel, [a, v]) => Command::Accel(Axis::parse(a)?, unum(v)?),
            _ => return Err(ParseError::BadArgument),
        };
        Ok(cmd)
    }

    pub(crate) fn write_body<W: Write>(&self, w: &mut W) -> fmt::Result {
        w.write_str(self.kind().word())?;
        match *self {
            Command::Home(a) | Command::Status(a) | Command::Stop(Some(a)) => write!(w, " {a}"),
            Command::MoveAbs(a, p) | Command::MoveRel(a, p) => write!(w, " {a} {p}"),
            Command::Speed(a, v) | Command::Accel(a, v) => write!(w, " {a} {v}"),
            Command::Hello
            | Command::Ping
            | Command::Stop(None)
            | Command::Estop
            | Command::Clear
            | Command::Reset => Ok(()),
        }
    }

    /// The axis the command acts on, if it names one.
    pub const fn axis(&self) -> Option<Axis> {
        match *self {
            Command::Home(a)
            | Command::MoveAbs(a, _)
            | Command::MoveRel(a, _)
            | Command::Speed(a, _)
            | Command::Accel(a, _)
            | Command::Status(a)
            | Command::Stop(Some(a)) => Some(a),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_commands() {
        assert_eq!(Command::parse("HELLO"), Ok(Command::Hello));
        assert_eq!(
            Command::parse("MOVE_ABS 1 -90000"),
            Ok(Command::MoveAbs(Axis::Turntable, -90000))
        );
        assert_eq!(
            Command::parse("MOVE_REL 2 1500"),
            Ok(Command::MoveRel(Axis::Rail, 1500))
        );
        assert_eq!(Command::parse("STOP"), Ok(Command::Stop(None)));
        assert_eq!(
            Command::parse("STOP 2"),
            Ok(Command::Stop(Some(Axis::Rail)))
        );
        assert_eq!(
            Command::parse("SPEED 1 36000"),
            Ok(Command::Speed(Axis::Turntable, 36000))
        );
    }

    #[test]
    fn rejects_bad_commands() {
        assert_eq!(Command::parse("FLY 1"), Err(ParseError::UnknownCommand));
        assert_eq!(
            Command::parse("FLY 1 2 3 4 5"),
            Err(ParseError::UnknownCommand)
        );
        assert_eq!(
            Command::parse("move_abs 1 5"),
            Err(ParseError::UnknownCommand)
        );
        assert_eq!(Command::parse("MOVE_ABS 3 5"), Err(ParseError::NoSuchAxis));
        assert_eq!(Command::parse("MOVE_ABS 1"), Err(ParseError::BadArgument));
        assert_eq!(
            Command::parse("MOVE_ABS 1 5 6"),
            Err(ParseError::BadArgument)
        );
        assert_eq!(
            Command::parse("MOVE_ABS 1 5 6 7 8"),
            Err(ParseError::BadArgument)
        );
        assert_eq!(
            Command::parse("MOVE_ABS  1 5"),
            Err(ParseError::BadArgument)
        );
        assert_eq!(Command::parse("SPEED 1 -5"), Err(ParseError::BadArgument));
        assert_eq!(
            Command::parse("MOVE_ABS 1 2147483648"),
            Err(ParseError::BadArgument)
        );
        assert_eq!(Command::parse("PING 1"), Err(ParseError::BadArgument));
    }
}
