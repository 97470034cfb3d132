//! The detector catalogue: every detector cac knows ([`MODELS`]), the one place a detector is
//! named, checked ([`check_spec`]) and loaded ([`load`], [`load_all`]).

use crate::centernet::CenterNet;
use crate::detector::Detector;
use crate::frcnn::{self, FasterRcnn};
use crate::nanodet::{NanoDet, NanoDetConfig};
use crate::{fetch, onnx};
use anyhow::Result;
use burn::tensor::Device;
use std::path::Path;

/// Where a catalogued detector's weights come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Weights {
    /// The TFJS graph-model files in the models folder (`cac models`; fetched into the cache).
    Folder,
    /// A torchvision state_dict (`.pth` from `torch.save`, or `.safetensors`), named with the
    /// model as `MODEL=FILE`.
    Checkpoint,
    /// A user's ONNX file, named in the spec: `onnx:MODEL.onnx[:CONFIG.toml]`.
    Onnx,
}

/// One entry of the detector catalogue.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelInfo {
    /// The name [`load`] and the command line take.
    pub name: &'static str,
    pub weights: Weights,
    /// For an entry that runs another entry's files with other pre-/post-processing (kept for
    /// parity checks), that entry.
    pub variant_of: Option<&'static str>,
    /// One line for help texts.
    pub about: &'static str,
}

/// The detector catalogue: every detector [`load`] knows, in the order help texts list them.
pub const MODELS: [ModelInfo; 7] = [
    ModelInfo {
        name: "centernet",
        weights: Weights::Folder,
        variant_of: None,
        about: "CenterNet-MobileNetV3 512 (TFJS graph)",
    },
    ModelInfo {
        name: "nanodet",
        weights: Weights::Folder,
        variant_of: None,
        about: "NanoDet-g 416 (TFJS graph)",
    },
    ModelInfo {
        name: "nanodet-human",
        weights: Weights::Folder,
        variant_of: Some("nanodet"),
        about: "NanoDet with @vladmandic/human's pre-/post-processing (parity checks)",
    },
    ModelInfo {
        name: frcnn::MODELS[0],
        weights: Weights::Checkpoint,
        variant_of: None,
        about: "torchvision fasterrcnn_mobilenet_v3_large_320_fpn (needs weights)",
    },
    ModelInfo {
        name: frcnn::MODELS[1],
        weights: Weights::Checkpoint,
        variant_of: None,
        about: "torchvision fasterrcnn_mobilenet_v3_large_fpn (needs weights)",
    },
    ModelInfo {
        name: frcnn::MODELS[2],
        weights: Weights::Checkpoint,
        variant_of: None,
        about: "torchvision fasterrcnn_resnet50_fpn (needs weights)",
    },
    ModelInfo {
        name: "onnx",
        weights: Weights::Onnx,
        variant_of: None,
        about: "your ONNX detector: onnx:MODEL.onnx[:CONFIG.toml] (YOLOv3/v5/v8/11 exports)",
    },
];

/// The catalogue entry of a model name (without any `=FILE`).
pub fn model_info(name: &str) -> Option<&'static ModelInfo> {
    MODELS.iter().find(|m| m.name == name)
}

/// The catalogue's names whose weights come from `w`.
pub fn names(w: Weights) -> impl Iterator<Item = &'static str> {
    MODELS
        .iter()
        .filter(move |m| m.weights == w)
        .map(|m| m.name)
}

/// What [`load`] accepts, as its error text lists it.
pub fn expected() -> String {
    let folder: Vec<&str> = names(Weights::Folder).collect();
    let (last, rest) = folder
        .split_last()
        .expect("the catalogue has folder models");
    format!(
        "{}, {last}, {}=FILE.pth or onnx:MODEL.onnx[:CONFIG.toml]",
        rest.join(", "),
        names(Weights::Checkpoint).collect::<Vec<_>>().join("|")
    )
}

/// Checks a detector spec (`NAME`, or `NAME=FILE` for a checkpoint model) against the
/// catalogue without loading anything; returns its entry.
pub fn check_spec(spec: &str) -> Result<&'static ModelInfo> {
    if spec.starts_with("onnx:") {
        let (model, config) = onnx::parse_spec(spec).ok_or_else(|| {
            anyhow::anyhow!("{spec:?}: write onnx:MODEL.onnx or onnx:MODEL.onnx:CONFIG.toml")
        })?;
        for f in std::iter::once(&model).chain(config.as_ref()) {
            if !f.is_file() {
                anyhow::bail!("{spec:?}: {} is not a file", f.display());
            }
        }
        return Ok(model_info("onnx").expect("the catalogue has onnx"));
    }
    let (name, file) = match spec.split_once('=') {
        Some((n, f)) => (n, Some(f)),
        None => (spec, None),
    };
    let info = model_info(name);
    match (info.map(|m| m.weights), file) {
        (Some(Weights::Checkpoint), Some(_)) | (Some(Weights::Folder), None) => {
            Ok(info.expect("matched"))
        }
        (Some(Weights::Onnx), _) => {
            anyhow::bail!("{spec:?}: name an ONNX detector with its file, onnx:MODEL.onnx")
        }
        (_, Some(_)) => anyhow::bail!(
            "{spec:?}: only Faster R-CNN models take a weights file (MODEL=FILE with MODEL one of {})",
            names(Weights::Checkpoint).collect::<Vec<_>>().join(", ")
        ),
        (Some(Weights::Checkpoint), None) => anyhow::bail!(
            "{spec} needs a torchvision checkpoint: write {spec}=FILE.pth (or FILE.safetensors)"
        ),
        (None, None) => anyhow::bail!("unknown detector {spec:?}: expected {}", expected()),
    }
}

/// The loading spec of catalogue model `info` with an optional weights file: `MODEL=FILE` for
/// a Faster R-CNN (which needs one), the name for a TFJS model (which takes none;
/// `nanodet-human` with `human`).
pub fn spec_with_weights(
    info: &ModelInfo,
    weights: Option<&std::path::Path>,
    human: bool,
) -> Result<String> {
    Ok(match (info.weights, weights) {
        (Weights::Checkpoint, Some(w)) => format!("{}={}", info.name, w.display()),
        (Weights::Checkpoint, None) => {
            anyhow::bail!(
                "--model {} needs --weights FILE (a torchvision state_dict)",
                info.name
            )
        }
        (Weights::Folder, Some(_)) => {
            anyhow::bail!("--weights only applies to the Faster R-CNN models")
        }
        (Weights::Onnx, _) => {
            anyhow::bail!("an ONNX detector is named with its file: onnx:MODEL.onnx[:CONFIG.toml]")
        }
        (Weights::Folder, None) if human => "nanodet-human".to_string(),
        (Weights::Folder, None) => info.name.to_string(),
    })
}

/// Loads a detector by catalogue name ([`MODELS`]) from `dir`, the folder holding the TFJS model
/// files (`nanodet-human` is NanoDet with the upstream library's pre-/post-processing).
///
/// A torchvision Faster R-CNN is named with its checkpoint, `MODEL=FILE` (e.g.
/// `frcnn-mobilenet-v3-320=ckpt.pth`, `.pth` or `.safetensors`); `dir` is not used for it. Its
/// candidates are the RPN's fixed top-n proposals with the box head's class logits, so the attack
/// and the evaluation take it like the one-stage detectors.
///
/// A user's ONNX detector is named with its file, `onnx:MODEL.onnx` (a config beside it,
/// `MODEL.toml`, is read when present) or `onnx:MODEL.onnx:CONFIG.toml` ([`onnx::OnnxConfig`]).
pub fn load(spec: &str, dir: &Path, device: &Device) -> Result<Box<dyn Detector>> {
    let info = check_spec(spec)?;
    if info.weights == Weights::Onnx {
        let (model, config) = onnx::parse_spec(spec).expect("checked");
        return Ok(Box::new(onnx::OnnxDetector::load(
            &model,
            config.as_deref(),
            device,
        )?));
    }
    Ok(match (info.name, spec.split_once('=')) {
        (name, Some((_, weights))) => Box::new(FasterRcnn::load(name, Path::new(weights), device)?),
        ("centernet", None) => Box::new(CenterNet::load(dir, device)?),
        ("nanodet", None) => Box::new(NanoDet::load(dir, device, NanoDetConfig::default())?),
        ("nanodet-human", None) => Box::new(NanoDet::load(dir, device, NanoDetConfig::human())?),
        (name, None) => unreachable!("catalogue entry {name} without a loader"),
    })
}

/// Loaded detectors as the trait objects the trainer and the evaluation take.
pub fn refs(boxes: &[Box<dyn Detector>]) -> Vec<&dyn Detector> {
    boxes.iter().map(|d| d.as_ref()).collect()
}

/// Loads detectors by spec (see [`load`]) on `device`. The TFJS model files come from `dir`, or,
/// when it is `None`, from the cache (fetched once on first use, and only when a spec needs
/// them); the specs are checked first, so a misspelt name fails before anything is fetched.
pub fn load_all<S: AsRef<str>>(
    specs: &[S],
    dir: Option<&Path>,
    device: &Device,
) -> Result<Vec<Box<dyn Detector>>> {
    let mut folder = false;
    for s in specs {
        folder |= check_spec(s.as_ref())?.weights == Weights::Folder;
    }
    let dir = match dir {
        Some(d) => d.to_path_buf(),
        None if folder => fetch::ensure_models()?,
        None => std::path::PathBuf::new(), // checkpoints only: no folder is read
    };
    specs
        .iter()
        .map(|s| load(s.as_ref(), &dir, device))
        .collect()
}
