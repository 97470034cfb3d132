//! Executor for an imported TFJS graph: resolves node inputs, plans the ancestors of the
//! requested outputs, and evaluates them as burn tensor ops (see `ops.rs`).
//!
//! Float activations are burn tensors (differentiable, on the caller's device); shape, axis and
//! size arguments and other small integer tensors stay on the host. Only the nodes needed for
//! the requested outputs run, so a graph whose decode tail uses unsupported ops can still serve
//! its dense outputs. The graph is traced at batch 1; batch > 1 flows through because the
//! executor treats a leading 1 in a Reshape target as the batch dimension.

use super::model::{GraphModel, HostData, HostTensor, NodeDef};
use super::ops;
use super::value::{pad4, FloatValue, Node, Value};
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
    pub device: Device,
}

impl Graph {
    /// Builds the executable graph: resolves every input reference, uploads float constants,
    /// and fuses elementwise chains (see [`super::fuse`]).
    pub fn new(model: GraphModel, device: &Device) -> Result<Self> {
        let mut g = Self::unfused(model, device)?;
        super::fuse::hard_swish(&mut g.nodes, &g.consts);
        Ok(g)
    }

    /// [`Graph::new`] without the fusions: every node runs as written in the file (for parity
    /// checks of the fusions).
    pub fn unfused(model: GraphModel, device: &Device) -> Result<Self> {
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
        Ok(Graph {
            source,
            nodes,
            index,
            consts,
            conv_weights,
            device: device.clone(),
        })
    }

    /// The index of a node by name (a `name:k` output reference is accepted).
    pub fn node_index(&self, name: &str) -> Option<usize> {
        self.index.get(parse_ref(name).0).copied()
    }

    /// The reference (`name` or `name:k`) of input `k` of node `i`.
    pub fn input_ref(&self, i: usize, k: usize) -> Option<String> {
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
    pub fn sigmoid_input(&self, output: &str) -> Result<String> {
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
        let mut injected: HashMap<usize, FloatValue> = HashMap::new();
        for (name, v) in inject {
            let (n, k) = parse_ref(name);
            if k != 0 {
                bail!(
                    "{}: only output 0 of a node can be replaced ({name:?})",
                    self.source
                );
            }
            let i = self
                .node_index(n)
                .ok_or_else(|| anyhow!("{}: no node named {n:?}", self.source))?;
            injected.insert(i, v.clone());
        }
        let mut wanted = Vec::new();
        for o in outputs {
            let (name, k) = parse_ref(o);
            let i = self
                .node_index(name)
                .ok_or_else(|| anyhow!("{}: no node named {name:?}", self.source))?;
            wanted.push((i, k));
        }
        // Plan: ancestors of the wanted nodes, in a valid evaluation order (iterative DFS).
        let mut order = Vec::new();
        let mut state = vec![0u8; self.nodes.len()]; // 0 new, 1 on stack, 2 done
        for &(root, _) in &wanted {
            let mut stack = vec![(root, false)];
            while let Some((i, expanded)) = stack.pop() {
                if expanded {
                    state[i] = 2;
                    order.push(i);
                    continue;
                }
                match state[i] {
                    2 => continue,
                    1 => bail!(
                        "{}: the graph has a cycle at {:?}",
                        self.source,
                        self.nodes[i].name()
                    ),
                    _ => {}
                }
                state[i] = 1;
                stack.push((i, true));
                if injected.contains_key(&i) {
                    continue;
                }
                for &(j, _) in &self.nodes[i].inputs {
                    if state[j] == 0 {
                        stack.push((j, false));
                    } else if state[j] == 1 {
                        bail!(
                            "{}: the graph has a cycle at {:?}",
                            self.source,
                            self.nodes[j].name()
                        );
                    }
                }
            }
        }
        // Last use of each node, to free activations early.
        let mut last_use = vec![0usize; self.nodes.len()];
        for (step, &i) in order.iter().enumerate() {
            if injected.contains_key(&i) {
                continue;
            }
            for &(j, _) in &self.nodes[i].inputs {
                last_use[j] = step;
            }
        }
        for &(i, _) in &wanted {
            last_use[i] = usize::MAX;
        }
        let mut values: HashMap<usize, Vec<Value>> = HashMap::new();
        let profile = std::env::var_os("CAC_PROFILE_GRAPH").is_some();
        let mut op_ms: HashMap<String, f64> = HashMap::new();
        let mut node_ms: Vec<(f64, usize, Vec<usize>)> = Vec::new();
        for (step, &i) in order.iter().enumerate() {
            let started = std::time::Instant::now();
            let node = &self.nodes[i];
            let out = if let Some(v) = injected.get(&i) {
                vec![Value::Float(v.clone())]
            } else if node.op() == "Placeholder" {
                let t = feeds
                    .iter()
                    .find(|(n, _)| *n == node.name())
                    .map(|(_, t)| t.clone())
                    .ok_or_else(|| {
                        anyhow!("{}: no value fed for input {:?}", self.source, node.name())
                    })?;
                vec![Value::Float(FloatValue::from4(t))]
            } else if let Some(c) = self.consts.get(&i) {
                vec![c.clone()]
            } else {
                let args: Vec<&Value> = node
                    .inputs
                    .iter()
                    .map(|&(j, k)| {
                        values.get(&j).and_then(|v| v.get(k)).ok_or_else(|| {
                            anyhow!(
                                "{}: node {:?} reads output {k} of {:?}, which does not exist",
                                self.source,
                                node.name(),
                                self.nodes[j].name()
                            )
                        })
                    })
                    .collect::<Result<_>>()?;
                ops::eval(node, self.conv_weights.get(&i), &self.device, &args).with_context(
                    || format!("{}: node {:?} (op {})", self.source, node.name(), node.op()),
                )?
            };
            if profile {
                if let Some(Value::Float(f)) = out.first() {
                    let _ = f.t.clone().slice([0..1, 0..1, 0..1, 0..1]).into_data();
                }
                let ms = started.elapsed().as_secs_f64() * 1e3;
                *op_ms.entry(node.op().to_string()).or_default() += ms;
                if let Some(Value::Float(f)) = out.first() {
                    node_ms.push((ms, i, f.shape.clone()));
                }
            }
            values.insert(i, out);
            if injected.contains_key(&i) {
                continue;
            }
            for &(j, _) in &node.inputs {
                if last_use[j] == step {
                    values.remove(&j);
                }
            }
        }
        if profile {
            let mut v: Vec<_> = op_ms.into_iter().collect();
            v.sort_by(|a, b| b.1.total_cmp(&a.1));
            eprintln!("graph profile (ms per op type): {v:.1?}");
            node_ms.sort_by(|a, b| b.0.total_cmp(&a.0));
            for (ms, i, shape) in node_ms.iter().take(30) {
                let n = &self.nodes[*i];
                eprintln!("  {ms:7.2} ms  {:28} {shape:?}  {}", n.op(), n.name());
            }
        }
        wanted
            .iter()
            .zip(outputs)
            .map(|(&(i, k), name)| {
                values
                    .get(&i)
                    .and_then(|v| v.get(k))
                    .cloned()
                    .map(|v| match v {
                        Value::Float(f) => Value::Float(f.logical()),
                        h => h,
                    })
                    .ok_or_else(|| anyhow!("{}: node {name:?} has no output {k}", self.source))
            })
            .collect()
    }
}

/// Splits `name:k` into (name, k); a plain name is output 0.
pub fn parse_ref(r: &str) -> (&str, usize) {
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
impl crate::CamGraph for Graph {
    fn device(&self) -> Device {
        self.device.clone()
    }

    fn feature_layers(&self, outputs: &[&str]) -> Result<Vec<(String, String)>> {
        let mut anc = vec![false; self.nodes.len()];
        let mut stack: Vec<usize> = outputs.iter().filter_map(|n| self.node_index(n)).collect();
        while let Some(i) = stack.pop() {
            if !std::mem::replace(&mut anc[i], true) {
                stack.extend(self.nodes[i].inputs.iter().map(|x| x.0));
            }
        }
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
