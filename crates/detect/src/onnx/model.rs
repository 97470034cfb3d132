//! Reads an `.onnx` file into plain Rust values: nodes with their attributes, initializers as
//! host tensors (float16/double widened or narrowed to f32, every integer type to i64, external
//! data read from beside the file), graph inputs and outputs with their (possibly dynamic)
//! shapes, opsets and metadata. [`Model::describe`] is what `cac models inspect` prints.
//! Not here: running anything.

use super::proto::{self, AttributeProto, TensorProto, ValueInfoProto};
use super::value::Host;
use anyhow::{anyhow, bail, ensure, Context, Result};
use ndarray::{ArrayD, IxDyn};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// The default-domain opsets this executor implements (the ops' versions in between are
/// handled where their semantics changed: Split, Squeeze, Unsqueeze, Softmax, Slice, Clip,
/// Resize, Reduce*).
pub(crate) const OPSETS: std::ops::RangeInclusive<i64> = 9..=22;

/// One dimension of a graph input or output.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Dim {
    Fixed(usize),
    /// A named dynamic dimension (`dim_param`, e.g. `batch`).
    Param(String),
    Unknown,
}

impl std::fmt::Display for Dim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Dim::Fixed(n) => write!(f, "{n}"),
            Dim::Param(p) => write!(f, "{p}"),
            Dim::Unknown => write!(f, "?"),
        }
    }
}

/// A graph input or output.
#[derive(Clone, Debug)]
pub struct Io {
    pub name: String,
    /// ONNX `DataType` (1 float, 7 int64, ...).
    pub elem_type: i32,
    pub dims: Vec<Dim>,
}

impl Io {
    /// The shape when every dimension is fixed.
    pub fn fixed(&self) -> Option<Vec<usize>> {
        self.dims
            .iter()
            .map(|d| match d {
                Dim::Fixed(n) => Some(*n),
                _ => None,
            })
            .collect()
    }
    pub(crate) fn shape_text(&self) -> String {
        let d: Vec<String> = self.dims.iter().map(|d| d.to_string()).collect();
        format!("[{}]", d.join(", "))
    }
}

/// A node attribute.
#[derive(Clone, Debug)]
pub enum Attr {
    F(f32),
    I(i64),
    S(String),
    T(Host),
    Fs(Vec<f32>),
    Is(Vec<i64>),
    Ss(Vec<String>),
    /// A graph, a type or a sparse tensor: no op this executor supports takes one.
    Other,
}

/// A node as the file states it.
#[derive(Clone, Debug)]
pub struct NodeDef {
    /// The node's name (`#k op` when the file leaves it empty).
    pub name: String,
    pub op: String,
    pub domain: String,
    /// Value names; an empty name is an omitted optional input.
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    pub attrs: BTreeMap<String, Attr>,
}

/// A whole model file.
#[derive(Clone, Debug)]
pub struct Model {
    pub path: PathBuf,
    pub ir_version: i64,
    pub producer: String,
    /// `(domain, version)`; the default domain is `""`.
    pub opsets: Vec<(String, i64)>,
    pub metadata: Vec<(String, String)>,
    pub inputs: Vec<Io>,
    pub outputs: Vec<Io>,
    pub initializers: HashMap<String, Host>,
    pub nodes: Vec<NodeDef>,
}

/// The nodes in an order where each comes after the producers of its inputs. ONNX requires
/// that order, but some exporters (ultralytics' fp16 export) write nodes out of it and
/// onnxruntime sorts them; so does cac. A graph already in order keeps its order (among the
/// nodes ready at a time, the earliest in the file goes first); a value that no node, graph
/// input or initializer (`defined`) produces is left for the graph to report; a cycle is an
/// error naming its nodes.
fn topological(
    nodes: Vec<NodeDef>,
    defined: &std::collections::HashSet<&str>,
) -> Result<Vec<NodeDef>> {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let mut producer: HashMap<&str, usize> = HashMap::new();
    for (k, n) in nodes.iter().enumerate() {
        for o in n.outputs.iter().filter(|o| !o.is_empty()) {
            producer.entry(o.as_str()).or_insert(k);
        }
    }
    let mut waits = vec![0usize; nodes.len()];
    let mut users: Vec<Vec<usize>> = vec![vec![]; nodes.len()];
    for (k, n) in nodes.iter().enumerate() {
        let mut deps: Vec<usize> = n
            .inputs
            .iter()
            .filter(|i| !i.is_empty() && !defined.contains(i.as_str()))
            .filter_map(|i| producer.get(i.as_str()).copied())
            .collect();
        deps.sort_unstable();
        deps.dedup();
        waits[k] = deps.len();
        for d in deps {
            users[d].push(k);
        }
    }
    let mut ready: BinaryHeap<Reverse<usize>> = (0..nodes.len())
        .filter(|&k| waits[k] == 0)
        .map(Reverse)
        .collect();
    let mut order = Vec::with_capacity(nodes.len());
    while let Some(Reverse(k)) = ready.pop() {
        order.push(k);
        for &u in &users[k] {
            waits[u] -= 1;
            if waits[u] == 0 {
                ready.push(Reverse(u));
            }
        }
    }
    if order.len() < nodes.len() {
        let stuck: Vec<&str> = (0..nodes.len())
            .filter(|&k| waits[k] > 0)
            .take(5)
            .map(|k| nodes[k].name.as_str())
            .collect();
        bail!(
            "the graph has a cycle: {} nodes wait on each other (among them {})",
            nodes.len() - order.len(),
            stuck.join(", ")
        );
    }
    let mut slots: Vec<Option<NodeDef>> = nodes.into_iter().map(Some).collect();
    Ok(order
        .into_iter()
        .map(|k| slots[k].take().expect("each node once"))
        .collect())
}

impl Model {
    /// Reads and decodes `path`; the nodes are put in topological order ([`topological`]).
    pub fn load(path: &Path) -> Result<Self> {
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        let m = proto::decode_model(&bytes).map_err(|e| {
            anyhow!(
                "{}: not an ONNX model (protobuf decoding failed: {e})",
                path.display()
            )
        })?;
        let src = path.display().to_string();
        let g = m
            .graph
            .ok_or_else(|| anyhow!("{src}: the model has no graph"))?;
        ensure!(
            m.functions.is_empty(),
            "{src}: model-local functions ({}) are not supported",
            m.functions.len()
        );
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut initializers = HashMap::new();
        for t in &g.initializer {
            let h = tensor(t, dir).with_context(|| format!("{src}: initializer {:?}", t.name))?;
            initializers.insert(t.name.clone(), h);
        }
        let mut nodes = Vec::with_capacity(g.node.len());
        for (k, n) in g.node.iter().enumerate() {
            let name = if n.name.is_empty() {
                format!("#{k} {}", n.op_type)
            } else {
                n.name.clone()
            };
            let mut attrs = BTreeMap::new();
            for a in &n.attribute {
                let v = attr(a, dir)
                    .with_context(|| format!("{src}: node {name:?} attribute {:?}", a.name))?;
                attrs.insert(a.name.clone(), v);
            }
            nodes.push(NodeDef {
                name,
                op: n.op_type.clone(),
                domain: n.domain.clone(),
                inputs: n.input.clone(),
                outputs: n.output.clone(),
                attrs,
            });
        }
        let defined: std::collections::HashSet<&str> = g
            .input
            .iter()
            .map(|i| i.name.as_str())
            .chain(initializers.keys().map(String::as_str))
            .collect();
        let nodes = topological(nodes, &defined).with_context(|| src.clone())?;
        let io = |v: &[ValueInfoProto]| -> Vec<Io> {
            v.iter()
                .filter(|i| !initializers.contains_key(&i.name))
                .map(value_info)
                .collect()
        };
        Ok(Model {
            path: path.to_path_buf(),
            ir_version: m.ir_version,
            producer: format!("{} {}", m.producer_name, m.producer_version)
                .trim()
                .to_string(),
            opsets: m
                .opset_import
                .iter()
                .map(|o| (o.domain.clone(), o.version))
                .collect(),
            metadata: m
                .metadata_props
                .iter()
                .map(|p| (p.key.clone(), p.value.clone()))
                .collect(),
            inputs: io(&g.input),
            outputs: io(&g.output),
            initializers,
            nodes,
        })
    }

    pub fn source(&self) -> String {
        self.path.display().to_string()
    }

    /// The default domain's opset; an error naming the file when it is outside [`OPSETS`].
    pub fn opset(&self) -> Result<i64> {
        let v = self
            .opsets
            .iter()
            .find(|(d, _)| d.is_empty() || d == "ai.onnx")
            .map(|o| o.1)
            .ok_or_else(|| anyhow!("{}: no default-domain opset is imported", self.source()))?;
        if !OPSETS.contains(&v) {
            bail!(
                "{}: opset {v} is not supported (cac runs opsets {}..={})",
                self.source(),
                OPSETS.start(),
                OPSETS.end()
            );
        }
        Ok(v)
    }

    /// A metadata value by key.
    pub fn meta(&self, key: &str) -> Option<&str> {
        self.metadata
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// What the file holds, for `cac models inspect`: producer, opsets, inputs and outputs with
    /// their shapes, op types with counts (those not in `supported` marked), metadata keys.
    pub fn describe(&self, supported: &[&str]) -> String {
        let mut s = format!(
            "{}\n  producer: {}\n  ir_version: {}\n  opsets: {}\n",
            self.source(),
            if self.producer.is_empty() {
                "(none)"
            } else {
                &self.producer
            },
            self.ir_version,
            self.opsets
                .iter()
                .map(|(d, v)| format!("{}={v}", if d.is_empty() { "ai.onnx" } else { d }))
                .collect::<Vec<_>>()
                .join(", ")
        );
        for (title, list) in [("inputs", &self.inputs), ("outputs", &self.outputs)] {
            s += &format!("  {title}:\n");
            for i in list {
                s += &format!(
                    "    {} {} {}\n",
                    i.name,
                    dtype_name(i.elem_type),
                    i.shape_text()
                );
            }
        }
        let mut ops: BTreeMap<&str, usize> = BTreeMap::new();
        for n in &self.nodes {
            *ops.entry(n.op.as_str()).or_default() += 1;
        }
        let params: usize = self.initializers.values().map(|h| h.len()).sum();
        s += &format!(
            "  nodes: {} ({} parameters in {} initializers)\n  ops:",
            self.nodes.len(),
            params,
            self.initializers.len()
        );
        for (op, n) in &ops {
            let mark = if supported.contains(op) {
                ""
            } else {
                " (unsupported)"
            };
            s += &format!(" {op}×{n}{mark}");
        }
        s += "\n";
        if !self.metadata.is_empty() {
            let keys: Vec<&str> = self.metadata.iter().map(|(k, _)| k.as_str()).collect();
            s += &format!("  metadata: {}\n", keys.join(", "));
        }
        s
    }
}

fn value_info(v: &ValueInfoProto) -> Io {
    let tt = v.r#type.as_ref().and_then(|t| t.tensor_type.as_ref());
    let dims = tt
        .and_then(|t| t.shape.as_ref())
        .map(|s| {
            s.dim
                .iter()
                .map(|d| match (&d.dim_value, &d.dim_param) {
                    (Some(n), _) if *n >= 0 => Dim::Fixed(*n as usize),
                    (_, Some(p)) if !p.is_empty() => Dim::Param(p.clone()),
                    _ => Dim::Unknown,
                })
                .collect()
        })
        .unwrap_or_default();
    Io {
        name: v.name.clone(),
        elem_type: tt.map(|t| t.elem_type).unwrap_or(0),
        dims,
    }
}

/// The name of an ONNX `DataType`.
pub(crate) fn dtype_name(t: i32) -> &'static str {
    match t {
        1 => "float32",
        2 => "uint8",
        3 => "int8",
        4 => "uint16",
        5 => "int16",
        6 => "int32",
        7 => "int64",
        8 => "string",
        9 => "bool",
        10 => "float16",
        11 => "float64",
        12 => "uint32",
        13 => "uint64",
        16 => "bfloat16",
        _ => "unknown",
    }
}

fn attr(a: &AttributeProto, dir: &Path) -> Result<Attr> {
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    Ok(match a.r#type {
        1 => Attr::F(a.f),
        2 => Attr::I(a.i),
        3 => Attr::S(text(&a.s)),
        4 => Attr::T(tensor(
            a.t.as_ref()
                .ok_or_else(|| anyhow!("tensor attribute without a tensor"))?,
            dir,
        )?),
        6 => Attr::Fs(a.floats.clone()),
        7 => Attr::Is(a.ints.clone()),
        8 => Attr::Ss(a.strings.iter().map(|s| text(s)).collect()),
        _ => Attr::Other,
    })
}

/// A `TensorProto` as a host tensor.
pub fn tensor(t: &TensorProto, dir: &Path) -> Result<Host> {
    let shape: Vec<usize> = t
        .dims
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| anyhow!("negative dimension {d}")))
        .collect::<Result<_>>()?;
    let n: usize = shape.iter().product();
    let external;
    let raw: &[u8] = if t.data_location == 1 {
        external = external_data(t, dir)?;
        &external
    } else {
        &t.raw_data
    };
    let le = |w: usize| -> Result<std::slice::ChunksExact<'_, u8>> {
        ensure!(
            raw.len() == n * w,
            "raw data has {} bytes, shape {shape:?} needs {}",
            raw.len(),
            n * w
        );
        Ok(raw.chunks_exact(w))
    };
    let has_raw = !raw.is_empty() || n == 0;
    let f: Option<Vec<f32>> = match t.data_type {
        1 if has_raw => Some(
            le(4)?
                .map(|c| f32::from_le_bytes(c.try_into().expect("4")))
                .collect(),
        ),
        1 => Some(t.float_data.clone()),
        10 if has_raw => Some(
            le(2)?
                .map(|c| half::f16::from_le_bytes(c.try_into().expect("2")).to_f32())
                .collect(),
        ),
        10 => Some(
            t.int32_data
                .iter()
                .map(|&b| half::f16::from_bits(b as u16).to_f32())
                .collect(),
        ),
        11 if has_raw => Some(
            le(8)?
                .map(|c| f64::from_le_bytes(c.try_into().expect("8")) as f32)
                .collect(),
        ),
        11 => Some(t.double_data.iter().map(|&v| v as f32).collect()),
        _ => None,
    };
    if let Some(v) = f {
        ensure!(v.len() == n, "{} values for shape {shape:?}", v.len());
        return Ok(Host::F(ArrayD::from_shape_vec(IxDyn(&shape), v)?));
    }
    let i: Vec<i64> = match t.data_type {
        7 if has_raw => le(8)?
            .map(|c| i64::from_le_bytes(c.try_into().expect("8")))
            .collect(),
        7 => t.int64_data.clone(),
        6 if has_raw => le(4)?
            .map(|c| i32::from_le_bytes(c.try_into().expect("4")) as i64)
            .collect(),
        2 | 9 if has_raw => le(1)?.map(|c| c[0] as i64).collect(),
        3 if has_raw => le(1)?.map(|c| c[0] as i8 as i64).collect(),
        4 if has_raw => le(2)?
            .map(|c| u16::from_le_bytes(c.try_into().expect("2")) as i64)
            .collect(),
        5 if has_raw => le(2)?
            .map(|c| i16::from_le_bytes(c.try_into().expect("2")) as i64)
            .collect(),
        12 if has_raw => le(4)?
            .map(|c| u32::from_le_bytes(c.try_into().expect("4")) as i64)
            .collect(),
        13 if has_raw => le(8)?
            .map(|c| u64::from_le_bytes(c.try_into().expect("8")) as i64)
            .collect(),
        13 => t.uint64_data.iter().map(|&v| v as i64).collect(),
        2..=6 | 9 | 12 => t.int32_data.iter().map(|&v| v as i64).collect(),
        d => bail!("data type {} ({d}) is not supported", dtype_name(d)),
    };
    ensure!(i.len() == n, "{} values for shape {shape:?}", i.len());
    Ok(Host::I(ArrayD::from_shape_vec(IxDyn(&shape), i)?))
}

/// The bytes of a tensor stored beside the model (`location`, `offset`, `length` keys).
fn external_data(t: &TensorProto, dir: &Path) -> Result<Vec<u8>> {
    let get = |k: &str| {
        t.external_data
            .iter()
            .find(|e| e.key == k)
            .map(|e| e.value.clone())
    };
    let loc = get("location").ok_or_else(|| anyhow!("external data without a location"))?;
    let file = dir.join(&loc);
    let bytes = std::fs::read(&file)
        .with_context(|| format!("cannot read external data {}", file.display()))?;
    let offset: usize = get("offset").map(|s| s.parse()).transpose()?.unwrap_or(0);
    let length: usize = match get("length") {
        Some(s) => s.parse()?,
        None => bytes.len().saturating_sub(offset),
    };
    bytes
        .get(offset..offset + length)
        .map(|b| b.to_vec())
        .ok_or_else(|| {
            anyhow!(
                "{}: bytes {offset}..{} are past its end",
                file.display(),
                offset + length
            )
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(name: &str, inputs: &[&str], outputs: &[&str]) -> NodeDef {
        NodeDef {
            name: name.into(),
            op: "Relu".into(),
            domain: String::new(),
            inputs: inputs.iter().map(|s| s.to_string()).collect(),
            outputs: outputs.iter().map(|s| s.to_string()).collect(),
            attrs: BTreeMap::new(),
        }
    }

    fn names(v: &[NodeDef]) -> Vec<&str> {
        v.iter().map(|n| n.name.as_str()).collect()
    }

    #[test]
    fn nodes_out_of_order_are_sorted_and_ordered_graphs_keep_their_order() {
        let defined: std::collections::HashSet<&str> = ["x", "w"].into_iter().collect();
        // c reads b's output, b reads a's: written c, a, b (as an fp16 export writes them).
        let shuffled = vec![
            node("c", &["vb", "w"], &["vc"]),
            node("a", &["x"], &["va"]),
            node("b", &["va", ""], &["vb"]),
        ];
        assert_eq!(
            names(&topological(shuffled, &defined).unwrap()),
            ["a", "b", "c"]
        );
        // Already in order, with independent branches: unchanged.
        let ordered = vec![
            node("p", &["x"], &["vp"]),
            node("q", &["x"], &["vq"]),
            node("r", &["vq", "vp"], &["vr"]),
            node("s", &["w"], &["vs"]),
        ];
        assert_eq!(
            names(&topological(ordered, &defined).unwrap()),
            ["p", "q", "r", "s"]
        );
        // A value nothing defines: left in place for the graph's error.
        let missing = vec![
            node("m", &["nowhere"], &["vm"]),
            node("n", &["vm"], &["vn"]),
        ];
        assert_eq!(names(&topological(missing, &defined).unwrap()), ["m", "n"]);
        // A cycle: named.
        let cycle = vec![
            node("u", &["vv"], &["vu"]),
            node("v", &["vu"], &["vv"]),
            node("t", &["x"], &["vt"]),
        ];
        let e = topological(cycle, &defined).unwrap_err().to_string();
        assert!(
            e.contains("cycle") && e.contains('u') && e.contains('v'),
            "{e}"
        );
    }
}
