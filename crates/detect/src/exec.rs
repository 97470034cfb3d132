//! The graph executor both model formats share (TFJS graphs and ONNX files): a dataflow of
//! nodes over value slots, and one run loop over it.
//!
//! A format resolves its file into a [`Dataflow`] (each node's input and output slots) and says
//! how one node is evaluated ([`Ops`]); the core does the rest, once for both: it plans the nodes
//! the requested outputs depend on and runs them in topological order (the file's order where the
//! file is sorted), frees each value after its last read, replaces injected values (Grad-CAM's
//! autodiff leaf in place of a feature map) without running what only they depend on, runs fused
//! pairs as one op, re-evaluates what lies downstream of *tapped* nodes with those nodes as the
//! identity (the pre-sigmoid logits behind a probability output), and profiles per op type and
//! per node when [`set_profiling`] is on.

use anyhow::{anyhow, bail, Context, Result};
use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap, HashSet};
use std::sync::atomic::{AtomicBool, Ordering};

static PROFILE: AtomicBool = AtomicBool::new(false);

/// Turns per-op profiling of every graph run on or off (printed to stderr after each run). The
/// binary sets it from `CAC_PROFILE_GRAPH`; library code reads no environment.
pub fn set_profiling(on: bool) {
    PROFILE.store(on, Ordering::Relaxed);
}

/// What a format tells the core about its nodes and values.
pub(crate) trait Ops {
    /// The values on the graph's edges (device tensors and small host tensors).
    type Value: Clone;
    /// Evaluates node `k` on its inputs (`None`: an omitted optional input).
    fn eval(&self, k: usize, args: &[Option<&Self::Value>]) -> Result<Vec<Self::Value>>;
    /// Evaluates the fused pair whose outer node is `k` ([`Dataflow::fuse`]) on the inner node's
    /// input `x`.
    fn eval_fused(&self, k: usize, _x: &Self::Value) -> Result<Vec<Self::Value>> {
        bail!("{}: no fused form", self.describe(k))
    }
    /// The value of a constant slot (weights, initializers), if `slot` is one.
    fn constant(&self, slot: usize) -> Option<&Self::Value>;
    /// `node "name" (op Type)`, for errors and profiles.
    fn describe(&self, k: usize) -> String;
    /// The op type of node `k`, for the profile.
    fn op(&self, k: usize) -> &str;
    /// What the fused pair whose outer node is `k` computes, for the profile.
    fn fused_op(&self, k: usize) -> String {
        format!("{} (fused)", self.op(k))
    }
    /// The name of a slot (a graph input, for "no value fed" errors).
    fn slot_name(&self, slot: usize) -> String;
    /// The file the graph came from, for errors.
    fn source(&self) -> String;
    /// Waits until `v` is computed and returns its shape (profiling only).
    fn settle(&self, v: &Self::Value) -> Option<Vec<usize>>;
}

/// A graph's nodes as slot readers and writers, with a topological rank for each node.
pub(crate) struct Dataflow {
    inputs: Vec<Vec<Option<usize>>>,
    outputs: Vec<Vec<usize>>,
    /// The node writing each slot (`None`: graph inputs, constants).
    producer: Vec<Option<usize>>,
    /// Position of each node in a topological order (`None`: on or after a cycle).
    rank: Vec<Option<usize>>,
    /// Fused pairs: outer node → (inner node, slot of the inner node's input).
    fused: HashMap<usize, (usize, usize)>,
    fused_inner: HashSet<usize>,
}

/// What a run returns: the values asked for, and their pre-tap versions (empty without taps).
pub type Outputs<V> = (Vec<V>, Vec<V>);

/// One run's requests.
pub struct Run<'a, V> {
    /// Values of the graph inputs, by slot.
    pub feeds: Vec<(usize, V)>,
    /// Values that replace what a node would write, by slot.
    pub inject: Vec<(usize, V)>,
    /// The slots to return.
    pub want: &'a [usize],
    /// Nodes that pass their first input through on the second ("pre-tap") pass.
    pub taps: &'a [usize],
}

impl Dataflow {
    /// The dataflow of `inputs[k]` / `outputs[k]` (slots read and written by node `k`) over
    /// `slots` slots. Ranks follow the smallest-index-first topological order, so a file whose
    /// nodes are already sorted runs in its own order; nodes on a cycle get no rank (a run that
    /// needs one is refused).
    pub fn new(
        inputs: Vec<Vec<Option<usize>>>,
        outputs: Vec<Vec<usize>>,
        slots: usize,
    ) -> Result<Self> {
        let n = inputs.len();
        if outputs.len() != n {
            bail!("{n} nodes' inputs but {} nodes' outputs", outputs.len());
        }
        let mut producer = vec![None; slots];
        for (k, outs) in outputs.iter().enumerate() {
            for &s in outs {
                *producer
                    .get_mut(s)
                    .ok_or_else(|| anyhow!("slot {s} out of range ({slots} slots)"))? = Some(k);
            }
        }
        let mut indegree = vec![0usize; n];
        let mut readers: Vec<Vec<usize>> = vec![vec![]; n];
        for (k, ins) in inputs.iter().enumerate() {
            for &s in ins.iter().flatten() {
                let p = *producer
                    .get(s)
                    .ok_or_else(|| anyhow!("slot {s} out of range ({slots} slots)"))?;
                if let Some(p) = p {
                    indegree[k] += 1;
                    readers[p].push(k);
                }
            }
        }
        let mut ready: BinaryHeap<Reverse<usize>> =
            (0..n).filter(|&k| indegree[k] == 0).map(Reverse).collect();
        let mut rank = vec![None; n];
        let mut next = 0;
        while let Some(Reverse(k)) = ready.pop() {
            rank[k] = Some(next);
            next += 1;
            for &r in &readers[k] {
                indegree[r] -= 1;
                if indegree[r] == 0 {
                    ready.push(Reverse(r));
                }
            }
        }
        Ok(Dataflow {
            inputs,
            outputs,
            producer,
            rank,
            fused: HashMap::new(),
            fused_inner: HashSet::new(),
        })
    }

    /// Runs `outer` as one fused op ([`Ops::eval_fused`]) on `x`, the input of `inner`, wherever
    /// `inner`'s output is needed by nothing else in a run (not asked for, not injected, not
    /// tapped and `x` not on the pre-tap pass); elsewhere both run as written.
    pub fn fuse(&mut self, outer: usize, inner: usize, x: usize) {
        self.fused.insert(outer, (inner, x));
        self.fused_inner.insert(inner);
    }

    pub fn inputs(&self, k: usize) -> &[Option<usize>] {
        &self.inputs[k]
    }
    pub fn producer(&self, slot: usize) -> Option<usize> {
        self.producer.get(slot).copied().flatten()
    }
    pub fn len(&self) -> usize {
        self.inputs.len()
    }

    /// Which nodes `want` depends on, not looking past the slots in `cut` (injected values).
    pub fn needed(&self, want: &[usize], cut: &HashSet<usize>) -> Vec<bool> {
        let mut needed = vec![false; self.len()];
        let mut stack: Vec<usize> = want
            .iter()
            .filter(|s| !cut.contains(s))
            .filter_map(|&s| self.producer(s))
            .collect();
        while let Some(k) = stack.pop() {
            if std::mem::replace(&mut needed[k], true) {
                continue;
            }
            stack.extend(
                self.inputs[k]
                    .iter()
                    .flatten()
                    .filter(|s| !cut.contains(s))
                    .filter_map(|&s| self.producer(s)),
            );
        }
        needed
    }

    /// Runs what `run.want` needs and returns `(values, pre-tap values)`; the second list is
    /// empty when `run.taps` is.
    pub fn run<O: Ops>(&self, ops: &O, run: Run<O::Value>) -> Result<Outputs<O::Value>> {
        let src = ops.source();
        let injected: HashMap<usize, O::Value> = run.inject.into_iter().collect();
        let cut: HashSet<usize> = injected.keys().copied().collect();
        let needed = self.needed(run.want, &cut);
        let order = self.run_order(ops, &needed, &src)?;
        let last_read = self.last_reads(&order);
        let keep: HashSet<usize> = run.want.iter().copied().collect();
        let mut vals: HashMap<usize, O::Value> = injected.clone();
        vals.extend(run.feeds);
        self.check_fed(ops, &order, &vals, &src)?;
        let mut state = RunState {
            flow: self,
            ops,
            src,
            injected,
            keep,
            tapped: run.taps.iter().copied().collect(),
            last_read,
            vals,
            pre: HashMap::new(),
            deferred: HashSet::new(),
        };
        let mut profile = PROFILE.load(Ordering::Relaxed).then(Profile::default);
        for &k in &order {
            let started = std::time::Instant::now();
            if state.defer_inner(k) {
                continue;
            }
            let fused_x = (self.fused.get(&k))
                .filter(|(inner, _)| state.deferred.contains(inner))
                .map(|&(_, x)| x);
            let (args, out) = state.eval_node(k, fused_x)?;
            state.pre_tap_pass(k, &args)?;
            if let Some(p) = profile.as_mut() {
                let shape = out.first().and_then(|v| ops.settle(v));
                let op = if fused_x.is_some() {
                    ops.fused_op(k)
                } else {
                    ops.op(k).to_string()
                };
                p.add(op, k, shape, started.elapsed().as_secs_f64() * 1e3);
            }
            state.store_outputs(k, out);
            state.free_inputs(k);
        }
        if let Some(p) = profile {
            p.print(ops);
        }
        state.results(run.want, !run.taps.is_empty())
    }

    /// The needed nodes in topological order; a needed node on a cycle is an error.
    fn run_order<O: Ops>(&self, ops: &O, needed: &[bool], src: &str) -> Result<Vec<usize>> {
        let mut order = Vec::new();
        for k in (0..self.len()).filter(|&k| needed[k]) {
            let r = self.rank[k]
                .ok_or_else(|| anyhow!("{src}: the graph has a cycle at {}", ops.describe(k)))?;
            order.push((r, k));
        }
        order.sort_unstable();
        Ok(order.into_iter().map(|(_, k)| k).collect())
    }

    /// The last node of `order` reading each slot, to free values early.
    fn last_reads(&self, order: &[usize]) -> HashMap<usize, usize> {
        let mut last_read: HashMap<usize, usize> = HashMap::new();
        for &k in order {
            for &s in self.inputs[k].iter().flatten() {
                last_read.insert(s, k);
            }
        }
        last_read
    }

    /// Refuses a run where a graph input read by `order` is neither fed nor a constant.
    fn check_fed<O: Ops>(
        &self,
        ops: &O,
        order: &[usize],
        vals: &HashMap<usize, O::Value>,
        src: &str,
    ) -> Result<()> {
        for &k in order {
            for &s in self.inputs[k].iter().flatten() {
                if self.producer(s).is_none() && !vals.contains_key(&s) && ops.constant(s).is_none()
                {
                    bail!("{src}: no value fed for graph input {}", ops.slot_name(s));
                }
            }
        }
        Ok(())
    }
}

/// A node's arguments (`None`: an omitted optional input) and its outputs.
type Evaluated<V> = (Vec<Option<V>>, Vec<V>);

/// One run in progress: the values computed so far and what the run asked for.
struct RunState<'r, O: Ops> {
    flow: &'r Dataflow,
    ops: &'r O,
    src: String,
    injected: HashMap<usize, O::Value>,
    /// What is asked for (never freed).
    keep: HashSet<usize>,
    tapped: HashSet<usize>,
    last_read: HashMap<usize, usize>,
    vals: HashMap<usize, O::Value>,
    /// Values of the pre-tap pass, where they differ from `vals`.
    pre: HashMap<usize, O::Value>,
    /// Inner nodes of fused pairs left to their outer node in this run.
    deferred: HashSet<usize>,
}

impl<O: Ops> RunState<'_, O> {
    /// The value of slot `s`: computed, fed, injected or constant.
    fn get(&self, s: usize) -> Result<O::Value> {
        let (ops, src) = (self.ops, &self.src);
        self.vals
            .get(&s)
            .or_else(|| ops.constant(s))
            .cloned()
            .ok_or_else(|| anyhow!("{src}: value {} missing", ops.slot_name(s)))
    }

    /// Leaves node `k` to its fused outer node (true) where `k` is an inner node whose output
    /// nothing else in this run needs.
    fn defer_inner(&mut self, k: usize) -> bool {
        let flow = self.flow;
        if !flow.fused_inner.contains(&k) {
            return false;
        }
        let (s, x) = (flow.outputs[k][0], flow.inputs[k][0]);
        let alone = !self.tapped.contains(&k)
            && !self.injected.contains_key(&s)
            && !self.keep.contains(&s)
            && x.is_some_and(|x| !self.pre.contains_key(&x));
        if alone {
            self.deferred.insert(k);
        }
        alone
    }

    /// Evaluates node `k` (as the fused op on `fused_x` where given) and returns its arguments
    /// (empty when fused) and outputs, checking it gave as many outputs as the graph reads.
    fn eval_node(&self, k: usize, fused_x: Option<usize>) -> Result<Evaluated<O::Value>> {
        let (flow, ops, src) = (self.flow, self.ops, &self.src);
        let (args, out) = if let Some(x) = fused_x {
            let out = ops
                .eval_fused(k, &self.get(x)?)
                .with_context(|| format!("{src}: {} (fused)", ops.describe(k)))?;
            (Vec::new(), out)
        } else {
            let args: Vec<Option<O::Value>> = flow.inputs[k]
                .iter()
                .map(|s| s.map(|s| self.get(s)).transpose())
                .collect::<Result<_>>()?;
            let refs: Vec<Option<&O::Value>> = args.iter().map(|v| v.as_ref()).collect();
            let out = ops
                .eval(k, &refs)
                .with_context(|| format!("{src}: {}", ops.describe(k)))?;
            (args, out)
        };
        if out.len() < flow.outputs[k].len() {
            bail!(
                "{src}: {} gave {} outputs, the graph reads {}",
                ops.describe(k),
                out.len(),
                flow.outputs[k].len()
            );
        }
        Ok((args, out))
    }

    /// The pre-tap pass: tapped nodes pass their input; their dependants run again.
    fn pre_tap_pass(&mut self, k: usize, args: &[Option<O::Value>]) -> Result<()> {
        let (flow, ops, src) = (self.flow, self.ops, &self.src);
        if self.tapped.contains(&k) {
            let x = args
                .first()
                .cloned()
                .flatten()
                .ok_or_else(|| anyhow!("{src}: tapped {} has no input", ops.describe(k)))?;
            self.pre.insert(flow.outputs[k][0], x);
        } else if flow.inputs[k]
            .iter()
            .flatten()
            .any(|s| self.pre.contains_key(s))
        {
            let pre_args: Vec<Option<O::Value>> = flow.inputs[k]
                .iter()
                .zip(args)
                .map(|(s, v)| {
                    s.and_then(|s| self.pre.get(&s).cloned())
                        .or_else(|| v.clone())
                })
                .collect();
            let refs: Vec<Option<&O::Value>> = pre_args.iter().map(|v| v.as_ref()).collect();
            let out = ops
                .eval(k, &refs)
                .with_context(|| format!("{src}: {}, pre-tap pass", ops.describe(k)))?;
            for (s, v) in flow.outputs[k].iter().zip(out) {
                self.pre.insert(*s, v);
            }
        }
        Ok(())
    }

    /// Keeps the outputs of node `k` that are read later or asked for (injected values win).
    fn store_outputs(&mut self, k: usize, out: Vec<O::Value>) {
        for (s, v) in self.flow.outputs[k].iter().zip(out) {
            let read = self.last_read.contains_key(s) || self.keep.contains(s);
            if read {
                let v = self.injected.get(s).cloned().unwrap_or(v);
                self.vals.insert(*s, v);
            }
        }
    }

    /// Frees the inputs node `k` read last, unless they are asked for.
    fn free_inputs(&mut self, k: usize) {
        for &s in self.flow.inputs[k].iter().flatten() {
            if self.last_read.get(&s) == Some(&k) && !self.keep.contains(&s) {
                self.vals.remove(&s);
                self.pre.remove(&s);
            }
        }
    }

    /// The values of `want`, and their pre-tap versions when the run had taps.
    fn results(&self, want: &[usize], with_pre: bool) -> Result<Outputs<O::Value>> {
        let (ops, src) = (self.ops, &self.src);
        let pick = |m: &HashMap<usize, O::Value>, s: usize| {
            m.get(&s)
                .or_else(|| ops.constant(s))
                .cloned()
                .ok_or_else(|| anyhow!("{src}: {} was not computed", ops.slot_name(s)))
        };
        let main = (want.iter())
            .map(|&s| pick(&self.vals, s))
            .collect::<Result<Vec<_>>>()?;
        let pre = if with_pre {
            (want.iter())
                .map(|&s| match self.pre.get(&s) {
                    Some(v) => Ok(v.clone()),
                    None => pick(&self.vals, s),
                })
                .collect::<Result<Vec<_>>>()?
        } else {
            Vec::new()
        };
        Ok((main, pre))
    }
}

/// Milliseconds per op type and per node of one run.
#[derive(Default)]
struct Profile {
    per_op: HashMap<String, f64>,
    per_node: Vec<(f64, usize, String, Option<Vec<usize>>)>,
}

impl Profile {
    fn add(&mut self, op: String, k: usize, shape: Option<Vec<usize>>, ms: f64) {
        *self.per_op.entry(op.clone()).or_default() += ms;
        self.per_node.push((ms, k, op, shape));
    }

    fn print<O: Ops>(mut self, ops: &O) {
        let mut v: Vec<_> = self.per_op.into_iter().collect();
        v.sort_by(|a, b| b.1.total_cmp(&a.1));
        eprintln!(
            "graph profile of {} (ms per op type): {v:.1?}",
            ops.source()
        );
        self.per_node.sort_by(|a, b| b.0.total_cmp(&a.0));
        for (ms, k, op, shape) in self.per_node.iter().take(30) {
            eprintln!("  {ms:7.2} ms  {op:28} {shape:?}  {}", ops.describe(*k));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A toy format: values are numbers; ops add their inputs, "Neg" negates, "Tap" doubles
    /// (and is the identity on the pre-tap pass); counts evaluations.
    struct Toy {
        ops: Vec<&'static str>,
        consts: HashMap<usize, f64>,
        evals: std::cell::Cell<usize>,
    }

    impl Ops for Toy {
        type Value = f64;
        fn eval(&self, k: usize, args: &[Option<&f64>]) -> Result<Vec<f64>> {
            self.evals.set(self.evals.get() + 1);
            let sum: f64 = args.iter().flatten().copied().sum();
            Ok(vec![match self.ops[k] {
                "Neg" => -sum,
                "Tap" => 2.0 * sum,
                _ => sum,
            }])
        }
        fn eval_fused(&self, _k: usize, x: &f64) -> Result<Vec<f64>> {
            Ok(vec![x + 2.0 * x + 1000.0])
        }
        fn constant(&self, slot: usize) -> Option<&f64> {
            self.consts.get(&slot)
        }
        fn describe(&self, k: usize) -> String {
            format!("node {k} (op {})", self.ops[k])
        }
        fn op(&self, k: usize) -> &str {
            self.ops[k]
        }
        fn slot_name(&self, slot: usize) -> String {
            format!("slot {slot}")
        }
        fn source(&self) -> String {
            "toy".into()
        }
        fn settle(&self, _v: &f64) -> Option<Vec<usize>> {
            None
        }
    }

    /// Slots: 0 input, 1 const; node 2 (Add 0+1 → 2), node 0 (Tap 2 → 3), node 1 (Add 3+0 → 4),
    /// listed out of order so the ranks must sort them.
    fn toy() -> (Dataflow, Toy) {
        let inputs = vec![
            vec![Some(2)],
            vec![Some(3), Some(0)],
            vec![Some(0), Some(1)],
        ];
        let outputs = vec![vec![3], vec![4], vec![2]];
        let flow = Dataflow::new(inputs, outputs, 5).unwrap();
        let ops = Toy {
            ops: vec!["Tap", "Add", "Add"],
            consts: [(1, 10.0)].into(),
            evals: 0.into(),
        };
        (flow, ops)
    }

    #[test]
    fn runs_in_topological_order_with_taps_and_injection() {
        let (flow, ops) = toy();
        let run = Run {
            feeds: vec![(0, 1.0)],
            inject: vec![],
            want: &[4],
            taps: &[0],
        };
        // (1 + 10) * 2 + 1 = 23; pre-tap: (1 + 10) + 1 = 12.
        let (main, pre) = flow.run(&ops, run).unwrap();
        assert_eq!((main, pre), (vec![23.0], vec![12.0]));
        // Injecting slot 3 skips nodes 2 and 0: only node 1 runs.
        ops.evals.set(0);
        let run = Run {
            feeds: vec![(0, 1.0)],
            inject: vec![(3, 100.0)],
            want: &[4],
            taps: &[],
        };
        assert_eq!(flow.run(&ops, run).unwrap().0, vec![101.0]);
        assert_eq!(ops.evals.get(), 1);
    }

    #[test]
    fn refuses_a_missing_feed_and_a_cycle() {
        let (flow, ops) = toy();
        let run = Run {
            feeds: vec![],
            inject: vec![],
            want: &[4],
            taps: &[],
        };
        let e = format!("{:#}", flow.run(&ops, run).unwrap_err());
        assert!(e.contains("no value fed for graph input slot 0"), "{e}");
        // Two nodes reading each other.
        let flow = Dataflow::new(
            vec![vec![Some(1)], vec![Some(0)]],
            vec![vec![0], vec![1]],
            2,
        )
        .unwrap();
        let run = Run {
            feeds: vec![],
            inject: vec![],
            want: &[1],
            taps: &[],
        };
        let e = format!("{:#}", flow.run(&ops, run).unwrap_err());
        assert!(e.contains("cycle"), "{e}");
    }

    #[test]
    fn a_fused_pair_runs_as_one_unless_its_inner_value_is_asked_for() {
        // Node 0: Neg(slot 0) → 1; node 1: Add(1, 0) → 2, fused as outer over inner node 0.
        let mut flow = Dataflow::new(
            vec![vec![Some(0)], vec![Some(1), Some(0)]],
            vec![vec![1], vec![2]],
            3,
        )
        .unwrap();
        flow.fuse(1, 0, 0);
        let ops = Toy {
            ops: vec!["Neg", "Add"],
            consts: HashMap::new(),
            evals: 0.into(),
        };
        let run = |want: &'static [usize]| Run {
            feeds: vec![(0, 2.0)],
            inject: vec![],
            want,
            taps: &[],
        };
        assert_eq!(flow.run(&ops, run(&[2])).unwrap().0, vec![1006.0]);
        assert_eq!(ops.evals.get(), 0);
        // Asking for the inner value runs both as written: -2 + 2 = 0.
        assert_eq!(flow.run(&ops, run(&[2, 1])).unwrap().0, vec![0.0, -2.0]);
        assert_eq!(ops.evals.get(), 2);
    }
}
