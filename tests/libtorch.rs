//! The libtorch fast path (`--features tch`) against the pure-Rust backend (Flex), both in one
//! process on the same seeded inputs: the detectors' candidates and input gradients, the image
//! formation, and the attack's loss over iterations agree within float noise; libtorch's fused
//! activation kernels agree with Flex's at the extremes. The conformance suites
//! (`detect_conformance`, `onnx_conformance`, `frcnn_conformance` with Faster R-CNN, `attack`)
//! also run on libtorch
//! in a `tch` build: `support::device()` is libtorch's CPU there. `.ci/run` runs them so.
#![cfg(feature = "tch")]

mod support;

use burn::tensor::{Device, Tensor, TensorData};
use cac::attack::{AttackConfig, Trainer};
use cac::detect;
use cac::environment::{EnvConfig, Environment};
use cac::render::{RenderSettings, Renderer};
use cac::scene::generate;
use rand::{Rng, SeedableRng};

fn flex() -> Device {
    Device::from(burn::backend::FlexDevice)
}

#[allow(deprecated)] // burn 0.22 marks its LibTorch backend deprecated (docs/detectors.md)
fn torch() -> Device {
    Device::from(burn::backend::LibTorchDevice::Cpu)
}

fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
}

/// A seeded uniform tensor on `dev` (the same values on every backend).
fn seeded(shape: [usize; 4], seed: u64, (lo, hi): (f32, f32), dev: &Device) -> Tensor<4> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = shape.iter().product();
    let v: Vec<f32> = (0..n).map(|_| rng.random_range(lo..hi)).collect();
    Tensor::from_data(TensorData::new(v, shape), dev)
}

/// A seeded leaf of NCHW shape `dims` on `train` (an autodiff device), and the NCHW tensor an op
/// reads: the leaf itself, or with `channels_last` an NHWC leaf seen as NCHW through a
/// permutation (channels-last memory, a view on both backends).
fn leaf(
    dims: [usize; 4],
    seed: u64,
    range: (f32, f32),
    train: &Device,
    channels_last: bool,
) -> (Tensor<4>, Tensor<4>) {
    let [n, c, h, w] = dims;
    match channels_last {
        true => {
            let x = seeded([n, h, w, c], seed, range, train).require_grad();
            (x.clone(), x.permute([0, 3, 1, 2]))
        }
        false => {
            let x = seeded(dims, seed, range, train).require_grad();
            (x.clone(), x)
        }
    }
}

fn max_abs(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// ‖a − b‖ / ‖b‖.
fn rel_l2(a: &[f32], b: &[f32]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let n: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (d / n).sqrt()
}

/// A detector's logits and the gradient of `sum(max_c logits)` to a seeded image, on `dev`;
/// with `jitter`, the image moved by about two ulps (float noise, to size the bounds by).
fn logits_and_gradient(name: &str, dev: &Device, jitter: bool) -> (Vec<f32>, Vec<f32>) {
    let det = detect::load(name, support::models(), dev).unwrap();
    let (w, h) = det.input_size();
    let train = Device::autodiff(dev.clone());
    let mut x = seeded([1, 3, h, w], 11, (0.0, 1.0), &train);
    if jitter {
        x = x.clone() + x * seeded([1, 3, h, w], 12, (-2.4e-7, 2.4e-7), &train);
    }
    let x = x.detach().require_grad();
    let c = det.candidates(x.clone()).unwrap();
    let logits = c.logits.clone();
    let g = c.logits.max_dim(2).sum().backward();
    let grad = x.grad(&g).expect("a gradient reaches the image");
    (host(logits), host(grad))
}

#[test]
fn detectors_on_libtorch_match_flex_forward_and_backward() {
    for name in ["nanodet", "centernet"] {
        let (lf, gf) = logits_and_gradient(name, &flex(), false);
        let (lt, gt) = logits_and_gradient(name, &torch(), false);
        // Flex against itself when the image moves by two ulps: the float noise of the network.
        let (lj, gj) = logits_and_gradient(name, &flex(), true);
        let scale = lf.iter().fold(0f32, |m, v| m.max(v.abs()));
        let (dl, dg) = (max_abs(&lt, &lf), rel_l2(&gt, &gf));
        let (nl, ng) = (max_abs(&lj, &lf), rel_l2(&gj, &gf));
        eprintln!(
            "{name}: logits max |Δ| {dl:.2e} (max |logit| {scale:.1}; Flex's own noise {nl:.2e}), \
             gradient rel L2 {dg:.2e} (Flex's own noise {ng:.2e})"
        );
        assert!(
            lt.iter().chain(&gt).all(|v| v.is_finite()),
            "{name}: non-finite"
        );
        assert!(
            dl <= 1e-4 * scale.max(1.0),
            "{name}: logits differ by {dl:e}"
        );
        let bound = (2e-3f64).max(4.0 * ng);
        assert!(
            dg <= bound,
            "{name}: input gradients differ (rel L2 {dg:e} > {bound:e})"
        );
        assert!(
            gf.iter().any(|v| *v != 0.0),
            "{name}: zero gradient proves nothing"
        );
    }
}

/// The fused kernels' forward and backward on libtorch (ATen's silu/silu_backward,
/// sigmoid_backward, leaky_relu_backward, hardswish/hardswish_backward, threshold_backward,
/// hardtanh_backward) against Flex's, including huge and saturating inputs and the kinks (0, ±3,
/// 6), where both take the same one-sided derivative.
#[test]
fn libtorch_activation_kernels_match_flex_at_the_extremes() {
    let run = |dev: &Device, f: &dyn Fn(Tensor<4>) -> Tensor<4>| {
        let train = Device::autodiff(dev.clone());
        let mut x = seeded([1, 4, 16, 16], 5, (-12.0, 12.0), &train);
        // Saturating and huge values, and exact zeros, in the first plane.
        let extremes = [
            1e30f32, -1e30, 88.0, -88.0, 0.0, -0.0, 1e-30, 40.0, 3.0, -3.0, 6.0,
        ];
        let mut v = host(x.clone());
        v[..extremes.len()].copy_from_slice(&extremes);
        x = Tensor::from_data(TensorData::new(v, [1, 4, 16, 16]), &train).require_grad();
        let y = f(x.clone());
        let g = (y.clone() * seeded([1, 4, 16, 16], 6, (-1.0, 1.0), &train))
            .sum()
            .backward();
        (host(y), host(x.grad(&g).unwrap()))
    };
    type Act = fn(Tensor<4>) -> Tensor<4>;
    let acts: [(&str, Act); 6] = [
        ("sigmoid", detect::activation::sigmoid),
        ("silu", detect::activation::silu),
        ("leaky_relu", |x| detect::activation::leaky_relu(x, 0.1)),
        ("hard_swish", |x| detect::activation::hard_swish(x, 1.7)),
        ("relu", detect::activation::relu),
        ("relu6", detect::activation::relu6),
    ];
    for (name, f) in acts {
        let (yf, gf) = run(&flex(), &f);
        let (yt, gt) = run(&torch(), &f);
        assert!(
            yt.iter().chain(&gt).all(|v| v.is_finite()),
            "{name}: non-finite on libtorch"
        );
        // Relative to each value (SiLU passes 1e30 through).
        let worst = yt
            .iter()
            .zip(&yf)
            .chain(gt.iter().zip(&gf))
            .map(|(a, b)| (a - b).abs() / b.abs().max(1.0))
            .fold(0f32, f32::max);
        eprintln!("{name}: worst relative |Δ| {worst:.2e}");
        assert!(
            worst <= 1e-5,
            "{name}: libtorch and Flex differ by {worst:e}"
        );
    }
}

/// Constant pads on libtorch (ATen's `pad`, which lists the pairs from the last axis backwards)
/// equal Flex's (zeros, a scalar add, a slice assignment), a different pair on every axis, for 0,
/// a value and −∞, on a channels-last input too; the gradient is the output gradient's centre on
/// both.
#[test]
fn libtorch_pads_match_flex_on_every_axis() {
    let run = |dev: &Device, pairs: &[(usize, usize)], value: f32, channels_last: bool| {
        let train = Device::autodiff(dev.clone());
        let (x, xin) = leaf([2, 3, 5, 4], 11, (-1.0, 1.0), &train, channels_last);
        let y = detect::kernels::pad_constant(xin, pairs, value);
        let n: usize = y.dims().iter().product();
        let ramp: Vec<f32> = (0..n).map(|i| (i % 97) as f32 * 0.01).collect();
        let up = Tensor::<4>::from_data(TensorData::new(ramp, y.dims()), &train);
        let finite = y.clone().clamp(-1e6, 1e6);
        let g = x.grad(&(finite * up).sum().backward()).unwrap();
        (y.dims(), host(y), host(g))
    };
    for pairs in [vec![(1, 0), (0, 2), (2, 1), (3, 0)], vec![(0, 1), (2, 0)]] {
        for value in [0.0f32, 2.5, f32::NEG_INFINITY] {
            for cl in [false, true] {
                let (df, yf, gf) = run(&flex(), &pairs, value, cl);
                let (dt, yt, gt) = run(&torch(), &pairs, value, cl);
                assert_eq!(df, dt, "{pairs:?}");
                assert_eq!(yf, yt, "pairs {pairs:?}, value {value}, channels-last {cl}");
                assert!(max_abs(&gf, &gt) <= 1e-6, "gradient, pairs {pairs:?}");
            }
        }
    }
}

/// The detectors' feature up-scalings on libtorch (ATen's bilinear up-sampling, `detect::upscale`)
/// equal Flex's phase path, values and input gradients, for TensorFlow's legacy and half-pixel
/// formulas, 2×, 4× and unequal factors, on NCHW and channels-last inputs.
#[test]
fn libtorch_upscalings_match_flex_for_both_tensorflow_formulas() {
    let run = |dev: &Device, dims: [usize; 4], k: [usize; 2], half: bool, channels_last: bool| {
        let train = Device::autodiff(dev.clone());
        let [n, c, h, w] = dims;
        let (x, xin) = leaf(dims, 5, (-3.0, 3.0), &train, channels_last);
        let (oh, ow) = (h * k[0], w * k[1]);
        let y = detect::preprocess::resize_bilinear(xin, 2, 3, oh, ow, false, half);
        let up = seeded([n, c, oh, ow], 6, (-1.0, 1.0), &train);
        let g = x.grad(&(y.clone() * up).sum().backward()).unwrap();
        (y.dims(), host(y), host(g))
    };
    // The comparison is between two paths: libtorch takes ATen's kernel, Flex the phases.
    let probe = |dev: &Device| seeded([1, 2, 6, 5], 0, (0.0, 1.0), dev);
    assert_eq!(
        detect::upscale::native_factors(&probe(&torch()), 12, 10),
        Some([2, 2])
    );
    assert_eq!(
        detect::upscale::native_factors(&probe(&flex()), 12, 10),
        None
    );
    for (dims, k) in [
        ([1, 8, 6, 5], [2, 2]),
        ([2, 3, 4, 7], [4, 2]),
        ([1, 4, 3, 3], [1, 8]),
    ] {
        for half in [false, true] {
            for cl in [false, true] {
                let what = format!("{dims:?} k {k:?} half-pixel {half} channels-last {cl}");
                let (df, yf, gf) = run(&flex(), dims, k, half, cl);
                let (dt, yt, gt) = run(&torch(), dims, k, half, cl);
                assert_eq!(df, dt, "{what}");
                assert!(max_abs(&yf, &yt) <= 1e-6, "values, {what}");
                assert!(max_abs(&gf, &gt) <= 1e-5, "gradient, {what}");
            }
        }
    }
}

/// Broadcast addition and multiplication on libtorch (one ATen `sum` over the broadcast axes of
/// a gradient, `detect::broadcast`) equal Flex's (burn's reduction), values and both operands'
/// gradients: a bias, a squeeze-and-excitation scale, a row, both operands broadcast, on NCHW
/// and channels-last maps; so does the mean over several axes (one ATen `mean`) and its
/// gradient.
#[test]
fn libtorch_broadcast_gradients_match_flex() {
    let run = |dev: &Device, xs: [usize; 4], ys: [usize; 4], mul: bool, channels_last: bool| {
        let train = Device::autodiff(dev.clone());
        let (x, xin) = leaf(xs, 21, (-2.0, 2.0), &train, channels_last);
        let y = seeded(ys, 22, (-2.0, 2.0), &train).require_grad();
        let z = match mul {
            true => detect::broadcast::mul(xin, y.clone()),
            false => detect::broadcast::add(xin, y.clone()),
        };
        let up = seeded(z.dims(), 23, (-1.0, 1.0), &train);
        let grads = (z.clone() * up).sum().backward();
        let (gx, gy) = (x.grad(&grads).unwrap(), y.grad(&grads).unwrap());
        (host(z), host(gx), host(gy))
    };
    let cases = [
        ([2, 6, 5, 4], [1, 6, 1, 1]),
        ([2, 6, 5, 4], [2, 6, 1, 1]),
        ([1, 6, 5, 4], [1, 1, 1, 4]),
        ([1, 6, 1, 4], [2, 6, 5, 1]),
    ];
    for (xs, ys) in cases {
        for mul in [false, true] {
            for cl in [false, true] {
                let what = format!("{xs:?} {ys:?} mul {mul} channels-last {cl}");
                let (zf, gxf, gyf) = run(&flex(), xs, ys, mul, cl);
                let (zt, gxt, gyt) = run(&torch(), xs, ys, mul, cl);
                assert!(max_abs(&zf, &zt) <= 1e-6, "values, {what}");
                assert!(max_abs(&gxf, &gxt) <= 1e-5, "x gradient, {what}");
                assert!(max_abs(&gyf, &gyt) <= 1e-5, "y gradient, {what}");
            }
        }
    }
    let mean = |dev: &Device, dims: &[usize], channels_last: bool| {
        let train = Device::autodiff(dev.clone());
        let (x, xin) = leaf([2, 5, 6, 7], 24, (-2.0, 2.0), &train, channels_last);
        let z = detect::broadcast::mean_dims(xin, dims);
        let up = seeded(z.dims(), 25, (-1.0, 1.0), &train);
        let g = x.grad(&(z.clone() * up).sum().backward()).unwrap();
        (z.dims(), host(z), host(g))
    };
    for dims in [vec![2, 3], vec![1], vec![0, 2, 3]] {
        for cl in [false, true] {
            let (df, zf, gf) = mean(&flex(), &dims, cl);
            let (dt, zt, gt) = mean(&torch(), &dims, cl);
            assert_eq!(df, dt, "mean over {dims:?}");
            assert!(
                max_abs(&zf, &zt) <= 1e-6,
                "mean over {dims:?}, channels-last {cl}"
            );
            assert!(max_abs(&gf, &gt) <= 1e-6, "gradient, mean over {dims:?}");
        }
    }
}

/// A convolution with TensorFlow's SAME padding at stride 2 (one more row and column after than
/// before, and the reverse) on libtorch equals Flex's, values and input gradient: libtorch's
/// input gradient runs on a zero-stride stand-in of the padded input's shape, not a padded copy.
#[test]
fn libtorch_asymmetrically_padded_convolutions_match_flex() {
    use burn::tensor::ops::ConvOptions;
    let run = |dev: &Device, padding: [(usize, usize); 2], groups: usize, channels_last: bool| {
        let train = Device::autodiff(dev.clone());
        let (x, xin) = leaf([2, 4, 9, 8], 31, (-1.0, 1.0), &train, channels_last);
        let w = seeded([6, 4 / groups, 3, 3], 32, (-0.5, 0.5), &train);
        let options = ConvOptions::new_with_padding([2, 2], padding, [1, 1], groups);
        let y = detect::conv::conv2d(xin, w, None, options);
        let up = seeded(y.dims(), 33, (-1.0, 1.0), &train);
        let g = x.grad(&(y.clone() * up).sum().backward()).unwrap();
        (y.dims(), host(y), host(g))
    };
    for padding in [[(0, 1), (0, 1)], [(1, 0), (0, 1)], [(0, 2), (1, 0)]] {
        for groups in [1, 2] {
            for cl in [false, true] {
                let what = format!("padding {padding:?}, groups {groups}, channels-last {cl}");
                let (df, yf, gf) = run(&flex(), padding, groups, cl);
                let (dt, yt, gt) = run(&torch(), padding, groups, cl);
                assert_eq!(df, dt, "{what}");
                assert!(max_abs(&yf, &yt) <= 1e-5, "values, {what}");
                assert!(max_abs(&gf, &gt) <= 1e-5, "gradient, {what}");
            }
        }
    }
}

fn scene() -> (Renderer, Environment) {
    let mut s = generate::jeep();
    s.normalise(0.0, None);
    let settings = RenderSettings {
        width: 128,
        height: 128,
        samples: 1,
        vfov_deg: 45.0,
        atlas_res: 64,
    };
    let env = EnvConfig {
        distance_ratio: [1.2, 2.0],
        elevation_deg: [0.0, 20.0],
        ..Default::default()
    };
    (
        Renderer::new(s, settings).unwrap(),
        Environment::new(env).unwrap(),
    )
}

/// The attack's loss over iterations (and the image formation of iteration 0) on `dev`.
fn attack_run(dev: &Device) -> (Vec<f64>, Vec<f32>) {
    let (r, env) = scene();
    let init = r.scene.initial_atlas(64);
    let d = detect::load("nanodet", support::models(), dev).unwrap();
    let cfg = AttackConfig {
        models: vec!["nanodet".into()],
        iterations: 3,
        batch: 2,
        top_n: 50,
        lr: 0.05,
        seed: 7,
        checkpoint_every: 0,
        ..Default::default()
    };
    let mut t = Trainer::new(
        cfg,
        &r,
        &env,
        vec![d.as_ref()],
        Device::autodiff(dev.clone()),
        &init,
    )
    .unwrap();
    let a = cac::render::atlas_tensor(&init, dev);
    let (img, _) = cac::environment::form(&r, &env, &t.conditions(0), a).unwrap();
    let losses = (0..3).map(|_| t.step().unwrap().loss).collect();
    (losses, host(img))
}

#[test]
fn the_attack_on_libtorch_follows_the_attack_on_flex() {
    let (lf, imf) = attack_run(&flex());
    let (lt, imt) = attack_run(&torch());
    let di = max_abs(&imt, &imf);
    eprintln!("image formation max |Δ| {di:.2e}; losses flex {lf:?} libtorch {lt:?}");
    assert!(di <= 1e-5, "the rendered batch differs by {di:e}");
    for (i, (a, b)) in lt.iter().zip(&lf).enumerate() {
        assert!(a.is_finite(), "iteration {i}: loss {a}");
        // Adam moves each texel by about lr whatever the gradient's size, so a gradient that
        // differs in the last bits moves a texel the same way: the losses stay close.
        assert!(
            (a - b).abs() <= 1e-3 * b.abs().max(1.0),
            "iteration {i}: {a} vs {b}"
        );
    }
    assert!(lt[2] != lt[0], "the atlas moved, so the loss moved");
}

/// libtorch's CPU computes on the host's cores, so the trainer plans each step's views itself
/// there; a CUDA device (only named here, not opened) does not, so it plans them ahead.
#[test]
#[allow(deprecated)]
fn libtorch_cpu_is_the_hosts_and_cuda_is_not() {
    assert!(detect::computes_on_host(&Device::autodiff(torch())));
    let cuda = Device::autodiff(Device::from(burn::backend::LibTorchDevice::Cuda(0)));
    assert!(!detect::computes_on_host(&cuda));
}
