//! Runs an ONNX [`Model`] as burn tensor ops: values are resolved to slots once, large float
//! initializers are uploaded to the device once, and a run evaluates only the nodes the requested
//! outputs depend on, in the file's (topological) order, freeing each value after its last use.
//!
//! [`OnnxGraph::run_tapped`] also gives the *pre-sigmoid* version of the outputs: the nodes
//! downstream of chosen Sigmoid nodes are evaluated a second time with each of those sigmoids
//! replaced by the identity, so a detector whose exported output holds probabilities
//! (YOLOv5/v8) still yields exact class logits (for log-sigmoid losses) at the cost of its
//! decode tail only.

use super::model::{Io, Model, NodeDef};
use super::ops;
use super::value::{Dev, Val};
use anyhow::{anyhow, bail, Context, Result};
use burn::tensor::{Device, Tensor};
use std::collections::{HashMap, HashSet};

/// A model ready to run on one device.
pub struct OnnxGraph {
    pub model: Model,
    pub opset: i64,
    /// Value slot of every node input (`None`: omitted optional input).
    inputs: Vec<Vec<Option<usize>>>,
    outputs: Vec<Vec<usize>>,
    slots: HashMap<String, usize>,
    /// The node writing each slot (`None` for graph inputs and initializers).
    producer: Vec<Option<usize>>,
    consts: HashMap<usize, Val>,
    /// `Mul(x, Sigmoid(x))` pairs run as one SiLU: Mul node → (Sigmoid node, slot of `x`). Only
    /// where the sigmoid's output feeds that Mul alone and is not a graph output.
    silu: HashMap<usize, (usize, usize)>,
    silu_sigmoids: HashSet<usize>,
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
    let hint = if selects {
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
        let silu = silu_pairs(&model, &inputs, &outputs, &producer, &slots);
        let silu_sigmoids = silu.values().map(|&(j, _)| j).collect();
        Ok(OnnxGraph {
            model,
            opset,
            inputs,
            outputs,
            slots,
            producer,
            consts,
            silu,
            silu_sigmoids,
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
    pub fn producer_of(&self, name: &str) -> Option<usize> {
        self.producer[*self.slots.get(name)?]
    }

    /// The nodes producing the inputs of node `k` (omitted inputs, graph inputs and
    /// initializers have none).
    pub fn input_producers(&self, k: usize) -> Vec<Option<usize>> {
        self.inputs[k]
            .iter()
            .map(|s| s.and_then(|s| self.producer[s]))
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
    pub fn run_tapped(
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
    pub fn run_full(
        &self,
        feeds: &[(&str, Val)],
        inject: &[(&str, Val)],
        outputs: &[&str],
        taps: &[usize],
    ) -> Result<(Vec<Val>, Vec<Val>)> {
        let src = self.source();
        let mut injected: HashMap<usize, Val> = HashMap::new();
        for (name, v) in inject {
            let s = *self
                .slots
                .get(*name)
                .ok_or_else(|| anyhow!("{src}: no value named {name:?}"))?;
            injected.insert(s, v.clone());
        }
        let want: Vec<usize> = outputs
            .iter()
            .map(|o| {
                self.slots
                    .get(*o)
                    .copied()
                    .ok_or_else(|| anyhow!("{src}: no value named {o:?}"))
            })
            .collect::<Result<_>>()?;
        // The nodes the outputs depend on.
        let n = self.model.nodes.len();
        let mut needed = vec![false; n];
        let mut stack: Vec<usize> = want
            .iter()
            .filter(|s| !injected.contains_key(s))
            .filter_map(|&s| self.producer[s])
            .collect();
        while let Some(k) = stack.pop() {
            if std::mem::replace(&mut needed[k], true) {
                continue;
            }
            stack.extend(
                self.inputs[k]
                    .iter()
                    .flatten()
                    .filter(|s| !injected.contains_key(s))
                    .filter_map(|&s| self.producer[s]),
            );
        }
        let mut last_use: HashMap<usize, usize> = HashMap::new();
        for k in (0..n).filter(|&k| needed[k]) {
            for &s in self.inputs[k].iter().flatten() {
                last_use.insert(s, k);
            }
        }
        let keep: HashSet<usize> = want.iter().copied().collect();
        let mut vals: HashMap<usize, Val> = injected.clone();
        for (name, v) in feeds {
            let s = *self
                .slots
                .get(*name)
                .ok_or_else(|| anyhow!("{src}: the graph has no input {name:?}"))?;
            vals.insert(s, v.clone());
        }
        for i in &self.model.inputs {
            let s = self.slots[&i.name];
            if !vals.contains_key(&s) && !self.consts.contains_key(&s) && last_use.contains_key(&s)
            {
                bail!("{src}: no value fed for graph input {:?}", i.name);
            }
        }
        let tapped: HashSet<usize> = taps.iter().copied().collect();
        let mut alt: HashMap<usize, Val> = HashMap::new();
        let get = |vals: &HashMap<usize, Val>, s: usize| -> Option<Val> {
            vals.get(&s).or_else(|| self.consts.get(&s)).cloned()
        };
        let profile = std::env::var_os("CAC_PROFILE_GRAPH").is_some();
        let mut op_ms: HashMap<&str, f64> = HashMap::new();
        // Sigmoids of SiLU pairs left to their Mul in this run (not tapped, not injected into,
        // their input not on the pre-sigmoid pass, their output not asked for).
        let mut deferred: HashSet<usize> = HashSet::new();
        for k in (0..n).filter(|&k| needed[k]) {
            let started = std::time::Instant::now();
            let node = &self.model.nodes[k];
            if self.silu_sigmoids.contains(&k) {
                let (s, x) = (self.outputs[k][0], self.inputs[k][0]);
                if !tapped.contains(&k)
                    && !injected.contains_key(&s)
                    && !keep.contains(&s)
                    && x.is_some_and(|x| !alt.contains_key(&x))
                {
                    deferred.insert(k);
                    continue;
                }
            }
            let silu_x = (self.silu.get(&k))
                .filter(|(j, _)| deferred.contains(j))
                .map(|&(_, x)| x);
            let (args, out) = if let Some(x) = silu_x {
                let xv = get(&vals, x).ok_or_else(|| anyhow!("{src}: value {x} missing"))?;
                let out = ops::silu(node, self.opset, &self.device, &[Some(&xv)])
                    .with_context(|| format!("{src}: node {:?} (SiLU)", node.name))?;
                (Vec::new(), out)
            } else {
                let args: Vec<Option<Val>> = self.inputs[k]
                    .iter()
                    .map(|s| {
                        s.map(|s| get(&vals, s).ok_or_else(|| anyhow!("{src}: value {s} missing")))
                            .transpose()
                    })
                    .collect::<Result<_>>()?;
                let refs: Vec<Option<&Val>> = args.iter().map(|v| v.as_ref()).collect();
                let out = ops::eval(node, self.opset, &self.device, &refs)
                    .with_context(|| format!("{src}: node {:?} (op {})", node.name, node.op))?;
                (args, out)
            };
            if out.len() < self.outputs[k].len() {
                bail!(
                    "{src}: node {:?} ({}) gave {} outputs, the file names {}",
                    node.name,
                    node.op,
                    out.len(),
                    self.outputs[k].len()
                );
            }
            // The pre-sigmoid pass: tapped sigmoids pass their input; their dependants re-run.
            if tapped.contains(&k) {
                alt.insert(self.outputs[k][0], args[0].clone().expect("sigmoid input"));
            } else if self.inputs[k].iter().flatten().any(|s| alt.contains_key(s)) {
                let alt_args: Vec<Option<Val>> = self.inputs[k]
                    .iter()
                    .zip(&args)
                    .map(|(s, v)| s.and_then(|s| alt.get(&s).cloned()).or_else(|| v.clone()))
                    .collect();
                let refs: Vec<Option<&Val>> = alt_args.iter().map(|v| v.as_ref()).collect();
                let out = ops::eval(node, self.opset, &self.device, &refs).with_context(|| {
                    format!(
                        "{src}: node {:?} (op {}), pre-sigmoid pass",
                        node.name, node.op
                    )
                })?;
                for (s, v) in self.outputs[k].iter().zip(out) {
                    alt.insert(*s, v);
                }
            }
            if profile {
                if let Some(Val::D(d)) = out.first() {
                    let _ = d.t.clone().sum().into_scalar::<f32>(); // wait for the op
                }
                let op = if silu_x.is_some() {
                    "SiLU (Sigmoid+Mul)"
                } else {
                    node.op.as_str()
                };
                *op_ms.entry(op).or_default() += started.elapsed().as_secs_f64() * 1e3;
            }
            for (s, v) in self.outputs[k].iter().zip(out) {
                let v = injected.get(s).cloned().unwrap_or(v);
                vals.insert(*s, v);
            }
            for &s in self.inputs[k].iter().flatten() {
                if last_use.get(&s) == Some(&k) && !keep.contains(&s) {
                    vals.remove(&s);
                    alt.remove(&s);
                }
            }
        }
        if profile {
            let mut v: Vec<_> = op_ms.into_iter().collect();
            v.sort_by(|a, b| b.1.total_cmp(&a.1));
            eprintln!("onnx graph profile (ms per op type): {v:.1?}");
        }
        let pick = |m: &HashMap<usize, Val>, s: usize, name: &str| {
            m.get(&s)
                .or_else(|| self.consts.get(&s))
                .cloned()
                .ok_or_else(|| anyhow!("{src}: output {name:?} was not computed"))
        };
        let main = want
            .iter()
            .zip(outputs)
            .map(|(&s, o)| pick(&vals, s, o))
            .collect::<Result<Vec<_>>>()?;
        let pre = if taps.is_empty() {
            Vec::new()
        } else {
            want.iter()
                .zip(outputs)
                .map(|(&s, o)| {
                    alt.get(&s)
                        .cloned()
                        .map(Ok)
                        .unwrap_or_else(|| pick(&vals, s, o))
                })
                .collect::<Result<Vec<_>>>()?
        };
        Ok((main, pre))
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
impl crate::CamGraph for OnnxGraph {
    fn device(&self) -> Device {
        self.device.clone()
    }

    fn feature_layers(&self, outputs: &[&str]) -> Result<Vec<(String, String)>> {
        let mut needed = vec![false; self.model.nodes.len()];
        let mut stack: Vec<usize> = outputs.iter().filter_map(|o| self.producer_of(o)).collect();
        while let Some(k) = stack.pop() {
            if !std::mem::replace(&mut needed[k], true) {
                stack.extend(self.input_producers(k).into_iter().flatten());
            }
        }
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
