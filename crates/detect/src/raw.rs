//! Raw network tensors in the TFJS reference runner's `--raw` JSON schema
//! (`{model, backend, norm, image, input:{name,shape,dtype,values}, outputs:{NAME:{shape,dtype,values}}}`,
//! values flat row-major f32), so that `cmp.py` can compare a cac dump with an oracle dump.

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// One tensor: shape and flat row-major values.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RawTensor {
    #[serde(default)]
    pub name: Option<String>,
    pub shape: Vec<usize>,
    #[serde(default = "float32")]
    pub dtype: String,
    #[serde(default)]
    pub values: Vec<f32>,
}

fn float32() -> String {
    "float32".into()
}

/// Size of the original image.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct RawImage {
    #[serde(default)]
    pub path: Option<String>,
    pub width: usize,
    pub height: usize,
}

/// A whole dump: the model input tensor and every graph output.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RawDump {
    pub model: String,
    #[serde(default)]
    pub backend: String,
    #[serde(default)]
    pub norm: String,
    #[serde(default)]
    pub image: RawImage,
    pub input: RawTensor,
    pub outputs: BTreeMap<String, RawTensor>,
}

impl RawTensor {
    pub fn new(name: Option<&str>, shape: Vec<usize>, values: Vec<f32>) -> Self {
        RawTensor {
            name: name.map(String::from),
            shape,
            dtype: float32(),
            values,
        }
    }
}

impl RawDump {
    /// Reads a dump written by `cac detect --raw` or by the reference runner.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read raw dump {}", path.display()))?;
        serde_json::from_str(&text)
            .with_context(|| format!("{} is not a raw tensor dump", path.display()))
    }

    /// Writes the dump atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        cac_core::io::write_atomic_with(path, |w| {
            serde_json::to_writer(w, self).map_err(Into::into)
        })
    }
}

/// `max |a - b| / max |b|` over two equally shaped value lists (the conformance metric).
///
/// Any mismatch that the ratio cannot measure is an infinite error: different lengths, NaN in
/// either list, an infinity against a different value. Equal infinities count as equal.
pub fn relative_error(a: &[f32], b: &[f32]) -> f64 {
    if a.len() != b.len() {
        return f64::INFINITY;
    }
    let (mut scale, mut diff) = (0f64, 0f64);
    for (&x, &y) in a.iter().zip(b) {
        if !(x.is_finite() && y.is_finite()) {
            if x == y {
                continue;
            }
            return f64::INFINITY;
        }
        scale = scale.max((y as f64).abs());
        diff = diff.max((x as f64 - y as f64).abs());
    }
    if scale == 0.0 {
        diff
    } else {
        diff / scale
    }
}

#[cfg(test)]
mod tests {
    use super::relative_error;

    #[test]
    fn ordinary_values() {
        let e = relative_error(&[1.0, 2.0, -4.5], &[1.0, 2.5, -4.0]);
        assert!((e - 0.5 / 4.0).abs() < 1e-12, "{e}");
        assert_eq!(relative_error(&[0.25, 0.0], &[0.0, 0.0]), 0.25);
        assert_eq!(relative_error(&[], &[]), 0.0);
    }

    #[test]
    fn nan_in_either_list_is_an_infinite_error() {
        assert_eq!(relative_error(&[1.0, f32::NAN], &[1.0, 2.0]), f64::INFINITY);
        assert_eq!(relative_error(&[1.0, 2.0], &[f32::NAN, 2.0]), f64::INFINITY);
        assert_eq!(relative_error(&[f32::NAN], &[f32::NAN]), f64::INFINITY);
    }

    #[test]
    fn infinity_against_a_finite_value_is_an_infinite_error() {
        assert_eq!(relative_error(&[f32::INFINITY], &[1e30]), f64::INFINITY);
        assert_eq!(relative_error(&[1.0], &[f32::NEG_INFINITY]), f64::INFINITY);
        assert_eq!(
            relative_error(&[f32::INFINITY], &[f32::NEG_INFINITY]),
            f64::INFINITY
        );
        let e = relative_error(&[f32::INFINITY, 1.0], &[f32::INFINITY, 1.0]);
        assert_eq!(e, 0.0, "equal infinities match");
    }

    #[test]
    fn different_lengths_are_an_infinite_error() {
        assert_eq!(relative_error(&[1.0], &[1.0, 2.0]), f64::INFINITY);
    }
}
