//! torchvision state_dicts: read from a `torch.save` `.pth` (via `pytorch-reader`) or a
//! `.safetensors` file into host f32 tensors, then taken by name and shape while the model is
//! built. Every missing, unexpected or mis-shaped key is collected and reported at once.
//!
//! `num_batches_tracked` buffers (BatchNorm counters, absent from FrozenBatchNorm checkpoints)
//! are ignored. A checkpoint whose model keys carry one extra prefix (`model.`, `module.`,
//! `state_dict.`) is accepted with that prefix stripped; keys outside the prefix (optimizer
//! state of a training checkpoint) are then ignored.

use anyhow::{bail, Context, Result};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// One tensor on the host: row-major f32 values.
#[derive(Clone, Debug, PartialEq)]
pub struct HostTensor {
    pub shape: Vec<usize>,
    pub values: Vec<f32>,
}

/// A state_dict: parameter name → tensor, with where it came from (for error messages).
#[derive(Clone, Debug)]
pub struct StateDict {
    pub source: String,
    pub tensors: BTreeMap<String, HostTensor>,
}

fn ignored(name: &str) -> bool {
    name.ends_with("num_batches_tracked")
}

impl StateDict {
    /// From tensors already in memory.
    pub(crate) fn from_map(source: &str, tensors: BTreeMap<String, HostTensor>) -> Self {
        StateDict {
            source: source.into(),
            tensors,
        }
    }

    /// Reads a `.pth` / `.pt` (torch.save, zip or legacy pickle) or `.safetensors` file.
    /// The format is told by the file's first bytes (a safetensors header), not by its name.
    pub fn read(path: &Path) -> Result<Self> {
        let mut head = [0u8; 9];
        let len = {
            use std::io::Read;
            let mut f = std::fs::File::open(path)
                .with_context(|| format!("cannot open weights file {}", path.display()))?;
            let n = f.read(&mut head).unwrap_or(0);
            if n < 9 {
                bail!("{}: too short to be a weights file", path.display());
            }
            f.metadata().map(|m| m.len()).unwrap_or(0)
        };
        // safetensors: an 8-byte little-endian header length, then a JSON header.
        let header = u64::from_le_bytes(head[..8].try_into().expect("8 bytes"));
        let safetensors = head[8] == b'{' && header.saturating_add(8) <= len;
        let tensors = if safetensors {
            read_safetensors(path)?
        } else {
            read_pth(path)?
        };
        Ok(StateDict {
            source: path.display().to_string(),
            tensors,
        })
    }
}

fn read_pth(path: &Path) -> Result<BTreeMap<String, HostTensor>> {
    use pytorch_reader::{DType, PytorchReader};
    let reader = PytorchReader::new(path)
        .map_err(|e| anyhow::anyhow!("{}: not a readable torch.save file: {e}", path.display()))?;
    let mut out = BTreeMap::new();
    for (name, t) in reader.into_tensors() {
        if ignored(&name) {
            continue;
        }
        let bytes = t
            .read()
            .with_context(|| format!("{}: cannot read tensor {name}", path.display()))?;
        let kind = match t.dtype() {
            DType::F32 => FloatKind::F32,
            DType::F64 => FloatKind::F64,
            DType::F16 => FloatKind::F16,
            DType::BF16 => FloatKind::BF16,
            other => bail!(
                "{}: tensor {name} has dtype {other:?}; float weights expected",
                path.display()
            ),
        };
        let values = floats_le(&bytes, kind);
        out.insert(
            name,
            HostTensor {
                shape: t.shape().to_vec(),
                values,
            },
        );
    }
    Ok(out)
}

/// The float element types a weight file may hold.
#[derive(Clone, Copy, Debug)]
enum FloatKind {
    F32,
    F64,
    F16,
    BF16,
}

/// Little-endian float elements as f32: torch.save archives and safetensors both store
/// little-endian data.
fn floats_le(bytes: &[u8], kind: FloatKind) -> Vec<f32> {
    let two = |b: &[u8]| [b[0], b[1]];
    match kind {
        FloatKind::F32 => bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
        FloatKind::F64 => bytes
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")) as f32)
            .collect(),
        FloatKind::F16 => bytes
            .chunks_exact(2)
            .map(|b| half::f16::from_le_bytes(two(b)).to_f32())
            .collect(),
        FloatKind::BF16 => bytes
            .chunks_exact(2)
            .map(|b| half::bf16::from_le_bytes(two(b)).to_f32())
            .collect(),
    }
}

fn read_safetensors(path: &Path) -> Result<BTreeMap<String, HostTensor>> {
    use safetensors::{Dtype, SafeTensors};
    let bytes = std::fs::read(path)
        .with_context(|| format!("cannot read weights file {}", path.display()))?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| {
        anyhow::anyhow!(
            "{}: neither a torch.save file nor safetensors: {e}",
            path.display()
        )
    })?;
    let mut out = BTreeMap::new();
    for (name, view) in st.tensors() {
        if ignored(&name) {
            continue;
        }
        let kind = match view.dtype() {
            Dtype::F32 => FloatKind::F32,
            Dtype::F64 => FloatKind::F64,
            Dtype::F16 => FloatKind::F16,
            Dtype::BF16 => FloatKind::BF16,
            other => bail!(
                "{}: tensor {name} has dtype {other:?}; float weights expected",
                path.display()
            ),
        };
        let values = floats_le(view.data(), kind);
        out.insert(
            name,
            HostTensor {
                shape: view.shape().to_vec(),
                values,
            },
        );
    }
    Ok(out)
}

/// Takes tensors out of a [`StateDict`] by name and expected shape, recording what is wrong.
pub struct Loader<'a> {
    sd: &'a StateDict,
    prefix: String,
    used: BTreeSet<String>,
    missing: Vec<String>,
    mismatched: Vec<String>,
    requested: Vec<(String, Vec<usize>)>,
}

impl<'a> Loader<'a> {
    /// `probe` is a key every checkpoint of the model has (used to detect a common prefix).
    pub fn new(sd: &'a StateDict, probe: &str) -> Self {
        let prefix = if sd.tensors.contains_key(probe) {
            String::new()
        } else {
            sd.tensors
                .keys()
                .find_map(|k| k.strip_suffix(probe))
                .filter(|p| p.ends_with('.'))
                .unwrap_or("")
                .to_string()
        };
        Loader {
            sd,
            prefix,
            used: BTreeSet::new(),
            missing: Vec::new(),
            mismatched: Vec::new(),
            requested: Vec::new(),
        }
    }

    /// The values of `name`, which must have `shape`; zeros (and a recorded error) otherwise.
    pub fn take(&mut self, name: &str, shape: &[usize]) -> Vec<f32> {
        let key = format!("{}{name}", self.prefix);
        let n: usize = shape.iter().product();
        self.requested.push((name.to_string(), shape.to_vec()));
        match self.sd.tensors.get(&key) {
            None => {
                self.missing.push(format!("{name} {shape:?}"));
                vec![0.0; n]
            }
            Some(t) => {
                self.used.insert(key);
                // A [N] / [N, 1, 1] difference is not tolerated: shapes must match exactly.
                if t.shape != shape {
                    self.mismatched.push(format!(
                        "{name}: the file has {:?}, the model needs {shape:?}",
                        t.shape
                    ));
                    vec![0.0; n]
                } else {
                    t.values.clone()
                }
            }
        }
    }

    /// Every `(name, shape)` taken so far: the model's state_dict layout.
    pub fn requested(&self) -> &[(String, Vec<usize>)] {
        &self.requested
    }

    /// Fails, naming every missing, unexpected and mis-shaped key, unless all matched.
    pub fn finish(self, model: &str) -> Result<()> {
        let unexpected: Vec<String> = self
            .sd
            .tensors
            .keys()
            // With a prefix (a training checkpoint), only the keys under it are the model's.
            .filter(|k| k.starts_with(&self.prefix) && !self.used.contains(*k))
            .cloned()
            .collect();
        if self.missing.is_empty() && self.mismatched.is_empty() && unexpected.is_empty() {
            return Ok(());
        }
        let list = |what: &str, v: &[String]| -> Option<String> {
            if v.is_empty() {
                return None;
            }
            let shown: Vec<&str> = v.iter().take(8).map(String::as_str).collect();
            let more = if v.len() > 8 {
                format!(", ... and {} more", v.len() - 8)
            } else {
                String::new()
            };
            Some(format!("{} {what}: {}{more}", v.len(), shown.join(", ")))
        };
        let parts: Vec<String> = [
            list("missing keys", &self.missing),
            list("unexpected keys", &unexpected),
            list("shape mismatches", &self.mismatched),
        ]
        .into_iter()
        .flatten()
        .collect();
        bail!(
            "{}: not a {model} state_dict: {}",
            self.sd.source,
            parts.join("; ")
        )
    }
}
