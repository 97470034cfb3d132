//! Body tokenising helpers shared by the command, reply and event parsers: strict decimal numbers
//! and `KEY=value` fields.

use core::fmt;

/// Why a well-framed body is not a valid message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParseError {
    /// The first word is not a known command (device answers `ERR BADCMD`).
    UnknownCommand,
    /// The first word is not a known event name.
    UnknownEvent,
    /// Wrong number of arguments, or an argument that is not a number (`ERR BADARG`).
    BadArgument,
    /// An axis number other than the defined ones (`ERR NOAXIS`).
    NoSuchAxis,
    /// A reply that is neither `OK ...` nor `ERR CODE`.
    BadReply,
    /// A required `KEY=value` field is missing or malformed.
    BadField(&'static str),
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParseError::UnknownCommand => write!(f, "unknown command"),
            ParseError::UnknownEvent => write!(f, "unknown event"),
            ParseError::BadArgument => write!(f, "bad or missing argument"),
            ParseError::NoSuchAxis => write!(f, "no such axis"),
            ParseError::BadReply => write!(f, "reply is neither OK nor ERR"),
            ParseError::BadField(k) => write!(f, "missing or malformed field {k}"),
        }
    }
}

/// Strict decimal `i32`: optional `-`, digits, no leading zeros, no `-0`, no `+`.
pub(crate) fn parse_i32(s: &str) -> Option<i32> {
    let digits = s.strip_prefix('-').unwrap_or(s);
    if !canonical_digits(digits) || s == "-0" {
        return None;
    }
    s.parse().ok()
}

/// Strict decimal `u32`: digits, no leading zeros, no sign.
pub(crate) fn parse_u32(s: &str) -> Option<u32> {
    if !canonical_digits(s) {
        return None;
    }
    s.parse().ok()
}

fn canonical_digits(d: &str) -> bool {
    !d.is_empty()
        && d.len() <= 10
        && d.bytes().all(|b| b.is_ascii_digit())
        && !(d.len() > 1 && d.starts_with('0'))
}

/// `0` or `1`.
pub(crate) fn parse_flag(s: &str) -> Option<bool> {
    match s {
        "0" => Some(false),
        "1" => Some(true),
        _ => None,
    }
}

/// The value of `key` among `KEY=value` tokens (last one wins; other tokens are ignored).
pub(crate) fn field<'a>(tokens: &'a str, key: &str) -> Option<&'a str> {
    tokens
        .rsplit(' ')
        .filter_map(|t| t.split_once('='))
        .find(|(k, _)| *k == key)
        .map(|(_, v)| v)
}

/// Parse a required field with `parse`, naming it in the error.
pub(crate) fn req<'a, T>(
    tokens: &'a str,
    key: &'static str,
    parse: impl FnOnce(&'a str) -> Option<T>,
) -> Result<T, ParseError> {
    field(tokens, key)
        .and_then(parse)
        .ok_or(ParseError::BadField(key))
}

/// Split a body into words, rejecting empty words (doubled, leading or trailing spaces).
pub(crate) fn words<const N: usize>(body: &str) -> Result<([&str; N], usize), ParseError> {
    let mut out = [""; N];
    let mut n = 0;
    for w in body.split(' ') {
        if w.is_empty() || n == N {
            return Err(ParseError::BadArgument);
        }
        out[n] = w;
        n += 1;
    }
    Ok((out, n))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strict_numbers() {
        assert_eq!(parse_i32("-2147483648"), Some(i32::MIN));
        assert_eq!(parse_i32("2147483647"), Some(i32::MAX));
        for bad in [
            "2147483648",
            "-0",
            "+1",
            "01",
            "",
            "-",
            "1.5",
            "99999999999",
            " 1",
        ] {
            assert_eq!(parse_i32(bad), None, "{bad:?}");
        }
        assert_eq!(parse_u32("4294967295"), Some(u32::MAX));
        assert_eq!(parse_u32("-1"), None);
        assert_eq!(parse_u32("0"), Some(0));
    }

    #[test]
    fn fields() {
        let t = "OK POS=5 X=1=2 POS=7";
        assert_eq!(field(t, "POS"), Some("7"));
        assert_eq!(field(t, "X"), Some("1=2"));
        assert_eq!(req(t, "Y", parse_i32), Err(ParseError::BadField("Y")));
    }
}
