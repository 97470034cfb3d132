//! The detector catalogue ([`crate::catalogue::MODELS`]) as clap's value parser: a command line's
//! `--models` and `--model` values are checked against it at parse time ([`crate::catalogue::check_spec`]),
//! and its help lists the catalogue with one line per detector.

use clap::builder::{PossibleValue, TypedValueParser};
use clap::error::ErrorKind;

/// The detector catalogue ([`crate::catalogue::MODELS`]) as clap's value list.
fn catalogue() -> impl Iterator<Item = PossibleValue> {
    crate::catalogue::MODELS
        .iter()
        .map(|m| PossibleValue::new(m.name).help(m.about))
}

/// A detector spec, checked by [`crate::catalogue::check_spec`] with the catalogue listed in the help:
/// `NAME`, `MODEL=FILE` for a checkpoint model, or `onnx:MODEL.onnx[:CONFIG.toml]`
/// (`--models`: [`MODEL_SPECS`]). [`MODEL_NAME`] also takes a checkpoint model's bare name (`cac detect --model`,
/// whose weights come from `--weights`).
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
        let bare = crate::catalogue::model_info(&s)
            .is_some_and(|m| m.weights == crate::catalogue::Weights::Checkpoint);
        if !(self.bare_checkpoints && bare) {
            crate::catalogue::check_spec(&s)
                .map_err(|e| clap::Error::raw(ErrorKind::InvalidValue, format!("{e}\n")))?;
        }
        Ok(s.into_owned())
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = PossibleValue> + '_>> {
        Some(Box::new(catalogue()))
    }
}
