//! Graph rewrites that run a chain of elementwise nodes as fewer burn ops.
//!
//! MobileNetV3's hard-swish is exported as four nodes over a full activation,
//! `Mul(X, c)`, `Add(X, 3)`, `Relu6`, `Mul`, i.e. four passes over memory, with `c` the float16
//! nearest 1/6 (0.16662598, so `6c` is 0.99975586, not 1). [`hard_swish`] rewrites the final
//! `Mul` into one `HardSwish` node reading `X` with attribute `scale = 6c`, evaluated as
//! `6c · X · clamp(X/6 + 1/2, 0, 1)` by one fused kernel each way (`activation::hard_swish`):
//! the same function, in one pass, with the chain's derivative at the kinks (TensorFlow's ReLU6
//! passes no gradient at its bounds: 0 at −3, 6c at 3; `tests/detect_fusion.rs`). The bypassed nodes stay in the graph, so a caller that asks for one
//! of them by name still gets it; they just no longer run for the others.

use super::model::HostData;
use super::value::{Node, Value};
use std::collections::HashMap;

/// What the rewrites read: the resolved nodes and the constant nodes' values.
struct View<'a> {
    nodes: &'a [Node],
    consts: &'a HashMap<usize, Value>,
}

/// The value of a one-element float constant node, if `i` is one.
fn scalar(g: &View, i: usize) -> Option<f32> {
    match g.consts.get(&i)? {
        Value::Host(h) if h.len() == 1 => match &h.data {
            HostData::F32(v) => Some(v[0]),
            HostData::I64(_) => None,
        },
        _ => None,
    }
}

/// Of a binary node's two inputs, the other one and the constant's value, where one input is a
/// scalar constant within `tol` of `c`.
fn split_scalar(g: &View, i: usize, c: f32, tol: f32) -> Option<((usize, usize), f32)> {
    let n = &g.nodes[i];
    if n.inputs.len() != 2 {
        return None;
    }
    let near = |k: usize| scalar(g, n.inputs[k].0).filter(|v| (v - c).abs() <= tol);
    match (near(0), near(1)) {
        (Some(v), None) => Some((n.inputs[1], v)),
        (None, Some(v)) => Some((n.inputs[0], v)),
        _ => None,
    }
}

/// Rewrites every `Mul(Mul(X, c), Relu6(Add(X, 3)))` (either operand order, `c` within float16
/// precision of 1/6) into `HardSwish(X)` with `scale = 6c`. Returns how many were rewritten.
pub fn hard_swish(nodes: &mut [Node], consts: &HashMap<usize, Value>) -> usize {
    let g = View {
        nodes: &*nodes,
        consts,
    };
    let mut consumers = vec![0usize; g.nodes.len()];
    for n in g.nodes {
        for &(j, _) in &n.inputs {
            consumers[j] += 1;
        }
    }
    let op = |g: &View, i: usize| g.nodes[i].op().to_string();
    let mut rewrites = Vec::new();
    for (i, n) in g.nodes.iter().enumerate() {
        if n.op() != "Mul" || n.inputs.len() != 2 {
            continue;
        }
        let match_pair = |relu: usize, scaled: usize| -> Option<((usize, usize), f32)> {
            if op(&g, relu) != "Relu6" || op(&g, scaled) != "Mul" {
                return None;
            }
            let (add, _) = *g.nodes[relu].inputs.first()?;
            if !matches!(op(&g, add).as_str(), "Add" | "AddV2") {
                return None;
            }
            let (x, three) = split_scalar(&g, add, 3.0, 0.0)?;
            let (x2, c) = split_scalar(&g, scaled, 1.0 / 6.0, 1e-3)?;
            let private = [relu, scaled, add].iter().all(|&k| consumers[k] == 1);
            (x == x2 && three == 3.0 && private).then_some((x, c))
        };
        let (a, b) = (n.inputs[0].0, n.inputs[1].0);
        if let Some((x, c)) = match_pair(a, b).or_else(|| match_pair(b, a)) {
            rewrites.push((i, x, c));
        }
    }
    for &(i, x, c) in &rewrites {
        let node = &mut nodes[i];
        node.def.op = "HardSwish".into();
        node.def
            .attr
            .insert("scale".into(), serde_json::json!({ "f": 6.0 * c as f64 }));
        node.inputs = vec![x];
    }
    rewrites.len()
}
