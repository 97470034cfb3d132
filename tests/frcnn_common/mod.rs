//! Shared by the Faster R-CNN tests: the oracle's deterministic weights rebuilt without Python
//! (the formula of tools/torchvision_oracle.py), the oracle files and reference images.
#![allow(dead_code)]

use burn::tensor::{Device, Tensor};
use cac::detect::frcnn::weights::{HostTensor, StateDict};
use cac::detect::frcnn::{Arch, FasterRcnn};
use cac::detect::preprocess;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

pub fn dev() -> Device {
    Device::from(burn::backend::FlexDevice)
}

pub fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/frcnn")
        .join(name)
}

pub fn image(stem: &str) -> Tensor<4> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(format!("../shared/reference/images/{stem}.png"));
    let img = cac::io::load_rgb(&p).expect("reference image (../shared/reference/images)");
    preprocess::image_to_tensor(&img, &dev())
}

// ---- the oracle's deterministic weights, without Python ----

fn fnv1a64(s: &str) -> u64 {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in s.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x100000001b3);
    }
    h
}

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

pub fn oracle_weights(arch: Arch) -> StateDict {
    let layout = FasterRcnn::layout(arch);
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

// ---- oracle files ----

/// A little-endian float32 C-order `.npy`: (shape, values).
pub fn npy(path: &Path) -> (Vec<usize>, Vec<f32>) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&b[..6], b"\x93NUMPY");
    let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
    let header = std::str::from_utf8(&b[10..10 + hl]).unwrap();
    assert!(
        header.contains("'<f4'") && header.contains("'fortran_order': False"),
        "{header}"
    );
    let shape_txt = header
        .split("'shape': (")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap();
    let shape: Vec<usize> = shape_txt
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let values = b[10 + hl..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    (shape, values)
}
