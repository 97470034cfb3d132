//! Deterministic synthetic weights for the Faster R-CNN models: every state_dict entry from a
//! hash of (key, flat index), scaled by the entry's role, exactly as tools/torchvision_oracle.py
//! sets torchvision's parameters (its `value`). The conformance tests and the benchmark use
//! them; no pretrained two-stage weights are needed.
//!
//! `v = 2 · (splitmix64(fnv1a64(key) + (i + 1) · φ64) >> 40) / 2²⁴ − 1` in [−1, 1), then:
//! conv/linear weights `v · sqrt(gain / fan_in)` (gain 6; class scores 24, or 6 for ResNet;
//! RPN objectness 0.6; box deltas 0.006), other biases `0.1 v`, BatchNorm `γ = 1 + 0.2 v`
//! (× 0.25 on ResNet's `bn3`), `β = mean = 0.2 v`, `var = 1.25 + 0.25 v`.

use super::weights::{HostTensor, StateDict};
use super::Arch;
use burn::tensor::Device;
use std::collections::{BTreeMap, BTreeSet};

fn fnv1a64(s: &str) -> u64 {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in s.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x100000001b3);
    }
    h
}

/// `n` deterministic values in [−1, 1) for `name` (exact multiples of 2⁻²³).
pub fn uniform(name: &str, n: usize) -> Vec<f64> {
    let seed = fnv1a64(name);
    (0..n as u64)
        .map(|i| {
            let mut z = seed.wrapping_add((i + 1).wrapping_mul(0x9E3779B97F4A7C15));
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
            z ^= z >> 31;
            (z >> 40) as f64 / (1u64 << 24) as f64 * 2.0 - 1.0
        })
        .collect()
}

fn value(name: &str, shape: &[usize], keys: &BTreeSet<String>) -> Vec<f32> {
    let n: usize = shape.iter().product();
    let (base, last) = name.rsplit_once('.').unwrap();
    let v = uniform(name, n);
    let f: Box<dyn Fn(f64) -> f64> = if keys.contains(&format!("{base}.running_mean")) {
        match last {
            "weight" => {
                let s = if base.ends_with(".bn3") { 0.25 } else { 1.0 };
                Box::new(move |v| (v * 0.2 + 1.0) * s)
            }
            "bias" | "running_mean" => Box::new(|v| v * 0.2),
            _ => Box::new(|v| v * 0.25 + 1.25),
        }
    } else if last == "weight" {
        let fan_in: usize = shape[1..].iter().product();
        let gain = if name.contains("cls_score") {
            if keys.contains("backbone.body.conv1.weight") {
                6.0
            } else {
                6.0 * 4.0
            }
        } else if name.contains("rpn.head.cls_logits") {
            6.0 * 0.1
        } else if name.contains("bbox_pred") {
            6.0 * 0.001
        } else {
            6.0
        };
        let s = (gain / fan_in as f64).sqrt();
        Box::new(move |v| v * s)
    } else {
        Box::new(|v| v * 0.1)
    };
    v.into_iter().map(|x| f(x) as f32).collect()
}

/// The full synthetic state_dict of `arch` (its layout is listed on `dev`).
pub fn state_dict(arch: Arch, dev: &Device) -> StateDict {
    let layout = super::FasterRcnn::layout(arch, dev);
    let keys: BTreeSet<String> = layout.iter().map(|(k, _)| k.clone()).collect();
    let map: BTreeMap<String, HostTensor> = layout
        .iter()
        .map(|(k, s)| {
            (
                k.clone(),
                HostTensor {
                    shape: s.clone(),
                    values: value(k, s, &keys),
                },
            )
        })
        .collect();
    StateDict::from_map("oracle formula", map)
}
