//! Settings that take one of a fixed set of named values (`--sky`-like flags, a run.json's
//! `method`): each such enum says once, with [`choices!`], its values' names, the other names
//! they answer to and a line of help on each. The libraries parse and print them by name
//! ([`parse`], `Display`); the `cac` binary turns [`Choice::ALL`] into its command line's
//! possible values, so no library needs a command-line parser.

/// An enum whose values have names.
pub trait Choice: Copy + PartialEq + Sized + 'static {
    /// Every value, in the order help lists them.
    const ALL: &'static [Self];
    /// The value's name on a command line or in a file.
    fn name(self) -> &'static str;
    /// Other names the value answers to.
    fn aliases(self) -> &'static [&'static str];
    /// One line on what the value means (empty: none).
    fn help(self) -> &'static str;
}

/// The value named `s` (its name or an alias, exactly), or `None`.
pub fn parse<T: Choice>(s: &str) -> Option<T> {
    T::ALL
        .iter()
        .copied()
        .find(|v| v.name() == s || v.aliases().contains(&s))
}

/// The value named `s`, ignoring ASCII case, or an error listing the names.
pub fn parse_ignoring_case<T: Choice>(s: &str) -> Result<T, String> {
    T::ALL
        .iter()
        .copied()
        .find(|v| {
            v.name().eq_ignore_ascii_case(s)
                || v.aliases().iter().any(|a| a.eq_ignore_ascii_case(s))
        })
        .ok_or_else(|| format!("{s:?} is not one of {}", names::<T>().join(", ")))
}

/// Every value's name, in order.
pub fn names<T: Choice>() -> Vec<&'static str> {
    T::ALL.iter().map(|v| v.name()).collect()
}

/// Implements [`Choice`] and `Display` (the name) for an enum:
///
/// ```
/// #[derive(Clone, Copy, Debug, PartialEq)]
/// pub enum Set { Free, Restricted }
/// cac_core::choices!(Set {
///     Free => "fv" | "free": "anywhere on the viewing sphere",
///     Restricted => "rv" | "restricted": "side views only",
/// });
/// assert_eq!(cac_core::choice::parse::<Set>("free"), Some(Set::Free));
/// assert_eq!(Set::Restricted.to_string(), "rv");
/// ```
#[macro_export]
macro_rules! choices {
    ($t:ident { $($v:ident => $name:literal $(| $alias:literal)* : $help:literal),+ $(,)? }) => {
        impl $crate::choice::Choice for $t {
            const ALL: &'static [Self] = &[$($t::$v),+];
            fn name(self) -> &'static str {
                match self { $($t::$v => $name),+ }
            }
            fn aliases(self) -> &'static [&'static str] {
                match self { $($t::$v => &[$($alias),*]),+ }
            }
            fn help(self) -> &'static str {
                match self { $($t::$v => $help),+ }
            }
        }
        impl ::std::fmt::Display for $t {
            fn fmt(&self, f: &mut ::std::fmt::Formatter<'_>) -> ::std::fmt::Result {
                f.write_str($crate::choice::Choice::name(*self))
            }
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Rule {
        Overlap,
        TopN,
    }
    crate::choices!(Rule {
        Overlap => "overlap": "on the object",
        TopN => "topn" | "top-n": "",
    });

    #[test]
    fn names_and_aliases_parse_and_print() {
        assert_eq!(parse::<Rule>("topn"), Some(Rule::TopN));
        assert_eq!(parse::<Rule>("top-n"), Some(Rule::TopN));
        assert_eq!(parse::<Rule>("TopN"), None, "exact unless asked");
        assert_eq!(parse_ignoring_case::<Rule>("TopN"), Ok(Rule::TopN));
        let e = parse_ignoring_case::<Rule>("all").unwrap_err();
        assert!(e.contains("overlap, topn"), "{e}");
        assert_eq!(Rule::Overlap.to_string(), "overlap");
        assert_eq!(Rule::TopN.help(), "");
        assert_eq!(names::<Rule>(), ["overlap", "topn"]);
    }
}
