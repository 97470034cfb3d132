//! The graph rewrites of `detect::tfjs::fuse` change the ops, not the function: CenterNet's graph
//! with and without them gives the same outputs and the same input gradient. Needs the model
//! files (fetched with npm on first use, cached).

use burn::tensor::{Device, Distribution, Tensor};
use cac::detect;
use cac::detect::tfjs::{Graph, GraphModel, Value};

fn max_abs(t: &Tensor<4>) -> f32 {
    t.clone().abs().max().into_scalar::<f32>()
}

#[test]
fn hard_swish_fusion_keeps_outputs_and_gradients() {
    let models = detect::fetch::ensure_models().expect("detector models");
    let json = models.join("centernet.json");
    let dev = Device::autodiff(Device::from(burn::backend::FlexDevice));
    let fused = Graph::new(GraphModel::load(&json).unwrap(), &dev).unwrap();
    let plain = Graph::unfused(GraphModel::load(&json).unwrap(), &dev).unwrap();
    let count = |g: &Graph| g.nodes.iter().filter(|n| n.op() == "HardSwish").count();
    // MobileNetV3-Large's 20 hard-swish activations; the 8 hard-sigmoids of the SE blocks
    // (Relu6(x + 3) * c without the product with x) are not of that form and stay.
    assert_eq!(count(&fused), 20);
    assert_eq!(count(&plain), 0);

    let x = Tensor::<4>::random([1, 512, 512, 3], Distribution::Uniform(0.0, 255.0), &dev);
    let input = fused.inputs()[0].to_string();
    let outputs = ["tower_0/keypoints", "tower_0/wh"];
    let run = |g: &Graph| {
        let x = x.clone().require_grad();
        let out = g.run(&[(input.as_str(), x.clone())], &outputs).unwrap();
        let ts: Vec<Tensor<4>> = out
            .into_iter()
            .map(|v| match v {
                Value::Float(f) => f.t,
                other => panic!("float output expected, got {other:?}"),
            })
            .collect();
        let loss = ts[0].clone().sum() + ts[1].clone().sum().mul_scalar(1e-2);
        let grads = loss.backward();
        let gx = x.grad(&grads).expect("gradient reaches the input");
        (ts.into_iter().map(|t| t.detach()).collect::<Vec<_>>(), gx)
    };
    let (yf, gf) = run(&fused);
    let (yp, gp) = run(&plain);
    for (k, (a, b)) in yf.iter().zip(&yp).enumerate() {
        let rel = max_abs(&(a.clone() - b.clone())) / max_abs(b).max(1e-12);
        assert!(
            rel <= 1e-5,
            "{}: max|fused - plain| / max|plain| = {rel:e}",
            outputs[k]
        );
    }
    let gf = Tensor::<4>::from_data(gf.to_data(), &Device::from(burn::backend::FlexDevice));
    let gp = Tensor::<4>::from_data(gp.to_data(), &Device::from(burn::backend::FlexDevice));
    // Relative L2 difference (3.0e-4 measured): the rounding of the two forms differs by an ulp,
    // and the backward through ~60 layers amplifies it; the max-norm difference is 2.5e-3 of the
    // largest entry. Both forms give the same derivative on scalar inputs (checked by hand).
    let l2 = |t: Tensor<4>| t.powi_scalar(2).sum().into_scalar::<f32>().sqrt();
    let rel = l2(gf - gp.clone()) / l2(gp).max(1e-12);
    eprintln!("input gradient: relative L2 difference {rel:e}");
    assert!(
        rel <= 1e-3,
        "input gradient: relative L2 difference {rel:e}"
    );
}
