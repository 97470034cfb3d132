//! Faster R-CNN, layer for layer as torchvision builds it (`fasterrcnn_mobilenet_v3_large_320_fpn`,
//! `fasterrcnn_mobilenet_v3_large_fpn`, `fasterrcnn_resnet50_fpn`), loading torchvision
//! state_dicts (`.pth` from `torch.save`, or `.safetensors`) and matched to torchvision on
//! deterministic weights (tests/frcnn_conformance.rs, oracle tools/torchvision_oracle.py).
//!
//! The attack interface: [`FasterRcnn::proposals`] gives the RPN's post-NMS top-n proposals
//! (host boxes, no gradient), [`FasterRcnn::box_outputs`] the box head's class logits for a fixed
//! proposal set, differentiable with respect to the image. [`Detector::candidates`] packages the
//! two: one candidate per proposal, with COCO-80 one-vs-rest logits of the softmax
//! (`σ(logit_c) = softmax_c`), so the sigmoid-based dense-proposals loss applies unchanged.

pub mod anchors;
pub mod backbone_mobilenet;
pub mod backbone_resnet;
pub mod box_head;
pub mod fpn;
pub mod layers;
pub mod postprocess;
pub mod roi_align;
pub mod rpn;
pub mod synthetic;
pub mod transform;
pub mod weights;

use super::labels::{coco80_to_91, coco91_to_80, COCO80, COCO91};
use super::raw::{RawDump, RawImage, RawTensor};
use crate::detector::{check_images, Candidates, Detection, Detector};
use crate::host::to_vec;
use anyhow::{bail, ensure, Result};
use backbone_mobilenet::MobileNetV3;
use backbone_resnet::ResNet50;
use box_head::BoxHead;
use burn::tensor::{activation, Device, Int, Tensor, TensorData};
use fpn::Fpn;
use postprocess::{BoxPost, RawDetection};
use rpn::{RpnConfig, RpnHead};
use std::path::Path;
use transform::Geometry;
use weights::{Loader, StateDict};

/// The three torchvision models by their cac names.
pub const MODELS: [&str; 3] = [
    "frcnn-mobilenet-v3-320",
    "frcnn-mobilenet-v3",
    "frcnn-resnet50",
];
/// Categories of the box predictor (torchvision's COCO ids, background 0).
pub(crate) const CLASSES: usize = 91;
const ANCHOR_SIZES: [f32; 5] = [32.0, 64.0, 128.0, 256.0, 512.0];
const ASPECT_RATIOS: [f32; 3] = [0.5, 1.0, 2.0];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arch {
    MobileNetV3Large320,
    MobileNetV3Large,
    ResNet50,
}

/// Everything torchvision sets per model at test time.
#[derive(Clone, Copy, Debug)]
pub struct FrcnnConfig {
    pub min_size: usize,
    pub max_size: usize,
    pub rpn: RpnConfig,
    pub post: BoxPost,
    /// RoIAlign samples per bin side (torchvision: 2; <= 0 is the adaptive grid).
    pub sampling_ratio: i64,
}

impl Arch {
    pub fn from_name(name: &str) -> Result<Self> {
        Ok(match name {
            "frcnn-mobilenet-v3-320" => Arch::MobileNetV3Large320,
            "frcnn-mobilenet-v3" => Arch::MobileNetV3Large,
            "frcnn-resnet50" => Arch::ResNet50,
            other => bail!("unknown Faster R-CNN {other:?}: expected one of {MODELS:?}"),
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Arch::MobileNetV3Large320 => MODELS[0],
            Arch::MobileNetV3Large => MODELS[1],
            Arch::ResNet50 => MODELS[2],
        }
    }

    /// torchvision's defaults for the model.
    pub fn config(self) -> FrcnnConfig {
        let mobile = self != Arch::ResNet50;
        let small = self == Arch::MobileNetV3Large320;
        FrcnnConfig {
            min_size: if small { 320 } else { 800 },
            max_size: if small { 640 } else { 1333 },
            rpn: RpnConfig {
                pre_nms_top_n: if small { 150 } else { 1000 },
                post_nms_top_n: if small { 150 } else { 1000 },
                nms_thresh: 0.7,
                score_thresh: if mobile { 0.05 } else { 0.0 },
                min_size: 1e-3,
            },
            post: BoxPost {
                score_thresh: 0.05,
                nms_thresh: 0.5,
                detections_per_img: 100,
            },
            sampling_ratio: 2,
        }
    }
}

enum Backbone {
    Mobile(Box<MobileNetV3>),
    Res(Box<ResNet50>),
}

/// A torchvision Faster R-CNN on burn.
pub struct FasterRcnn {
    arch: Arch,
    pub cfg: FrcnnConfig,
    backbone: Backbone,
    fpn: Fpn,
    rpn: RpnHead,
    head: BoxHead,
    /// Cell anchors per FPN level (pool included).
    cells: Vec<Vec<[f32; 4]>>,
}

/// Everything one image goes through, on the host.
#[derive(Clone, Debug)]
pub struct Output {
    pub geometry: Geometry,
    /// RPN proposals `[x1, y1, x2, y2]` in resized-image pixels (torchvision's `proposals`).
    pub proposals: Vec<[f32; 4]>,
    /// `[N, 91]` box head class logits.
    pub class_logits: Vec<f32>,
    /// `[N, 364]` box head regression.
    pub box_regression: Vec<f32>,
    /// Final detections in input-image pixels (torchvision's output).
    pub detections: Vec<RawDetection>,
}

impl FasterRcnn {
    /// Loads `model` (one of [`MODELS`]) from a torchvision `.pth` or `.safetensors` file.
    pub fn load(model: &str, weights: &Path, device: &Device) -> Result<Self> {
        let arch = Arch::from_name(model)?;
        let sd = StateDict::read(weights)?;
        Self::from_state_dict(arch, &sd, arch.config(), device)
    }

    /// Builds the model from a state_dict; fails naming every missing, unexpected or
    /// mis-shaped key.
    pub fn from_state_dict(
        arch: Arch,
        sd: &StateDict,
        cfg: FrcnnConfig,
        dev: &Device,
    ) -> Result<Self> {
        let mut l = Loader::new(sd, "rpn.head.cls_logits.weight");
        let (backbone, channels): (Backbone, Vec<usize>) = match arch {
            Arch::ResNet50 => (
                Backbone::Res(Box::new(ResNet50::load(&mut l, "backbone.body", dev))),
                ResNet50::CHANNELS.to_vec(),
            ),
            _ => (
                Backbone::Mobile(Box::new(MobileNetV3::load(&mut l, "backbone.body", dev))),
                MobileNetV3::CHANNELS.to_vec(),
            ),
        };
        let fpn = Fpn::load(&mut l, "backbone.fpn", &channels, dev);
        let cells: Vec<Vec<[f32; 4]>> = match arch {
            Arch::ResNet50 => ANCHOR_SIZES
                .iter()
                .map(|&s| anchors::cell_anchors(&[s], &ASPECT_RATIOS))
                .collect(),
            _ => (0..3)
                .map(|_| anchors::cell_anchors(&ANCHOR_SIZES, &ASPECT_RATIOS))
                .collect(),
        };
        let rpn = RpnHead::load(&mut l, "rpn.head", fpn::CHANNELS, cells[0].len(), dev);
        let pooled = fpn::CHANNELS * roi_align::OUTPUT * roi_align::OUTPUT;
        let head = BoxHead::load(&mut l, pooled, CLASSES, dev);
        l.finish(arch.name())?;
        Ok(FasterRcnn {
            arch,
            cfg,
            backbone,
            fpn,
            rpn,
            head,
            cells,
        })
    }

    /// The state_dict layout the model needs: every `(key, shape)`, in build order
    /// (`num_batches_tracked` buffers excluded). The layers are built (with placeholder values)
    /// on `dev` to list their keys.
    pub fn layout(arch: Arch, dev: &Device) -> Vec<(String, Vec<usize>)> {
        let empty = StateDict::from_map("layout", Default::default());
        let mut l = Loader::new(&empty, "rpn.head.cls_logits.weight");
        let channels = match arch {
            Arch::ResNet50 => {
                ResNet50::load(&mut l, "backbone.body", dev);
                ResNet50::CHANNELS.to_vec()
            }
            _ => {
                MobileNetV3::load(&mut l, "backbone.body", dev);
                MobileNetV3::CHANNELS.to_vec()
            }
        };
        Fpn::load(&mut l, "backbone.fpn", &channels, dev);
        let a = if arch == Arch::ResNet50 { 3 } else { 15 };
        RpnHead::load(&mut l, "rpn.head", fpn::CHANNELS, a, dev);
        BoxHead::load(&mut l, fpn::CHANNELS * 49, CLASSES, dev);
        l.requested().to_vec()
    }

    pub fn arch(&self) -> Arch {
        self.arch
    }

    /// The FPN levels (pool last) of `images` `[B, 3, H, W]` in [0, 1], and the batch geometry.
    pub fn features(&self, images: Tensor<4>) -> Result<(Vec<Tensor<4>>, Geometry, Tensor<4>)> {
        check_images(&images)?;
        let (x, g) = transform::prepare(images, self.cfg.min_size, self.cfg.max_size);
        let c = match &self.backbone {
            Backbone::Mobile(m) => m.forward(x.clone()),
            Backbone::Res(r) => r.forward(x.clone()),
        };
        Ok((self.fpn.forward(c), g, x))
    }

    /// The RPN's proposals per image from the FPN levels (host boxes, resized-image pixels).
    pub fn rpn_proposals(&self, features: &[Tensor<4>], g: Geometry) -> Result<Vec<Vec<[f32; 4]>>> {
        let detached: Vec<Tensor<4>> = features.iter().map(|f| f.clone().detach()).collect();
        let levels = self.rpn.forward(&detached)?;
        let b = features[0].dims()[0];
        Ok((0..b)
            .map(|i| rpn::proposals(&levels, &self.cells, i, g.resized, g.padded, self.cfg.rpn))
            .collect())
    }

    /// The proposals after the RPN's NMS (top-n per image), computed without gradient.
    pub fn proposals(&self, images: Tensor<4>) -> Result<Vec<Vec<[f32; 4]>>> {
        let (f, g, _) = self.features(images.detach())?;
        self.rpn_proposals(&f, g)
    }

    /// The box head on fixed `proposals` (per image, resized-image pixels): `(class logits
    /// [N, 91], box regression [N, 364])` over all images' proposals in order; None when there
    /// is no proposal at all. Differentiable with respect to the features.
    pub fn box_outputs(
        &self,
        features: &[Tensor<4>],
        g: Geometry,
        proposals: &[Vec<[f32; 4]>],
    ) -> Option<(Tensor<2>, Tensor<2>)> {
        let boxes: Vec<(usize, [f32; 4])> = proposals
            .iter()
            .enumerate()
            .flat_map(|(i, p)| p.iter().map(move |b| (i, *b)))
            .collect();
        if boxes.is_empty() {
            return None;
        }
        let levels = &features[..features.len() - 1];
        let pooled =
            roi_align::multiscale_roi_align(levels, &boxes, g.resized, self.cfg.sampling_ratio);
        Some(self.head.forward(pooled))
    }

    /// The whole model on the host: proposals, box head outputs, final detections per image.
    pub fn run(&self, images: Tensor<4>) -> Result<Vec<Output>> {
        let (f, g, _) = self.features(images.detach())?;
        let props = self.rpn_proposals(&f, g)?;
        let (logits, regs) = match self.box_outputs(&f, g, &props) {
            Some((l, r)) => (to_vec(&l)?, to_vec(&r)?),
            None => (vec![], vec![]),
        };
        let mut out = Vec::new();
        let mut row = 0;
        for p in props {
            let n = p.len();
            let lg = logits[row * CLASSES..(row + n) * CLASSES].to_vec();
            let rg = regs[row * CLASSES * 4..(row + n) * CLASSES * 4].to_vec();
            row += n;
            let mut det = postprocess::detections(&p, &lg, &rg, CLASSES, g.resized, self.cfg.post);
            for d in &mut det {
                d.bbox = postprocess::resize_box(d.bbox, g.resized, g.original);
            }
            out.push(Output {
                geometry: g,
                proposals: p,
                class_logits: lg,
                box_regression: rg,
                detections: det,
            });
        }
        Ok(out)
    }
}

/// COCO-80 one-vs-rest logits of a softmax over 91 categories: `z_c − logsumexp_{j≠c} z_j`
/// (so `σ(logit_c) = softmax_c`), computed without overflow for any finite logits.
pub fn one_vs_rest_logits(z: Tensor<2>) -> Tensor<2> {
    let [n, k] = z.dims();
    let dev = z.device();
    let map = coco80_to_91();
    let cols: Vec<i64> = map.iter().map(|&c| c as i64).collect();
    let zc = z.clone().select(
        1,
        Tensor::<1, Int>::from_data(TensorData::new(cols, [80]), &dev),
    );
    let mut mask = vec![0f32; 80 * k];
    for (c80, &c91) in map.iter().enumerate() {
        mask[c80 * k + c91] = -1e30;
    }
    let mask = Tensor::<3>::from_data(TensorData::new(mask, [1, 80, k]), &dev);
    let others = z.reshape([n, 1, k]) + mask;
    let m = others.clone().max_dim(2).detach();
    let lse = (others - m.clone()).exp().sum_dim(2).log() + m;
    zc - lse.reshape([n, 80])
}

impl Detector for FasterRcnn {
    fn name(&self) -> &str {
        self.arch.name()
    }

    /// A 4:3 landscape image at the model's `min_size` (the network input size varies).
    fn input_size(&self) -> (usize, usize) {
        (self.cfg.min_size * 4 / 3, self.cfg.min_size)
    }

    /// One candidate per fixed RPN proposal (post-NMS top-n; no gradient through the
    /// selection): its box in input pixels and the box head's class scores, differentiable
    /// with respect to `images`. Images with fewer proposals than the batch's most are padded
    /// with empty boxes whose logits are −30 (constant).
    fn candidates(&self, images: Tensor<4>) -> Result<Candidates> {
        let [b, _, _, _] = check_images(&images)?;
        let dev = images.device();
        let anchor = images.clone().sum().reshape([1, 1]) * 0.0;
        let (f, g, _) = self.features(images)?;
        let props = self.rpn_proposals(&f, g)?;
        let n = props.iter().map(Vec::len).max().unwrap_or(0).max(1);
        let logits = self
            .box_outputs(&f, g, &props)
            .map(|(l, _)| one_vs_rest_logits(l));
        let (sy, sx) = (
            g.original.0 as f32 / g.resized.0 as f32,
            g.original.1 as f32 / g.resized.1 as f32,
        );
        let mut rows = Vec::new();
        let mut boxes = Vec::with_capacity(b * n * 4);
        let mut start = 0;
        for p in &props {
            let k = p.len();
            if k > 0 {
                let l = logits.as_ref().expect("proposals have logits");
                rows.push(l.clone().slice([start..start + k, 0..80]));
            }
            if k < n {
                rows.push(anchor.clone().repeat_dim(0, n - k).repeat_dim(1, 80) - 30.0);
            }
            start += k;
            for i in 0..n {
                let q = p
                    .get(i)
                    .map_or([0.0; 4], |q| [q[0] * sx, q[1] * sy, q[2] * sx, q[3] * sy]);
                boxes.extend(q);
            }
        }
        let logits = Tensor::cat(rows, 0).reshape([b, n, 80]);
        Ok(Candidates {
            boxes: Tensor::from_data(TensorData::new(boxes, [b, n, 4]), &dev),
            scores: activation::sigmoid(logits.clone()),
            logits,
        })
    }

    fn detect(&self, images: Tensor<4>) -> Result<Vec<Vec<Detection>>> {
        Ok(self
            .run(images)?
            .into_iter()
            .map(|o| {
                o.detections
                    .iter()
                    .filter_map(|d| {
                        let c = coco91_to_80(d.label)?;
                        Some(Detection {
                            class_id: c,
                            label: COCO80[c],
                            score: d.score,
                            bbox: d.bbox,
                        })
                    })
                    .collect()
            })
            .collect())
    }

    fn raw(&self, image: Tensor<4>) -> Result<RawDump> {
        let [b, _, h, w] = check_images(&image)?;
        ensure!(b == 1, "a raw dump is of one image, got a batch of {b}");
        let (_, _, x) = self.features(image.clone().detach())?;
        let o = self.run(image)?.remove(0);
        let n = o.proposals.len();
        let mut outputs = std::collections::BTreeMap::new();
        let flat: Vec<f32> = o.proposals.iter().flatten().copied().collect();
        outputs.insert("proposals".into(), RawTensor::new(None, vec![n, 4], flat));
        outputs.insert(
            "class_logits".into(),
            RawTensor::new(None, vec![n, CLASSES], o.class_logits),
        );
        outputs.insert(
            "box_regression".into(),
            RawTensor::new(None, vec![n, CLASSES * 4], o.box_regression),
        );
        let det: Vec<f32> = o
            .detections
            .iter()
            .flat_map(|d| {
                [
                    d.bbox[0],
                    d.bbox[1],
                    d.bbox[2],
                    d.bbox[3],
                    d.score,
                    d.label as f32,
                ]
            })
            .collect();
        outputs.insert(
            "detections".into(),
            RawTensor::new(None, vec![o.detections.len(), 6], det),
        );
        let [_, c, ph, pw] = x.dims();
        Ok(RawDump {
            model: self.arch.name().into(),
            backend: "burn".into(),
            norm: format!("torchvision (labels: {} COCO categories)", COCO91.len()),
            image: RawImage {
                path: None,
                width: w,
                height: h,
            },
            input: RawTensor::new(Some("images"), vec![1, c, ph, pw], to_vec(&x)?),
            outputs,
        })
    }
}
