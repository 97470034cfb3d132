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
        crate::io::write_atomic_with(path, |w| serde_json::to_writer(w, self).map_err(Into::into))
    }
}

/// `max |a - b| / max |b|` over two equally shaped value lists (the conformance metric).
pub fn relative_error(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len(), "value counts differ");
    let scale = b.iter().fold(0f64, |m, &v| m.max((v as f64).abs()));
    let diff = a
        .iter()
        .zip(b)
        .fold(0f64, |m, (&x, &y)| m.max((x as f64 - y as f64).abs()));
    if scale == 0.0 {
        diff
    } else {
        diff / scale
    }
}
