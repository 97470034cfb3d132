//! Shared by the Faster R-CNN tests: the oracle's deterministic weights rebuilt without Python
//! (the formula of tools/torchvision_oracle.py), the oracle files and reference images.
#![allow(dead_code)]

use burn::tensor::{Device, Tensor};
use cac::detect::preprocess;
use std::path::{Path, PathBuf};

/// The build's CPU backend (libtorch's in a `tch` build), as `support::device`.
pub fn dev() -> Device {
    #[cfg(feature = "tch")]
    #[allow(deprecated)] // burn 0.22 marks LibTorch deprecated (docs/detectors.md)
    return Device::from(burn::backend::LibTorchDevice::Cpu);
    #[cfg(not(feature = "tch"))]
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

#[allow(unused_imports)]
pub use cac::detect::frcnn::synthetic::uniform;

/// The oracle's synthetic state_dict of `arch`.
pub fn oracle_weights(arch: cac::detect::frcnn::Arch) -> cac::detect::frcnn::weights::StateDict {
    cac::detect::frcnn::synthetic::state_dict(arch, &dev())
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

/// Writes a state_dict as a `.safetensors` file (float32), each key prefixed with `prefix`, plus
/// `extra` zero-filled tensors (other state a training checkpoint holds beside the model).
pub fn write_safetensors(
    sd: &cac::detect::frcnn::weights::StateDict,
    prefix: &str,
    extra: &[(&str, &[usize])],
    path: &Path,
) {
    let mut bytes: Vec<(String, Vec<u8>, Vec<usize>)> = sd
        .tensors
        .iter()
        .map(|(k, t)| {
            (
                format!("{prefix}{k}"),
                t.values.iter().flat_map(|v| v.to_le_bytes()).collect(),
                t.shape.clone(),
            )
        })
        .collect();
    for (k, shape) in extra {
        let n: usize = shape.iter().product();
        bytes.push((k.to_string(), vec![0u8; 4 * n], shape.to_vec()));
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = bytes
        .iter()
        .map(|(k, b, s)| {
            (
                k.clone(),
                safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b)
                    .unwrap(),
            )
        })
        .collect();
    safetensors::serialize_to_file(views, None, path).unwrap();
}
