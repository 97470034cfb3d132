//! Reading a TensorFlow.js graph model from disk: `model.json` (topology + weightsManifest) and
//! its weight shards, with dequantisation (float16, and the uint8/uint16 affine scheme).
//!
//! This is only the file format; running the graph is `graph.rs`. Every problem with a file is an
//! error naming the file (and the weight or node) and what is wrong.

use anyhow::{anyhow, bail, Context, Result};
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A host tensor: constants, weights and the small integer tensors graphs compute on the side.
#[derive(Clone, Debug, PartialEq)]
pub struct HostTensor {
    pub shape: Vec<usize>,
    pub data: HostData,
}

/// Element storage of a [`HostTensor`]; all integer types are widened to i64.
#[derive(Clone, Debug, PartialEq)]
pub enum HostData {
    F32(Vec<f32>),
    I64(Vec<i64>),
}

impl HostTensor {
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Values as i64 (floats truncated), for shape/axis/size arguments.
    pub fn as_i64(&self) -> Vec<i64> {
        match &self.data {
            HostData::I64(v) => v.clone(),
            HostData::F32(v) => v.iter().map(|&x| x as i64).collect(),
        }
    }
    /// Values as f32.
    pub(crate) fn as_f32(&self) -> Vec<f32> {
        match &self.data {
            HostData::F32(v) => v.clone(),
            HostData::I64(v) => v.iter().map(|&x| x as f32).collect(),
        }
    }
}

/// One node of the graph as stored in model.json.
#[derive(Clone, Debug, Deserialize)]
pub struct NodeDef {
    pub name: String,
    pub op: String,
    #[serde(default)]
    pub input: Vec<String>,
    #[serde(default)]
    pub attr: HashMap<String, serde_json::Value>,
}

#[derive(Debug, Deserialize)]
struct Topology {
    node: Vec<NodeDef>,
}

#[derive(Debug, Deserialize)]
struct Quantization {
    dtype: String,
    #[serde(default)]
    scale: Option<f32>,
    #[serde(default)]
    min: Option<f32>,
}

#[derive(Debug, Deserialize)]
struct WeightSpec {
    name: String,
    shape: Vec<usize>,
    dtype: String,
    #[serde(default)]
    quantization: Option<Quantization>,
}

#[derive(Debug, Deserialize)]
struct WeightGroup {
    paths: Vec<String>,
    weights: Vec<WeightSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
struct ModelJson {
    format: Option<String>,
    model_topology: Topology,
    weights_manifest: Vec<WeightGroup>,
}

/// A parsed graph model: its nodes and its (dequantised) weights by name.
#[derive(Debug)]
pub struct GraphModel {
    pub path: PathBuf,
    pub nodes: Vec<NodeDef>,
    pub weights: HashMap<String, HostTensor>,
}

impl GraphModel {
    /// Loads `model.json` and the weight files it names (relative to its folder).
    pub fn load(json_path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(json_path)
            .with_context(|| format!("cannot read TFJS model file {}", json_path.display()))?;
        let dir = json_path.parent().unwrap_or(Path::new("."));
        Self::parse(&text, json_path, |p| {
            let f = dir.join(p);
            std::fs::read(&f).with_context(|| format!("cannot read weight file {}", f.display()))
        })
    }

    /// Parses a model from its JSON text; `read_shard` returns the bytes of a weight path.
    pub fn parse(
        json_text: &str,
        json_path: &Path,
        mut read_shard: impl FnMut(&str) -> Result<Vec<u8>>,
    ) -> Result<Self> {
        let name = json_path.display();
        let m: ModelJson = serde_json::from_str(json_text)
            .with_context(|| format!("{name} is not a valid TFJS graph-model JSON file"))?;
        if let Some(f) = &m.format {
            if f != "graph-model" {
                bail!("{name}: format is {f:?}, only \"graph-model\" is supported");
            }
        }
        let mut weights = HashMap::new();
        for group in &m.weights_manifest {
            let mut bytes = Vec::new();
            for p in &group.paths {
                bytes.extend(read_shard(p)?);
            }
            let shard_names = group.paths.join(",");
            let mut offset = 0usize;
            for w in &group.weights {
                let (t, used) =
                    decode_weight(w, &bytes[offset.min(bytes.len())..]).with_context(|| {
                        format!(
                            "{name}: weight {:?} in {shard_names} (at byte {offset})",
                            w.name
                        )
                    })?;
                offset += used;
                weights.insert(w.name.clone(), t);
            }
            if offset != bytes.len() {
                bail!(
                    "{name}: weight file(s) {shard_names} hold {} bytes but the manifest describes {offset}",
                    bytes.len()
                );
            }
        }
        Ok(GraphModel {
            path: json_path.to_path_buf(),
            nodes: m.model_topology.node,
            weights,
        })
    }
}

fn decode_weight(w: &WeightSpec, bytes: &[u8]) -> Result<(HostTensor, usize)> {
    let n: usize = w.shape.iter().product();
    let need = |size: usize| -> Result<&[u8]> {
        let total = n * size;
        bytes.get(..total).ok_or_else(|| {
            anyhow!(
                "needs {total} bytes but only {} are left: the weight file is truncated",
                bytes.len()
            )
        })
    };
    let shape = w.shape.clone();
    if let Some(q) = &w.quantization {
        let data: Vec<f32> = match q.dtype.as_str() {
            "float16" => need(2)?
                .chunks_exact(2)
                .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect(),
            "uint8" | "uint16" => {
                let (scale, min) = match (q.scale, q.min) {
                    (Some(s), Some(m)) => (s, m),
                    _ => bail!("{} quantisation needs scale and min", q.dtype),
                };
                if q.dtype == "uint8" {
                    need(1)?.iter().map(|&b| b as f32 * scale + min).collect()
                } else {
                    need(2)?
                        .chunks_exact(2)
                        .map(|c| u16::from_le_bytes([c[0], c[1]]) as f32 * scale + min)
                        .collect()
                }
            }
            other => bail!("unsupported quantisation dtype {other:?}"),
        };
        let size = if q.dtype == "uint8" { 1 } else { 2 };
        let t = if w.dtype == "int32" {
            HostTensor {
                shape,
                data: HostData::I64(data.iter().map(|&x| x.round() as i64).collect()),
            }
        } else {
            HostTensor {
                shape,
                data: HostData::F32(data),
            }
        };
        return Ok((t, n * size));
    }
    let t = match w.dtype.as_str() {
        "float32" => HostData::F32(
            need(4)?
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        ),
        "int32" => HostData::I64(
            need(4)?
                .chunks_exact(4)
                .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]) as i64)
                .collect(),
        ),
        "bool" => HostData::I64(need(1)?.iter().map(|&b| (b != 0) as i64).collect()),
        other => bail!("unsupported weight dtype {other:?}"),
    };
    let size = if w.dtype == "bool" { 1 } else { 4 };
    Ok((HostTensor { shape, data: t }, n * size))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest(weights: &str) -> String {
        format!(
            r#"{{"format":"graph-model","modelTopology":{{"node":[]}},
               "weightsManifest":[{{"paths":["w.bin"],"weights":{weights}}}]}}"#
        )
    }

    #[test]
    fn dequantises_float16_uint8_and_reads_int32() {
        let json = manifest(
            r#"[{"name":"a","shape":[2],"dtype":"float32","quantization":{"dtype":"float16","original_dtype":"float32"}},
                {"name":"b","shape":[2],"dtype":"float32","quantization":{"dtype":"uint8","scale":0.5,"min":-1.0}},
                {"name":"c","shape":[1],"dtype":"int32"}]"#,
        );
        let mut bin = Vec::new();
        bin.extend(half::f16::from_f32(1.0 / 6.0).to_le_bytes());
        bin.extend(half::f16::from_f32(-2.5).to_le_bytes());
        bin.extend([0u8, 4u8]);
        bin.extend((-7i32).to_le_bytes());
        let m = GraphModel::parse(&json, Path::new("m.json"), |_| Ok(bin.clone())).unwrap();
        assert_eq!(m.weights["a"].as_f32(), vec![0.166_625_98, -2.5]);
        assert_eq!(m.weights["b"].as_f32(), vec![-1.0, 1.0]);
        assert_eq!(m.weights["c"].as_i64(), vec![-7]);
    }

    #[test]
    fn truncated_or_oversized_weight_files_are_clear_errors() {
        let json = manifest(r#"[{"name":"w0","shape":[3],"dtype":"float32"}]"#);
        let e = GraphModel::parse(&json, Path::new("m.json"), |_| Ok(vec![0; 8])).unwrap_err();
        let msg = format!("{e:#}");
        assert!(msg.contains("w0") && msg.contains("truncated"), "{msg}");
        let e = GraphModel::parse(&json, Path::new("m.json"), |_| Ok(vec![0; 16])).unwrap_err();
        assert!(format!("{e:#}").contains("16 bytes"), "{e:#}");
        let e = GraphModel::parse("{\"format\":", Path::new("m.json"), |_| Ok(vec![])).unwrap_err();
        assert!(format!("{e:#}").contains("m.json"), "{e:#}");
    }
}
