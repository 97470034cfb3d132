//! Runs an ONNX [`Model`] on the executor core ([`crate::exec`]): values are resolved to slots
//! once, large float initializers are uploaded to the device once, and `Mul(x, Sigmoid(x))` pairs
//! are fused into one SiLU. A run evaluates only the nodes the requested outputs depend on, in the
//! file's (topological) order, freeing each value after its last use.
//!
//! [`OnnxGraph::run_tapped`] also gives the *pre-sigmoid* version of the outputs: the nodes
//! downstream of chosen Sigmoid nodes are evaluated a second time with each of those sigmoids
//! replaced by the identity, so a detector whose exported output holds probabilities
//! (YOLOv5/v8) still yields exact class logits (for log-sigmoid losses) at the cost of its
//! decode tail only.

use super::model::{Io, Model, NodeDef};
use super::ops;
use super::value::{Dev, Val};
use crate::exec::{self, Dataflow};
use anyhow::{anyhow, bail, Context, Result};
use burn::tensor::{Device, Tensor};
use std::collections::HashMap;

/// A model ready to run on one device.
pub struct OnnxGraph {
    pub model: Model,
    pub opset: i64,
    flow: Dataflow,
    slots: HashMap<String, usize>,
    /// The value name of each slot.
    names: Vec<String>,
    consts: HashMap<usize, Val>,
    pub device: Device,
}

/// Initializers with more elements than this go to the device at load time.
const UPLOAD_OVER: usize = 16;

/// Every op type of `model` that cac does not run, at once (with how many nodes use it and the
/// first one's name), or Ok. A file with NMS or top-k selection inside is told how to export
/// the dense head instead.
fn unsupported(model: &Model) -> Result<()> {
    let mut missing: Vec<(String, usize, &str)> = vec![];
    for n in &model.nodes {
        let std = n.domain.is_empty() || n.domain == "ai.onnx";
        if std && ops::SUPPORTED.contains(&n.op.as_str()) {
            continue;
        }
        let op = if std {
            n.op.clone()
        } else {
            format!("{} (domain {})", n.op, n.domain)
        };
        match missing.iter_mut().find(|m| m.0 == op) {
            Some(m) => m.1 += 1,
            None => missing.push((op, 1, n.name.as_str())),
        }
    }
    if missing.is_empty() {
        return Ok(());
    }
    let list: Vec<String> = missing
        .iter()
        .map(|(op, k, first)| match k {
            1 => format!("{op} (node {first:?})"),
            _ => format!("{op} ({k} nodes, first {first:?})"),
        })
        .collect();
    // Ops that select boxes (NMS, top-k) and the unsupported ops that come with them in
    // `nms=True` and end-to-end exports: both present means selection inside the file.
    const SELECTS: [&str; 2] = ["NonMaxSuppression", "TopK"];
    const WITH_SELECTION: [&str; 4] = ["NonMaxSuppression", "TopK", "NonZero", "GatherElements"];
    let selects = model.nodes.iter().any(|n| SELECTS.contains(&n.op.as_str()))
        && missing
            .iter()
            .any(|m| WITH_SELECTION.contains(&m.0.as_str()));
    // Quantized files (onnxruntime's quantizer, QDQ exports): cac runs float graphs.
    const QUANTIZED: [&str; 8] = [
        "DynamicQuantizeLinear",
        "QuantizeLinear",
        "DequantizeLinear",
        "ConvInteger",
        "MatMulInteger",
        "QLinearConv",
        "QLinearMatMul",
        "QLinearAdd",
    ];
    let quantized = missing.iter().any(|m| QUANTIZED.contains(&m.0.as_str()));
    let hint = if quantized {
        "\n  The file is quantized (int8 weights or activations, as onnxruntime's quantizer or a \
         QDQ export writes them): cac attacks and differentiates in float. Give it the float \
         model, the file before quantization."
    } else if selects {
        "\n  The file has NMS or top-k selection inside (an `nms=True` export, or the end-to-end head \
         of YOLOv10 / YOLO26): cac needs the dense head, every candidate box with its class \
         scores, because the attack and the overlap rule work on the candidates before any \
         selection. Export the dense head instead: ultralytics `model.export(format=\"onnx\")` \
         with `nms` left at its default (`nms=True` embeds NMS, `nms=False` picks the NMS-free \
         end-to-end head; both select boxes inside the file)."
    } else {
        ""
    };
    bail!(
        "{}: cac does not support {} op type{} of this file: {}{hint}\n  (supported: {})",
        model.source(),
        missing.len(),
        if missing.len() == 1 { "" } else { "s" },
        list.join(", "),
        ops::SUPPORTED.join(", ")
    )
}

impl OnnxGraph {
    /// Resolves `model` for `device`: checks the opset and that every node's inputs exist and
    /// its op is supported (an error names the file, the node and its op type).
    pub fn new(model: Model, device: &Device) -> Result<Self> {
        let src = model.source();
        let opset = model.opset()?;
        let mut slots: HashMap<String, usize> = HashMap::new();
        let mut producer = Vec::new();
        fn slot(
            slots: &mut HashMap<String, usize>,
            name: &str,
            by: Option<usize>,
            producer: &mut Vec<Option<usize>>,
        ) -> usize {
            let n = slots.len();
            let s = *slots.entry(name.to_string()).or_insert(n);
            if s == producer.len() {
                producer.push(by);
            } else if by.is_some() {
                producer[s] = by;
            }
            s
        }
        let mut consts = HashMap::new();
        for (name, h) in &model.initializers {
            let s = slot(&mut slots, name, None, &mut producer);
            let v = if h.len() > UPLOAD_OVER && matches!(h, super::value::Host::F(_)) {
                Val::D(h.to_dev(device)?)
            } else {
                Val::H(h.clone())
            };
            consts.insert(s, v);
        }
        for i in &model.inputs {
            slot(&mut slots, &i.name, None, &mut producer);
        }
        unsupported(&model)?;
        let mut inputs = Vec::new();
        let mut outputs = Vec::new();
        for (k, n) in model.nodes.iter().enumerate() {
            let mut ins = Vec::new();
            for r in &n.inputs {
                if r.is_empty() {
                    ins.push(None);
                    continue;
                }
                let s = *slots.get(r).ok_or_else(|| {
                    anyhow!("{src}: node {:?} ({}) reads {r:?}, which no earlier node, input or initializer defines", n.name, n.op)
                })?;
                ins.push(Some(s));
            }
            inputs.push(ins);
            outputs.push(
                n.outputs
                    .iter()
                    .map(|o| slot(&mut slots, o, Some(k), &mut producer))
                    .collect(),
            );
        }
        for o in &model.outputs {
            if !slots.contains_key(&o.name) {
                bail!(
                    "{src}: graph output {:?} is not produced by any node",
                    o.name
                );
            }
        }
        let pairs = silu_pairs(&model, &inputs, &outputs, &producer, &slots);
        let mut names = vec![String::new(); slots.len()];
        for (name, &s) in &slots {
            names[s] = name.clone();
        }
        let mut flow = Dataflow::new(inputs, outputs, slots.len())
            .with_context(|| format!("{src}: resolving the nodes"))?;
        for (mul, (sigmoid, x)) in pairs {
            flow.fuse(mul, sigmoid, x);
        }
        Ok(OnnxGraph {
            model,
            opset,
            flow,
            slots,
            names,
            consts,
            device: device.clone(),
        })
    }

    pub fn source(&self) -> String {
        self.model.source()
    }
    pub fn graph_inputs(&self) -> &[Io] {
        &self.model.inputs
    }
    pub fn graph_outputs(&self) -> &[Io] {
        &self.model.outputs
    }
    pub fn node(&self, k: usize) -> &NodeDef {
        &self.model.nodes[k]
    }

    /// The node producing value `name`.
    pub(crate) fn producer_of(&self, name: &str) -> Option<usize> {
        self.flow.producer(*self.slots.get(name)?)
    }

    /// The nodes producing the inputs of node `k` (omitted inputs, graph inputs and
    /// initializers have none).
    pub(crate) fn input_producers(&self, k: usize) -> Vec<Option<usize>> {
        self.flow
            .inputs(k)
            .iter()
            .map(|s| s.and_then(|s| self.flow.producer(s)))
            .collect()
    }

    /// Runs the graph on `feeds` (by graph-input name) and returns `outputs` (value names).
    pub fn run(&self, feeds: &[(&str, Val)], outputs: &[&str]) -> Result<Vec<Val>> {
        Ok(self.run_tapped(feeds, outputs, &[])?.0)
    }

    /// [`OnnxGraph::run`] feeding one image batch `[B, C, H, W]` to the graph input `input`.
    pub fn run_images(&self, input: &str, x: Tensor<4>, outputs: &[&str]) -> Result<Vec<Val>> {
        self.run(&[(input, Val::D(Dev::from(x)?))], outputs)
    }

    /// Runs the graph and returns `(outputs, outputs with the sigmoid nodes in taps replaced by
    /// the identity)`; the second list is empty when `taps` is.
    pub(crate) fn run_tapped(
        &self,
        feeds: &[(&str, Val)],
        outputs: &[&str],
        taps: &[usize],
    ) -> Result<(Vec<Val>, Vec<Val>)> {
        self.run_full(feeds, &[], outputs, taps)
    }

    /// [`OnnxGraph::run_tapped`] with the values of some graph values replaced (`inject`: value
    /// name, value): the nodes only they depend on are not run (Grad-CAM injects an autodiff
    /// leaf in place of a feature map).
    pub(crate) fn run_full(
        &self,
        feeds: &[(&str, Val)],
        inject: &[(&str, Val)],
        outputs: &[&str],
        taps: &[usize],
    ) -> Result<(Vec<Val>, Vec<Val>)> {
        let src = self.source();
        let slot = |name: &str, what: &str| {
            self.slots
                .get(name)
                .copied()
                .ok_or_else(|| anyhow!("{src}: {what} {name:?}"))
        };
        let want: Vec<usize> = outputs
            .iter()
            .map(|o| slot(o, "no value named"))
            .collect::<Result<_>>()?;
        let run = exec::Run {
            feeds: (feeds.iter())
                .map(|(n, v)| Ok((slot(n, "the graph has no input")?, v.clone())))
                .collect::<Result<_>>()?,
            inject: (inject.iter())
                .map(|(n, v)| Ok((slot(n, "no value named")?, v.clone())))
                .collect::<Result<_>>()?,
            want: &want,
            taps,
        };
        self.flow.run(self, run)
    }
}

/// How the executor core evaluates an ONNX node.
impl exec::Ops for OnnxGraph {
    type Value = Val;

    fn eval(&self, k: usize, args: &[Option<&Val>]) -> Result<Vec<Val>> {
        ops::eval(&self.model.nodes[k], self.opset, &self.device, args)
    }

    /// A `Mul` fused with its `Sigmoid`: SiLU.
    fn eval_fused(&self, k: usize, x: &Val) -> Result<Vec<Val>> {
        ops::silu(&self.model.nodes[k], self.opset, &self.device, &[Some(x)])
    }

    fn constant(&self, slot: usize) -> Option<&Val> {
        self.consts.get(&slot)
    }

    fn describe(&self, k: usize) -> String {
        let n = &self.model.nodes[k];
        format!("node {:?} (op {})", n.name, n.op)
    }

    fn op(&self, k: usize) -> &str {
        &self.model.nodes[k].op
    }

    fn fused_op(&self, _k: usize) -> String {
        "SiLU (Sigmoid+Mul)".into()
    }

    fn slot_name(&self, slot: usize) -> String {
        format!("{:?}", self.names[slot])
    }

    fn source(&self) -> String {
        self.model.source()
    }

    fn settle(&self, v: &Val) -> Option<Vec<usize>> {
        if let Val::D(d) = v {
            let _ = d.t.clone().sum().into_scalar::<f32>();
        }
        Some(v.shape().to_vec())
    }
}

/// The `Mul(x, Sigmoid(x))` pairs (SiLU, as PyTorch exports it) of the graph: Mul node →
/// (Sigmoid node, slot of `x`), where the sigmoid's output has no other reader and is not a graph
/// output.
fn silu_pairs(
    model: &Model,
    inputs: &[Vec<Option<usize>>],
    outputs: &[Vec<usize>],
    producer: &[Option<usize>],
    slots: &HashMap<String, usize>,
) -> HashMap<usize, (usize, usize)> {
    let mut readers = vec![0usize; producer.len()];
    for s in inputs.iter().flatten().flatten() {
        readers[*s] += 1;
    }
    for o in &model.outputs {
        if let Some(&s) = slots.get(&o.name) {
            readers[s] += 1;
        }
    }
    let mut pairs = HashMap::new();
    for (k, n) in model.nodes.iter().enumerate() {
        let (Some(a), Some(b)) = (
            inputs[k].first().copied().flatten(),
            inputs[k].get(1).copied().flatten(),
        ) else {
            continue;
        };
        if n.op != "Mul" || inputs[k].len() != 2 {
            continue;
        }
        for (s, x) in [(a, b), (b, a)] {
            let Some(j) = producer[s] else { continue };
            if model.nodes[j].op == "Sigmoid"
                && inputs[j].first() == Some(&Some(x))
                && outputs[j].first() == Some(&s)
                && readers[s] == 1
            {
                pairs.insert(k, (j, x));
                break;
            }
        }
    }
    pairs
}

/// Grad-CAM's view of an ONNX graph: layers are node output values, feature maps are NCHW.
impl crate::detector::CamGraph for OnnxGraph {
    fn device(&self) -> Device {
        self.device.clone()
    }

    fn feature_layers(&self, outputs: &[&str]) -> Result<Vec<(String, String)>> {
        let want: Vec<usize> = outputs
            .iter()
            .filter_map(|o| self.slots.get(*o).copied())
            .collect();
        let needed = self.flow.needed(&want, &Default::default());
        Ok(self
            .model
            .nodes
            .iter()
            .enumerate()
            .filter(|(k, n)| {
                needed[*k]
                    && matches!(
                        n.op.as_str(),
                        "Conv" | "Relu" | "LeakyRelu" | "Add" | "Mul" | "Concat" | "HardSwish"
                    )
            })
            .filter_map(|(_, n)| Some((n.outputs.first()?.clone(), n.op.clone())))
            .collect())
    }

    fn run_cam(
        &self,
        feeds: &[(&str, Tensor<4>)],
        inject: Option<(&str, Tensor<4>, &[usize])>,
        outputs: &[&str],
    ) -> Result<Vec<(Tensor<4>, Vec<usize>)>> {
        let feeds: Vec<(&str, Val)> = feeds
            .iter()
            .map(|(n, t)| Ok((*n, Val::D(Dev::from(t.clone())?))))
            .collect::<Result<_>>()?;
        let inj: Vec<(&str, Val)> = match inject {
            Some((n, t, s)) => vec![(n, Val::D(Dev::new(t, s.to_vec())?))],
            None => vec![],
        };
        let (vals, _) = self.run_full(&feeds, &inj, outputs, &[])?;
        vals.into_iter()
            .zip(outputs)
            .map(|(v, name)| {
                let d = v.dev(&self.device)?;
                // Rank 5 and 6 (YOLOv5's [1, 3, h, w, 5 + C] head): the leading axes folded
                // into one, so the last three keep their meaning.
                let r = d.rank();
                if r > 4 {
                    let s = &d.shape;
                    let lead: usize = s[..r - 3].iter().product();
                    let shape = [lead, s[r - 3], s[r - 2], s[r - 1]];
                    return Ok((d.t.clone().reshape(shape), shape.to_vec()));
                }
                let t = d
                    .t4()
                    .with_context(|| format!("{}: value {name:?}", self.source()))?;
                Ok((t, d.shape))
            })
            .collect()
    }

    /// Every `[1, C, h, w]` value is channels-first.
    fn channel_axis(&self, shape: &[usize]) -> Option<usize> {
        matches!(shape, [1, _, _, _]).then_some(1)
    }
}
