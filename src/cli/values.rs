//! Value parsers for the libraries' plain types: the command line is the only place that knows
//! clap. [`choice`] turns an enum's names ([`cac::choice::Choice`]) into possible values; the
//! detector catalogue ([`cac::detect::MODELS`]) is checked at parse time by [`MODEL_SPECS`] and
//! [`MODEL_NAME`], whose help lists it with one line per detector.

use cac::choice::Choice;
use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::error::ErrorKind;

/// The parser of a [`Choice`] enum: its names and aliases are the possible values, each with
/// its line of help.
pub fn choice<T: Choice + Clone + Send + Sync>() -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(T::ALL.iter().map(|v| {
        let p = PossibleValue::new(v.name()).aliases(v.aliases().iter().copied());
        match v.help() {
            "" => p,
            h => p.help(h),
        }
    }))
    .map(|s| cac::choice::parse::<T>(&s).expect("the parser accepts only possible values"))
}

/// The detector catalogue as clap's value list.
fn catalogue() -> impl Iterator<Item = PossibleValue> {
    cac::detect::MODELS
        .iter()
        .map(|m| PossibleValue::new(m.name).help(m.about))
}

/// A detector spec, checked by [`cac::detect::check_spec`] with the catalogue listed in the
/// help: `NAME`, `MODEL=FILE` for a checkpoint model, or `onnx:MODEL.onnx[:CONFIG.toml]`
/// (`--models`: [`MODEL_SPECS`]). [`MODEL_NAME`] also takes a checkpoint model's bare name
/// (`cac detect --model`, whose weights come from `--weights`).
#[derive(Clone, Copy, Debug)]
pub struct ModelSpec {
    bare_checkpoints: bool,
}

/// `--models`' parser.
pub const MODEL_SPECS: ModelSpec = ModelSpec {
    bare_checkpoints: false,
};

/// `cac detect --model`'s parser.
pub const MODEL_NAME: ModelSpec = ModelSpec {
    bare_checkpoints: true,
};

impl TypedValueParser for ModelSpec {
    type Value = String;

    fn parse_ref(
        &self,
        _cmd: &clap::Command,
        _arg: Option<&clap::Arg>,
        value: &std::ffi::OsStr,
    ) -> std::result::Result<String, clap::Error> {
        let s = value.to_string_lossy();
        let bare = cac::detect::model_info(&s)
            .is_some_and(|m| m.weights == cac::detect::Weights::Checkpoint);
        if !(self.bare_checkpoints && bare) {
            cac::detect::check_spec(&s)
                .map_err(|e| clap::Error::raw(ErrorKind::InvalidValue, format!("{e}\n")))?;
        }
        Ok(s.into_owned())
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = PossibleValue> + '_>> {
        Some(Box::new(catalogue()))
    }
}

/// A duration such as `10m`, `90s` or `1h30m`, in seconds (`--budget`).
pub fn duration(s: &str) -> Result<f64, String> {
    match cac::report::timer::parse_duration(s) {
        Some(v) if v > 0.0 => Ok(v),
        _ => Err(format!("{s:?} is not a duration such as 10m, 90s or 1h30m")),
    }
}
