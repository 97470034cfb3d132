//! An imported TFJS graph on the executor core ([`crate::exec`]): resolves node inputs to value
//! slots (one per node output that something reads), fuses elementwise chains, and evaluates
//! nodes as burn tensor ops (see `ops.rs`).
//!
//! Float activations are burn tensors (differentiable, on the caller's device); shape, axis and
//! size arguments and other small integer tensors stay on the host. Only the nodes needed for
//! the requested outputs run, so a graph whose decode tail uses unsupported ops can still serve
//! its dense outputs. The graph is traced at batch 1; batch > 1 flows through because the
//! executor treats a leading 1 in a Reshape target as the batch dimension.

use super::model::{GraphModel, HostData, HostTensor, NodeDef};
use super::ops;
use super::value::{pad4, FloatValue, Node, Value};
use crate::exec::{self, Dataflow};
use anyhow::{anyhow, bail, Context, Result};
use burn::tensor::{Device, Tensor, TensorData};
use std::collections::HashMap;

/// A graph ready to run on one device: nodes in file order, constants already on the device.
pub struct Graph {
    pub source: String,
    pub nodes: Vec<Node>,
    index: HashMap<String, usize>,
    consts: HashMap<usize, Value>,
    /// Convolution weights pre-arranged to burn's OIHW layout, keyed by the conv node.
    conv_weights: HashMap<usize, Tensor<4>>,
    flow: Dataflow,
    /// The slot of output `k` of node `i`, and back.
    slot_of: HashMap<(usize, usize), usize>,
    slot_ref: Vec<(usize, usize)>,
    pub device: Device,
}

impl Graph {
    /// Builds the executable graph: resolves every input reference, uploads float constants,
    /// and fuses elementwise chains (see [`super::fuse`]).
    pub fn new(model: GraphModel, device: &Device) -> Result<Self> {
        Self::build(model, device, true)
    }

    /// [`Graph::new`] without the fusions: every node runs as written in the file (for parity
    /// checks of the fusions).
    pub fn unfused(model: GraphModel, device: &Device) -> Result<Self> {
        Self::build(model, device, false)
    }

    fn build(model: GraphModel, device: &Device, fuse: bool) -> Result<Self> {
        let source = model.path.display().to_string();
        let mut index = HashMap::new();
        for (i, n) in model.nodes.iter().enumerate() {
            if index.insert(n.name.clone(), i).is_some() {
                bail!("{source}: node name {:?} appears twice", n.name);
            }
        }
        let mut nodes = Vec::with_capacity(model.nodes.len());
        for def in model.nodes.iter() {
            let mut inputs = Vec::new();
            for r in &def.input {
                if r.starts_with('^') {
                    continue; // control dependency: no data
                }
                let (name, out) = parse_ref(r);
                let j = *index.get(name).ok_or_else(|| {
                    anyhow!("{source}: node {:?} reads missing node {r:?}", def.name)
                })?;
                inputs.push((j, out));
            }
            nodes.push(Node {
                def: def.clone(),
                inputs,
            });
        }
        let mut consts = HashMap::new();
        for (i, n) in nodes.iter().enumerate() {
            if n.op() != "Const" {
                continue;
            }
            let h = match model.weights.get(n.name()) {
                Some(h) => h.clone(),
                None => inline_const(&n.def)
                    .with_context(|| format!("{source}: constant node {:?}", n.name()))?,
            };
            let v = match &h.data {
                HostData::F32(v) if h.len() > 16 => {
                    let t = Tensor::<1>::from_data(TensorData::new(v.clone(), [v.len()]), device);
                    Value::Float(FloatValue::new(t.reshape(pad4(&h.shape)), h.shape.clone()))
                }
                _ => Value::Host(h),
            };
            consts.insert(i, v);
        }
        let conv_weights = ops::prepare_conv_weights(&source, &nodes, &consts, device)?;
        if fuse {
            super::fuse::hard_swish(&mut nodes, &consts);
        }
        let (flow, slot_of, slot_ref) = dataflow(&source, &nodes)?;
        Ok(Graph {
            source,
            nodes,
            index,
            consts,
            conv_weights,
            flow,
            slot_of,
            slot_ref,
            device: device.clone(),
        })
    }

    /// The index of a node by name (a `name:k` output reference is accepted).
    pub(crate) fn node_index(&self, name: &str) -> Option<usize> {
        self.index.get(parse_ref(name).0).copied()
    }

    /// The reference (`name` or `name:k`) of input `k` of node `i`.
    pub(crate) fn input_ref(&self, i: usize, k: usize) -> Option<String> {
        let &(j, out) = self.nodes[i].inputs.get(k)?;
        let name = self.nodes[j].name();
        Some(if out == 0 {
            name.to_string()
        } else {
            format!("{name}:{out}")
        })
    }

    /// Follows `Identity` nodes back from `output` to a `Sigmoid` and returns the reference of
    /// the sigmoid's input: the pre-sigmoid logits behind a probability output.
    pub(crate) fn sigmoid_input(&self, output: &str) -> Result<String> {
        let mut i = self
            .node_index(output)
            .ok_or_else(|| anyhow!("{}: no node named {output:?}", self.source))?;
        while self.nodes[i].op() == "Identity" {
            i = self.nodes[i].inputs.first().map(|x| x.0).unwrap_or(i);
        }
        if self.nodes[i].op() != "Sigmoid" {
            bail!("{}: {output:?} is not a sigmoid output", self.source);
        }
        self.input_ref(i, 0).ok_or_else(|| {
            anyhow!(
                "{}: sigmoid {:?} has no input",
                self.source,
                self.nodes[i].name()
            )
        })
    }

    /// The names of the graph inputs (Placeholder nodes).
    pub fn inputs(&self) -> Vec<&str> {
        self.nodes
            .iter()
            .filter(|n| n.op() == "Placeholder")
            .map(|n| n.name())
            .collect()
    }

    /// Runs the graph: `feeds` by Placeholder name, returns the values of `outputs`
    /// (node names, optionally `name:k` for the k-th output of a multi-output node).
    pub fn run(&self, feeds: &[(&str, Tensor<4>)], outputs: &[&str]) -> Result<Vec<Value>> {
        self.run_injected(feeds, &[], outputs)
    }

    /// Runs the graph with the outputs of some nodes replaced: each `(node name, value)` in
    /// `inject` stands for that node's output 0 (its ancestors are not run unless another path
    /// needs them). With an autodiff leaf injected, gradients of the outputs with respect to
    /// that intermediate activation can be taken (Grad-CAM). Values are logical (NHWC for
    /// rank 4), as [`Graph::run`] returns them.
    pub fn run_injected(
        &self,
        feeds: &[(&str, Tensor<4>)],
        inject: &[(&str, FloatValue)],
        outputs: &[&str],
    ) -> Result<Vec<Value>> {
        let src = &self.source;
        let slot = |r: &str| -> Result<usize> {
            let (name, k) = parse_ref(r);
            let i = self
                .node_index(name)
                .ok_or_else(|| anyhow!("{src}: no node named {name:?}"))?;
            (self.slot_of.get(&(i, k)).copied())
                .ok_or_else(|| anyhow!("{src}: node {name:?} has no output {k}"))
        };
        let mut inj = Vec::new();
        for (name, v) in inject {
            if parse_ref(name).1 != 0 {
                bail!("{src}: only output 0 of a node can be replaced ({name:?})");
            }
            inj.push((slot(name)?, Value::Float(v.clone())));
        }
        let mut fed = Vec::new();
        for (name, t) in feeds {
            let i = (self.node_index(name))
                .filter(|&i| self.nodes[i].op() == "Placeholder")
                .ok_or_else(|| anyhow!("{src}: the graph has no input {name:?}"))?;
            fed.push((
                self.slot_of[&(i, 0)],
                Value::Float(FloatValue::from4(t.clone())),
            ));
        }
        let want: Vec<usize> = outputs.iter().map(|o| slot(o)).collect::<Result<_>>()?;
        let run = exec::Run {
            feeds: fed,
            inject: inj,
            want: &want,
            taps: &[],
        };
        let (vals, _) = self.flow.run(self, run)?;
        Ok(vals
            .into_iter()
            .map(|v| match v {
                Value::Float(f) => Value::Float(f.logical()),
                h => h,
            })
            .collect())
    }
}

/// The slots of a resolved graph: one for output 0 of every node and for each further output
/// some node reads. Placeholders and constants write no slot as nodes: theirs are fed or
/// constant.
type Slots = (
    Dataflow,
    HashMap<(usize, usize), usize>,
    Vec<(usize, usize)>,
);
fn dataflow(source: &str, nodes: &[Node]) -> Result<Slots> {
    let mut width = vec![1usize; nodes.len()];
    for n in nodes {
        for &(j, k) in &n.inputs {
            width[j] = width[j].max(k + 1);
        }
    }
    let mut slot_of = HashMap::new();
    let mut slot_ref = Vec::new();
    let mut outputs = Vec::with_capacity(nodes.len());
    for (i, n) in nodes.iter().enumerate() {
        let source_node = matches!(n.op(), "Placeholder" | "Const");
        if source_node && width[i] > 1 {
            bail!(
                "{source}: {} node {:?} has one output, a node reads output {}",
                n.op(),
                n.name(),
                width[i] - 1
            );
        }
        let mut outs = Vec::new();
        for k in 0..width[i] {
            slot_of.insert((i, k), slot_ref.len());
            outs.push(slot_ref.len());
            slot_ref.push((i, k));
        }
        outputs.push(if source_node { vec![] } else { outs });
    }
    let inputs = nodes
        .iter()
        .map(|n| n.inputs.iter().map(|r| Some(slot_of[r])).collect())
        .collect();
    let flow = Dataflow::new(inputs, outputs, slot_ref.len())
        .with_context(|| format!("{source}: resolving the nodes"))?;
    Ok((flow, slot_of, slot_ref))
}

/// How the executor core evaluates a TFJS node.
impl exec::Ops for Graph {
    type Value = Value;

    fn eval(&self, k: usize, args: &[Option<&Value>]) -> Result<Vec<Value>> {
        let args: Vec<&Value> = args.iter().flatten().copied().collect();
        ops::eval(
            &self.nodes[k],
            self.conv_weights.get(&k),
            &self.device,
            &args,
        )
    }

    fn constant(&self, slot: usize) -> Option<&Value> {
        self.consts.get(&self.slot_ref.get(slot)?.0)
    }

    fn describe(&self, k: usize) -> String {
        format!(
            "node {:?} (op {})",
            self.nodes[k].name(),
            self.nodes[k].op()
        )
    }

    fn op(&self, k: usize) -> &str {
        self.nodes[k].op()
    }

    fn slot_name(&self, slot: usize) -> String {
        let (i, k) = self.slot_ref[slot];
        match k {
            0 => format!("{:?}", self.nodes[i].name()),
            k => format!("{:?}", format!("{}:{k}", self.nodes[i].name())),
        }
    }

    fn source(&self) -> String {
        self.source.clone()
    }

    fn settle(&self, v: &Value) -> Option<Vec<usize>> {
        match v {
            Value::Float(f) => {
                let _ = f.t.clone().slice([0..1, 0..1, 0..1, 0..1]).into_data();
                Some(f.shape.clone())
            }
            Value::Host(h) => Some(h.shape.clone()),
        }
    }
}

/// Splits `name:k` into (name, k); a plain name is output 0.
pub(crate) fn parse_ref(r: &str) -> (&str, usize) {
    if let Some((name, k)) = r.rsplit_once(':') {
        if let Ok(k) = k.parse() {
            return (name, k);
        }
    }
    (r, 0)
}

/// A constant whose value is inline in the node attributes (small scalars, some converters).
fn inline_const(def: &NodeDef) -> Result<HostTensor> {
    let t = def
        .attr
        .get("value")
        .and_then(|v| v.get("tensor"))
        .ok_or_else(|| anyhow!("has no value: neither in the weights manifest nor inline"))?;
    let dims: Vec<usize> = t
        .get("tensorShape")
        .and_then(|s| s.get("dim"))
        .and_then(|d| d.as_array())
        .map(|d| {
            d.iter()
                .map(|x| {
                    x.get("size")
                        .and_then(|s| {
                            s.as_str()
                                .and_then(|s| s.parse().ok())
                                .or(s.as_u64().map(|u| u as usize))
                        })
                        .unwrap_or(1)
                })
                .collect()
        })
        .unwrap_or_default();
    let n: usize = dims.iter().product();
    let dtype = t.get("dtype").and_then(|d| d.as_str()).unwrap_or("");
    let list = |key: &str| t.get(key).and_then(|v| v.as_array()).cloned();
    let data = if dtype == "DT_FLOAT" {
        let v: Vec<f32> = list("floatVal")
            .unwrap_or_default()
            .iter()
            .filter_map(|x| x.as_f64().map(|f| f as f32))
            .collect();
        HostData::F32(broadcast_fill(v, n)?)
    } else {
        let v: Vec<i64> = list("intVal")
            .or_else(|| list("int64Val"))
            .unwrap_or_default()
            .iter()
            .filter_map(|x| x.as_i64().or(x.as_str().and_then(|s| s.parse().ok())))
            .collect();
        HostData::I64(broadcast_fill(v, n)?)
    };
    Ok(HostTensor { shape: dims, data })
}

fn broadcast_fill<T: Clone>(v: Vec<T>, n: usize) -> Result<Vec<T>> {
    match v.len() {
        len if len == n => Ok(v),
        1 => Ok(vec![v[0].clone(); n]),
        0 if n == 0 => Ok(v),
        len => bail!("inline value has {len} elements, shape needs {n}"),
    }
}

/// Grad-CAM's view of a TFJS graph (values logical: NHWC, or NCHW where the converter kept it).
impl crate::detector::CamGraph for Graph {
    fn device(&self) -> Device {
        self.device.clone()
    }

    fn feature_layers(&self, outputs: &[&str]) -> Result<Vec<(String, String)>> {
        let want: Vec<usize> = (outputs.iter())
            .filter_map(|o| {
                let (name, k) = parse_ref(o);
                self.slot_of.get(&(self.node_index(name)?, k)).copied()
            })
            .collect();
        let anc = self.flow.needed(&want, &Default::default());
        Ok(self
            .nodes
            .iter()
            .enumerate()
            .filter(|(i, n)| {
                let op = n.op();
                anc[*i]
                    && (op.contains("Conv")
                        || matches!(
                            op,
                            "Relu" | "Relu6" | "LeakyRelu" | "AddV2" | "Add" | "ConcatV2" | "Mul"
                        ))
            })
            .map(|(_, n)| (n.name().to_string(), n.op().to_string()))
            .collect())
    }

    fn run_cam(
        &self,
        feeds: &[(&str, Tensor<4>)],
        inject: Option<(&str, Tensor<4>, &[usize])>,
        outputs: &[&str],
    ) -> Result<Vec<(Tensor<4>, Vec<usize>)>> {
        let inj: Vec<(&str, FloatValue)> = inject
            .map(|(n, t, s)| (n, FloatValue::new(t, s.to_vec())))
            .into_iter()
            .collect();
        self.run_injected(feeds, &inj, outputs)?
            .into_iter()
            .zip(outputs)
            .map(|(v, name)| match v {
                Value::Float(f) => Ok((f.t, f.shape)),
                Value::Host(_) => bail!("{}: {name:?} is not a float tensor", self.source),
            })
            .collect()
    }
}
