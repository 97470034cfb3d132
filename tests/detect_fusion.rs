//! The graph rewrite `detect::tfjs::fuse::hard_swish` changes the ops, not the function.
//!
//! Fused, hard-swish is `(x·6c) · clamp(x/6 + 1/2, 0, 1)`; the file's own chain is
//! `(x·c) · clamp(x + 3, 0, 6)`. The two are equal in exact arithmetic but round differently, and
//! both are piecewise smooth with kinks at `x = ±3`, where the derivative jumps by `|3c| ≈ 0.5`.
//! So a value within an ulp or two of a kink can land on different sides in the two forms. What
//! is asserted, from the smallest piece up:
//!
//! 1. **One node, by construction** (no model files): on inputs that include both kinks and
//!    their ulp neighbours, zeros, huge values and seeded random values, forward values agree
//!    within the rounding bound derived below, and so do derivatives, except at points within
//!    [`KINK_ULPS`] ulps of a kink, where they may differ by exactly the jump.
//! 2. **Each of CenterNet's 20 hard-swish nodes, on its real activations**: the same property
//!    node by node, with the node's input taken from a seeded run of the whole network.
//! 3. **The whole network**: outputs within 1e-5 of the largest; the input gradient differs
//!    from the plain graph's no more than the plain graph's own gradient moves when its input
//!    moves by one rounding error. The gradient of a ReLU network is only defined up to such
//!    kink flips; this says the fusion adds nothing beyond them, on any machine.
//!
//! Every random input is seeded; the seed is printed on failure.

use burn::tensor::{Device, Tensor, TensorData};
use cac::detect;
use cac::detect::tfjs::{FloatValue, Graph, GraphModel, Value};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;

const SEED: u64 = 14;
/// Unit roundoff of f32.
const U: f32 = f32::EPSILON / 2.0;
/// How close (in ulps of the kink, 3.0) a value may be to ±3 for the two forms to take
/// different sides: `x/6 + 1/2` carries about two roundings of `|x|/6 ≈ 0.5`, i.e. under one ulp
/// of 3; four leaves margin.
const KINK_ULPS: f32 = 4.0;
/// MobileNetV3's float16 constant nearest 1/6.
const C16: f32 = 0.166_625_98;

fn flex() -> Device {
    Device::from(burn::backend::FlexDevice)
}

fn host(t: &Tensor<4>) -> Vec<f32> {
    t.to_data().convert::<f32>().try_into_vec::<f32>().unwrap()
}

/// A one-node model, the file's chain `Mul(Mul(x, c), Relu6(AddV2(x, 3)))`, with `c` stored
/// as float16 as in the detectors' files.
fn hard_swish_model() -> GraphModel {
    let json = r#"{
      "format": "graph-model",
      "modelTopology": {"node": [
        {"name": "x", "op": "Placeholder"},
        {"name": "c", "op": "Const"},
        {"name": "three", "op": "Const"},
        {"name": "scaled", "op": "Mul", "input": ["x", "c"]},
        {"name": "shifted", "op": "AddV2", "input": ["x", "three"]},
        {"name": "relu6", "op": "Relu6", "input": ["shifted"]},
        {"name": "y", "op": "Mul", "input": ["scaled", "relu6"]}
      ]},
      "weightsManifest": [{"paths": ["w.bin"], "weights": [
        {"name": "c", "shape": [], "dtype": "float32", "quantization": {"dtype": "float16"}},
        {"name": "three", "shape": [], "dtype": "float32"}
      ]}]
    }"#;
    let mut bytes = half::f16::from_f32(C16).to_le_bytes().to_vec();
    bytes.extend(3.0f32.to_le_bytes());
    GraphModel::parse(json, Path::new("hard_swish.json"), |_| Ok(bytes.clone())).unwrap()
}

/// Forward values and the vector-Jacobian product with `upstream` of output `out` of `g`, with
/// `x` fed (or injected) at node `at`.
fn value_and_vjp(
    g: &Graph,
    at: &str,
    inject: bool,
    x: &Tensor<4>,
    upstream: &Tensor<4>,
    out: &str,
    dev: &Device,
) -> (Vec<f32>, Vec<f32>) {
    let xa = Tensor::<4>::from_data(x.to_data(), dev).require_grad();
    let vals = if inject {
        let v = FloatValue::new(xa.clone(), xa.dims().to_vec());
        g.run_injected(&[], &[(at, v)], &[out]).unwrap()
    } else {
        g.run(&[(at, xa.clone())], &[out]).unwrap()
    };
    let Value::Float(y) = vals.into_iter().next().unwrap() else {
        panic!("float output expected");
    };
    let y = y.logical().t;
    let up = Tensor::<4>::from_data(upstream.to_data(), dev);
    let grads = (y.clone() * up).sum().backward();
    let gx = xa.grad(&grads).expect("gradient reaches the node's input");
    (host(&y), host(&gx))
}

/// How two evaluations of hard-swish at `x` compare: the number of points that differ beyond
/// the rounding bounds (all must be within `KINK_ULPS` of a kink, and their derivatives differ
/// by the jump), and how many points lie that close to a kink at all.
#[derive(Debug, Default)]
struct Agreement {
    points: usize,
    near_kink: usize,
    flipped: usize,
}

fn compare(
    x: &[f32],
    up: &[f32],
    (yf, gf): (&[f32], &[f32]),
    (yp, gp): (&[f32], &[f32]),
) -> Agreement {
    let kink_ulp = 2.0 * f32::EPSILON; // one ulp of 3 (in [2, 4)) is 2^-22
    let mut a = Agreement {
        points: x.len(),
        ..Default::default()
    };
    for i in 0..x.len() {
        let (xi, ui) = (x[i], up[i]);
        let near = (xi.abs() - 3.0).abs() <= KINK_ULPS * kink_ulp;
        a.near_kink += near as usize;
        // Forward: plain ≤ 3 roundings of |y|; fused ≤ 2 roundings of |y| plus the error of
        // x/6 + 1/2 (≤ u(|x|/3 + 1) absolute) times |x·6c| where it matters (|x| ≤ 3 + margin).
        let y = yp[i].abs().max(yf[i].abs());
        let xm = xi.abs().min(3.5);
        let fwd_bound = 6.0 * U * y + U * xm * (xm / 3.0 + 1.0) * 1.01 + f32::MIN_POSITIVE;
        let dy = (yf[i] - yp[i]).abs();
        assert!(
            dy <= fwd_bound || near,
            "forward at x = {xi:e}: fused {} vs plain {} (|diff| {dy:e} > bound {fwd_bound:e}; seed {SEED})",
            yf[i],
            yp[i]
        );
        // Backward: g = u·(c·r + x·c·r') — each term a few roundings of its size.
        let size = ui.abs() * (6.0 * C16 + xi.abs() * C16 * 1.01);
        let bwd_bound = 8.0 * U * size + f32::MIN_POSITIVE;
        let dg = (gf[i] - gp[i]).abs();
        if dg > bwd_bound {
            a.flipped += 1;
            let jump = (ui * xi * C16).abs();
            assert!(
                near && (dg - jump).abs() <= 8.0 * U * jump + bwd_bound,
                "derivative at x = {xi:e} (upstream {ui:e}): fused {} vs plain {} differ by {dg:e}, \
                 not within rounding ({bwd_bound:e}) nor a kink flip (jump {jump:e}); seed {SEED}",
                gf[i],
                gp[i]
            );
        }
    }
    a
}

#[test]
fn one_hard_swish_node_matches_the_plain_chain_on_its_kinks() {
    let dev = Device::autodiff(flex());
    let fused = Graph::new(hard_swish_model(), &dev).unwrap();
    let plain = Graph::unfused(hard_swish_model(), &dev).unwrap();
    assert_eq!(
        fused.nodes.iter().filter(|n| n.op() == "HardSwish").count(),
        1
    );
    assert_eq!(
        plain.nodes.iter().filter(|n| n.op() == "HardSwish").count(),
        0
    );

    // Both kinks and 40 ulps either side of each, the flat parts' edges, zero, tiny and huge
    // values, then seeded random values over the interesting range.
    let mut xs = vec![
        0.0f32, -0.0, 1e-30, -1e-30, 6.0, -6.0, 1e4, -1e4, 1e30, -1e30,
    ];
    for k in [-3.0f32, 3.0] {
        let mut up = k;
        let mut down = k;
        xs.push(k);
        for _ in 0..40 {
            up = f32::from_bits(if up > 0.0 {
                up.to_bits() + 1
            } else {
                up.to_bits() - 1
            });
            down = f32::from_bits(if down > 0.0 {
                down.to_bits() - 1
            } else {
                down.to_bits() + 1
            });
            xs.extend([up, down]);
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    xs.extend((0..4000).map(|_| rng.random_range(-8.0f32..8.0)));
    let up: Vec<f32> = (0..xs.len())
        .map(|_| rng.random_range(-2.0f32..2.0))
        .collect();
    let n = xs.len();
    let x = Tensor::<4>::from_data(TensorData::new(xs.clone(), [1, 1, n, 1]), &flex());
    let u = Tensor::<4>::from_data(TensorData::new(up.clone(), [1, 1, n, 1]), &flex());
    let f = value_and_vjp(&fused, "x", false, &x, &u, "y", &dev);
    let p = value_and_vjp(&plain, "x", false, &x, &u, "y", &dev);
    let a = compare(&xs, &up, (&f.0, &f.1), (&p.0, &p.1));
    eprintln!("one node: {a:?}");
    assert!(
        a.near_kink >= 4,
        "the inputs must probe both kinks closely: {a:?}"
    );
    // At the kinks themselves both forms take the same side, TensorFlow's (its ReLU6 passes no
    // gradient at its bounds; ATen's hardswish_backward agrees), so the derivative is c·r there
    // in both: 0 at -3 (r = 0), 6c at 3 (r = 6).
    for (k, want) in [(-3.0f32, 0.0), (3.0, 6.0 * C16)] {
        let i = xs.iter().position(|&v| v == k).unwrap();
        for (name, g) in [("fused", &f.1), ("plain", &p.1)] {
            let got = g[i] / up[i];
            assert!(
                (got - want).abs() <= 1e-5,
                "{name} derivative at {k}: {got} (want {want})"
            );
        }
    }
    // ±1e30 stays finite in both forms (x·c·r with r = 0 or 6 is at most ~1e30).
    assert!(f
        .0
        .iter()
        .chain(&p.0)
        .chain(&f.1)
        .chain(&p.1)
        .all(|v| v.is_finite()));
}

#[test]
fn centernet_hard_swish_nodes_match_node_by_node_and_the_network_agrees() {
    let models = detect::fetch::ensure_models().expect("detector models");
    let json = models.join("centernet.json");
    let dev = Device::autodiff(flex());
    let fused = Graph::new(GraphModel::load(&json).unwrap(), &dev).unwrap();
    let plain = Graph::unfused(GraphModel::load(&json).unwrap(), &dev).unwrap();
    // MobileNetV3-Large's 20 hard-swish activations; the 8 hard-sigmoids of the SE blocks
    // (Relu6(x + 3) * c without the product with x) are not of that form and stay.
    let hs: Vec<(String, String)> = fused
        .nodes
        .iter()
        .filter(|n| n.op() == "HardSwish")
        .map(|n| {
            (
                n.name().to_string(),
                fused.nodes[n.inputs[0].0].name().to_string(),
            )
        })
        .collect();
    assert_eq!(hs.len(), 20);
    assert_eq!(
        plain.nodes.iter().filter(|n| n.op() == "HardSwish").count(),
        0
    );

    let input = fused.inputs()[0].to_string();
    let x = seeded(&[1, 512, 512, 3], 0.0, 255.0, SEED);

    // (2) Node by node, on the activations the plain network computes for x.
    let names: Vec<&str> = hs.iter().map(|(_, i)| i.as_str()).collect();
    let acts = plain.run(&[(input.as_str(), x.clone())], &names).unwrap();
    let mut total = Agreement::default();
    for (k, ((node, at), act)) in hs.iter().zip(acts).enumerate() {
        let Value::Float(a) = act else {
            panic!("{at}: float expected")
        };
        let a = Tensor::<4>::from_data(a.logical().t.to_data(), &flex());
        let xs = host(&a);
        let up = seeded(&a.dims(), -1.0, 1.0, SEED + 1 + k as u64);
        let ups = host(&up);
        let f = value_and_vjp(&fused, at, true, &a, &up, node, &dev);
        let p = value_and_vjp(&plain, at, true, &a, &up, node, &dev);
        let r = compare(&xs, &ups, (&f.0, &f.1), (&p.0, &p.1));
        total.points += r.points;
        total.near_kink += r.near_kink;
        total.flipped += r.flipped;
    }
    eprintln!("20 nodes on CenterNet's activations: {total:?}");
    assert!(total.flipped <= total.near_kink);

    // (3) The whole network.
    let outputs = ["tower_0/keypoints", "tower_0/wh"];
    let run = |g: &Graph, x: &Tensor<4>| {
        let x = Tensor::<4>::from_data(x.to_data(), &dev).require_grad();
        let out = g.run(&[(input.as_str(), x.clone())], &outputs).unwrap();
        let ts: Vec<Tensor<4>> = out
            .into_iter()
            .map(|v| match v {
                Value::Float(f) => f.t,
                other => panic!("float output expected, got {other:?}"),
            })
            .collect();
        let loss = ts[0].clone().sum() + ts[1].clone().sum().mul_scalar(1e-2);
        let gx = x
            .grad(&loss.backward())
            .expect("gradient reaches the input");
        let ys: Vec<Vec<f32>> = ts.iter().map(host).collect();
        (ys, host(&gx))
    };
    let (yf, gf) = run(&fused, &x);
    let (yp, gp) = run(&plain, &x);
    for (k, (a, b)) in yf.iter().zip(&yp).enumerate() {
        let top = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
        let d = a.iter().zip(b).fold(0f32, |m, (p, q)| m.max((p - q).abs()));
        assert!(
            d / top <= 1e-5,
            "{}: max|fused - plain| / max|plain| = {:e} (seed {SEED})",
            outputs[k],
            d / top
        );
    }
    // The plain network's own sensitivity: the same input moved by one rounding error
    // (each value times 1 ± u, signs seeded).
    let mut rng = ChaCha8Rng::seed_from_u64(SEED + 100);
    let xv = host(&x);
    let moved: Vec<f32> = xv
        .iter()
        .map(|&v| {
            if rng.random_bool(0.5) {
                v * (1.0 + 2.0 * U)
            } else {
                v * (1.0 - 2.0 * U)
            }
        })
        .collect();
    let x2 = Tensor::<4>::from_data(TensorData::new(moved, x.dims()), &flex());
    let (_, gp2) = run(&plain, &x2);
    let rel = |a: &[f32], b: &[f32]| {
        let d: f64 = a.iter().zip(b).map(|(p, q)| ((p - q) as f64).powi(2)).sum();
        let n: f64 = b.iter().map(|q| (*q as f64).powi(2)).sum();
        (d / n.max(1e-300)).sqrt()
    };
    let fusion = rel(&gf, &gp);
    let rounding = rel(&gp2, &gp);
    eprintln!(
        "input gradient, relative L2: fused vs plain {fusion:e}; plain vs plain at x(1 ± u) {rounding:e}"
    );
    assert!(
        fusion <= 4.0 * rounding.max(1e-6),
        "the fusion moves the input gradient by {fusion:e} (relative L2), more than 4x what one \
         rounding error of the input does ({rounding:e}); seed {SEED}"
    );
}

/// A seeded uniform tensor on the plain device.
fn seeded(shape: &[usize], lo: f32, hi: f32, seed: u64) -> Tensor<4> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n: usize = shape.iter().product();
    let v: Vec<f32> = (0..n).map(|_| rng.random_range(lo..hi)).collect();
    let s: [usize; 4] = shape.try_into().unwrap();
    Tensor::<4>::from_data(TensorData::new(v, s), &flex())
}
