//! A user's ONNX detector as a [`Detector`]: pre-processing (letterbox or stretch, channel order,
//! mean/std), the graph, and a dense head read from the exported output:
//! - `yolov8`: `[B, 4 + C, N]`, rows `cx, cy, w, h` then C class probabilities (ultralytics
//!   YOLOv8/11 and YOLOv5u exports: anchor-free, DFL decoded inside the graph);
//! - `yolov5`: `[B, N, 5 + C]`, columns `cx, cy, w, h, objectness`, then C class probabilities
//!   (the YOLOv5 repository's and YOLOv3/v7 exports: anchors decoded inside the graph);
//!   a class's score is objectness × class probability, as those repositories rank it;
//! - `split`: boxes `[B, N, 4]` and class scores `[B, N, C]` in two outputs (mmdeploy's dense
//!   export, or any head written that way).
//!
//! The class *logits* the attack needs come from the graph itself: the Sigmoid nodes whose
//! outputs reach the exported scores through layout ops only are tapped
//! ([`super::graph::OnnxGraph::run_tapped`]), so the logits are exact, not `log(p / (1 - p))`
//! of a rounded probability. A small TOML beside the model (`model.toml`, or named as
//! `onnx:MODEL.onnx:CONFIG.toml`) overrides every choice; see [`super::config`].

use super::config::OnnxConfig;
use super::graph::OnnxGraph;
use super::model::{Dim, Io, Model};
use super::runtime;
use super::value::{Dev, Val};
use crate::detector::{check_images, Candidates, Detection, Detector};
use crate::host::to_vec;
use crate::labels::COCO80;
use crate::nms::class_aware_nms;
use crate::preprocess::resize_bilinear;
use crate::raw::{RawDump, RawImage, RawTensor};
use anyhow::{anyhow, bail, ensure, Context, Result};
use burn::tensor::{activation, Device, Tensor, TensorData};
use std::collections::BTreeMap;
use std::path::Path;

/// What runs the graph of a forward pass that needs no gradient.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Engine {
    /// cac's own executor ([`OnnxGraph`]), which also runs every gradient.
    Executor,
    /// onnxruntime ([`runtime`]), where it was enabled when the detector was loaded.
    Runtime,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Head {
    /// `[B, 4 + C, N]`.
    V8,
    /// `[B, N, 5 + C]`.
    V5,
    /// Boxes `[B, N, 4]` and scores `[B, N, C]` in two outputs.
    Split,
}

/// Where the network input sits in the image: `net = img * scale + pad`.
#[derive(Clone, Copy, Debug)]
pub struct Geometry {
    /// Network pixels per image pixel, `[x, y]`.
    pub scale: [f32; 2],
    /// The letterbox border, `[left, top]`, in network pixels.
    pub pad: [f32; 2],
}

/// An ONNX detector.
pub struct OnnxDetector {
    graph: OnnxGraph,
    name: String,
    config: OnnxConfig,
    input: String,
    output: String,
    /// `(width, height)`.
    size: (usize, usize),
    head: Head,
    classes: Vec<&'static str>,
    /// The Sigmoid nodes whose inputs are the class logits.
    taps: Vec<usize>,
    /// The exported graph takes a batch of exactly one.
    batch_one: bool,
    /// The file in onnxruntime, where [`runtime::enable`] was called before loading and the
    /// head's outputs are the file's own (f32 ones).
    runtime: Option<runtime::Session>,
    /// The file, as errors name it.
    file: String,
}

impl OnnxDetector {
    /// Loads `path` with the config `config`, or `path` with the extension `.toml` when that
    /// exists, or the defaults; checks the graph, finds the head with one dry run.
    pub fn load(path: &Path, config: Option<&Path>, device: &Device) -> Result<Self> {
        let src = path.display().to_string();
        let mut config = load_config(path, config)?;
        let model = Model::load(path)?;
        not_a_detector(&model, &src)?;
        let graph = OnnxGraph::new(model, device)?;
        stop_before_selection(&graph, &mut config, &src)?;
        let input_io = image_input(&graph, &config, &src)?;
        let size = input_size(&config, &input_io, &src)?;
        let batch_one = input_io.dims[0] == Dim::Fixed(1);
        let output = match &config.output {
            Some(o) => o.clone(),
            None => graph
                .graph_outputs()
                .first()
                .map(|o| o.name.clone())
                .ok_or_else(|| anyhow!("{src}: the graph has no output"))?,
        };
        // One dry run gives the output's shape (exports often leave it symbolic).
        let zeros = Tensor::<4>::zeros([1, 3, size.1, size.0], device);
        let probe: Vec<&str> = std::iter::once(output.as_str())
            .chain(config.boxes.as_deref())
            .collect();
        let outs = graph.run_images(&input_io.name, zeros, &probe)?;
        let (head, n_classes) = dense_head(&config, &outs, &output, &src)?;
        let classes = class_names(&config, graph.model.meta("names"), n_classes)
            .with_context(|| src.clone())?;
        let taps = logit_taps(&graph, &config, &output, &src)?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "onnx".into());
        let exported = |n: &str| graph.graph_outputs().iter().any(|o| o.name == n);
        let runtime = match runtime::enabled() {
            Some(_) if probe.iter().all(|n| exported(n)) => {
                runtime::Session::open(path, &input_io.name, &probe)?
            }
            _ => None,
        };
        Ok(OnnxDetector {
            graph,
            name,
            config,
            input: input_io.name,
            output,
            size,
            head,
            classes,
            taps,
            batch_one,
            runtime,
            file: src,
        })
    }

    /// What [`Detector::detect`] runs the graph on.
    pub fn engine(&self) -> Engine {
        match self.runtime {
            Some(_) => Engine::Runtime,
            None => Engine::Executor,
        }
    }

    /// [`Detector::detect`] with the graph run by `engine` (cac's executor where onnxruntime
    /// was not enabled): class-aware NMS over the candidates, then the kept boxes clipped to
    /// the image (as ultralytics clips them after its NMS).
    pub fn detect_with(&self, images: Tensor<4>, engine: Engine) -> Result<Vec<Vec<Detection>>> {
        let [_, _, ih, iw] = check_images(&images)?;
        let c = self.scored(images.detach(), engine, false)?;
        let [b, n, k] = c.scores.dims();
        let boxes = to_vec(&c.boxes)?;
        let scores = to_vec(&c.scores)?;
        let cfg = &self.config;
        let mut out = Vec::with_capacity(b);
        for i in 0..b {
            let mut cand: Vec<(usize, f32, [f32; 4])> = Vec::new();
            for j in 0..n {
                let row = &scores[(i * n + j) * k..(i * n + j + 1) * k];
                let bx: [f32; 4] = std::array::from_fn(|q| boxes[(i * n + j) * 4 + q]);
                for (c, &s) in row.iter().enumerate() {
                    if s.is_finite() && s as f64 > cfg.score_threshold {
                        cand.push((c, s, bx));
                    }
                }
            }
            // Class-aware NMS (a box suppresses only its own class, as ultralytics' offsets do).
            let yx: Vec<[f32; 4]> = cand
                .iter()
                .map(|(_, _, b)| [b[1], b[0], b[3], b[2]])
                .collect();
            let sc: Vec<f32> = cand.iter().map(|c| c.1).collect();
            let cls: Vec<usize> = cand.iter().map(|c| c.0).collect();
            let keep = class_aware_nms(
                &yx,
                &sc,
                &cls,
                cfg.max_detections,
                cfg.iou_threshold,
                cfg.score_threshold,
            );
            out.push(
                keep.into_iter()
                    .map(|q| {
                        let (c, score, [x1, y1, x2, y2]) = cand[q];
                        let (w, h) = (iw as f32, ih as f32);
                        Detection {
                            class_id: c,
                            label: self.classes[c],
                            score,
                            bbox: [
                                x1.clamp(0.0, w),
                                y1.clamp(0.0, h),
                                x2.clamp(0.0, w),
                                y2.clamp(0.0, h),
                            ],
                        }
                    })
                    .collect(),
            );
        }
        Ok(out)
    }

    pub fn config(&self) -> &OnnxConfig {
        &self.config
    }
    pub fn graph(&self) -> &OnnxGraph {
        &self.graph
    }
    /// The network input of `images` (`[B, 3, H, W]` in [0, 1]) and where it sits in them.
    pub fn network_input(&self, images: Tensor<4>) -> Result<(Tensor<4>, Geometry)> {
        let [_, _, h, w] = check_images(&images)?;
        let (nw, nh) = self.size;
        let dev = images.device();
        let (x, geo) = if self.config.resize == "stretch" {
            (
                resize_bilinear(images, 2, 3, nh, nw, false, true),
                Geometry {
                    scale: [nw as f32 / w as f32, nh as f32 / h as f32],
                    pad: [0.0, 0.0],
                },
            )
        } else {
            let r = (nw as f32 / w as f32).min(nh as f32 / h as f32);
            let (rw, rh) = (
                ((w as f32 * r).round() as usize).clamp(1, nw),
                ((h as f32 * r).round() as usize).clamp(1, nh),
            );
            let (left, top) = ((nw - rw) / 2, (nh - rh) / 2);
            let x = resize_bilinear(images, 2, 3, rh, rw, false, true);
            let x = crate::kernels::pad_constant(
                x,
                &[(top, nh - rh - top), (left, nw - rw - left)],
                self.config.pad_value,
            );
            (
                x,
                Geometry {
                    scale: [rw as f32 / w as f32, rh as f32 / h as f32],
                    pad: [left as f32, top as f32],
                },
            )
        };
        let x = if self.config.channels == "bgr" {
            x.flip([1])
        } else {
            x
        };
        let x = if self.config.mean != [0.0; 3] || self.config.std != [1.0; 3] {
            let c = |v: [f32; 3]| {
                Tensor::<4>::from_data(TensorData::new(v.to_vec(), [1, 3, 1, 1]), &dev)
            };
            (x - c(self.config.mean)) / c(self.config.std)
        } else {
            x
        };
        Ok((x, geo))
    }

    /// The dense output `[B, N, K]` (rows per candidate) and its pre-sigmoid version, from the
    /// `engine` (onnxruntime gives no pre-sigmoid values: the probabilities twice).
    fn dense(&self, x: Tensor<4>, engine: Engine) -> Result<(Tensor<3>, Tensor<3>)> {
        let b = x.dims()[0];
        let chunks: Vec<Tensor<4>> = if self.batch_one && b > 1 {
            (0..b).map(|i| x.clone().narrow(0, i, 1)).collect()
        } else {
            vec![x]
        };
        let mut probs = Vec::new();
        let mut pre = Vec::new();
        for c in chunks {
            let (p, l) = match (&self.runtime, engine) {
                (Some(rt), Engine::Runtime) => {
                    let p = self.dense_runtime(rt, c)?;
                    (p.clone(), p)
                }
                _ => self.dense_executor(c)?,
            };
            probs.push(p);
            pre.push(l);
        }
        Ok((Tensor::cat(probs, 0), Tensor::cat(pre, 0)))
    }

    /// The shape of the dense output `name`, which must be `[B, A, N]` (or `[B, N, K]`).
    fn dense_dims(&self, name: &str, shape: &[usize]) -> Result<[usize; 3]> {
        match shape[..] {
            [a, b, c] => Ok([a, b, c]),
            _ => bail!(
                "{}: output {name:?} has shape {shape:?}; a dense [B, A, N] output is expected",
                self.file
            ),
        }
    }

    /// A dense output as rows per candidate `[B, N, K]`.
    fn rows(&self, t: Tensor<3>) -> Tensor<3> {
        match self.head {
            Head::V8 => t.swap_dims(1, 2),
            _ => t,
        }
    }

    /// Split: the boxes joined in front of the scores, as the yolov8 head has them.
    fn joined(&self, scores: Tensor<3>, boxes: Option<Tensor<3>>) -> Result<Tensor<3>> {
        Ok(match (self.head, boxes) {
            (Head::Split, Some(b)) => Tensor::cat(vec![b, scores], 2),
            (Head::Split, None) => bail!("{}: the split head has no boxes output", self.file),
            _ => scores,
        })
    }

    /// [`Self::dense`] of one chunk on cac's executor, with the tapped pre-sigmoid values.
    fn dense_executor(&self, c: Tensor<4>) -> Result<(Tensor<3>, Tensor<3>)> {
        let feed = [(self.input.as_str(), Val::D(Dev::from(c)?))];
        let names: Vec<&str> = std::iter::once(self.output.as_str())
            .chain(self.config.boxes.as_deref())
            .collect();
        let (main, alt) = self.graph.run_tapped(&feed, &names, &self.taps)?;
        let as3 = |name: &str, v: &Val| -> Result<Tensor<3>> {
            let d = v.dev(&self.graph.device)?;
            let dims = self.dense_dims(name, &d.shape)?;
            Ok(self.rows(d.t.clone().reshape(dims)))
        };
        let boxes = match (self.head, &self.config.boxes) {
            (Head::Split, Some(name)) => Some(as3(name, &main[1])?),
            _ => None,
        };
        let p = self.joined(as3(&self.output, &main[0])?, boxes.clone())?;
        let l = match alt.first() {
            Some(a) => self.joined(as3(&self.output, a)?, boxes)?,
            None => p.clone(),
        };
        Ok((p, l))
    }

    /// [`Self::dense`]'s probabilities of one chunk, run by onnxruntime.
    fn dense_runtime(&self, rt: &runtime::Session, c: Tensor<4>) -> Result<Tensor<3>> {
        let dev = c.device();
        let shape = c.dims();
        let outs = rt.run(crate::host::to_vec(&c)?, &shape)?;
        let names = std::iter::once(&self.output).chain(&self.config.boxes);
        let mut t = Vec::with_capacity(outs.len());
        for (name, (s, v)) in names.zip(outs) {
            let dims = self.dense_dims(name, &s)?;
            t.push(self.rows(Tensor::from_data(TensorData::new(v, dims), &dev)));
        }
        let mut t = t.into_iter();
        let scores = t
            .next()
            .with_context(|| format!("{}: onnxruntime returned no output", self.file))?;
        self.joined(scores, t.next())
    }

    /// [`Detector::candidates`] with the graph run by `engine` (cac's executor where onnxruntime
    /// was not enabled; onnxruntime's candidates carry no gradient, and their logits are those
    /// of the probabilities it outputs).
    pub fn candidates_with(&self, images: Tensor<4>, engine: Engine) -> Result<Candidates> {
        self.scored(images, engine, true)
    }

    /// [`Self::candidates_with`]; without `with_logits` (detection needs none) the logits of
    /// probabilities are not computed (a log and a log1p over every score): the field holds the
    /// scores.
    fn scored(&self, images: Tensor<4>, engine: Engine, with_logits: bool) -> Result<Candidates> {
        let (x, geo) = self.network_input(images)?;
        let (p, l) = self.dense(x, engine)?;
        let [b, n, k] = p.dims();
        let col = |t: &Tensor<3>, i: usize| t.clone().narrow(2, i, 1);
        let (c0, c1, c2, c3) = (col(&p, 0), col(&p, 1), col(&p, 2), col(&p, 3));
        let (x1, y1, x2, y2) = if self.config.box_format == "xyxy" {
            (c0, c1, c2, c3)
        } else {
            let (hw, hh) = (c2.div_scalar(2.0), c3.div_scalar(2.0));
            (
                c0.clone() - hw.clone(),
                c1.clone() - hh.clone(),
                c0 + hw,
                c1 + hh,
            )
        };
        let (x1, y1, x2, y2) = if self.config.box_scale == "normalized" {
            let (nw, nh) = (self.size.0 as f32, self.size.1 as f32);
            let (sx, sy) = (
                |v: Tensor<3>| v.mul_scalar(nw),
                |v: Tensor<3>| v.mul_scalar(nh),
            );
            (sx(x1), sy(y1), sx(x2), sy(y2))
        } else {
            (x1, y1, x2, y2)
        };
        let ux = |v: Tensor<3>| v.sub_scalar(geo.pad[0]).div_scalar(geo.scale[0]);
        let uy = |v: Tensor<3>| v.sub_scalar(geo.pad[1]).div_scalar(geo.scale[1]);
        let boxes = Tensor::cat(vec![ux(x1), uy(y1), ux(x2), uy(y2)], 2);
        let skip = if self.head == Head::V5 { 5 } else { 4 };
        let cls_p = p.clone().narrow(2, skip, k - skip);
        let cls_l = l.clone().narrow(2, skip, k - skip);
        // onnxruntime returns the probabilities only: read them as such.
        let remapped =
            self.config.scores == "sigmoid" && engine == Engine::Runtime && self.runtime.is_some();
        let mode = match remapped {
            true => "probabilities",
            false => self.config.scores.as_str(),
        };
        // Log-probabilities of each class's score, for the logits of a product.
        let logit_of_prob = |q: Tensor<3>| match with_logits {
            true => {
                let q = q.clamp(1e-30, 1.0 - 1e-7);
                q.clone().log() - q.neg().log1p()
            }
            false => q,
        };
        let (scores, logits) = match (self.head, mode) {
            (Head::V8 | Head::Split, "logits") => {
                (crate::activation::sigmoid(cls_p.clone()), cls_p)
            }
            (Head::V8 | Head::Split, "probabilities") => (cls_p.clone(), logit_of_prob(cls_p)),
            (Head::V8 | Head::Split, _) => (cls_p, cls_l),
            (Head::V5, _) => {
                let obj_p = col(&p, 4);
                let obj_l = col(&l, 4);
                if mode == "probabilities" {
                    let s = cls_p * obj_p.expand([b, n, k - skip]);
                    // Read from onnxruntime's probabilities in place of the sigmoids' inputs:
                    // capped as the executor caps exp(log σ(o) + log σ(c)).
                    let s = match remapped {
                        true => s.clamp_max(1.0 - 1e-7),
                        false => s,
                    };
                    (s.clone(), logit_of_prob(s))
                } else {
                    // log p = log σ(o) + log σ(c); logit = log p − log(1 − p).
                    let (lo, lc) = if mode == "logits" {
                        (col(&p, 4), cls_p)
                    } else {
                        (obj_l, cls_l)
                    };
                    let logp = activation::log_sigmoid(lc)
                        + activation::log_sigmoid(lo).expand([b, n, k - skip]);
                    let p1 = logp.clone().exp().clamp_max(1.0 - 1e-7);
                    let logits = match with_logits {
                        true => logp - p1.clone().neg().log1p(),
                        false => p1.clone(),
                    };
                    (p1, logits)
                }
            }
        };
        Ok(Candidates {
            boxes,
            scores,
            logits,
        })
    }
}

/// The config named, or the `.toml` beside `path`, or the defaults.
fn load_config(path: &Path, config: Option<&Path>) -> Result<OnnxConfig> {
    let beside = path.with_extension("toml");
    Ok(match config {
        Some(c) => OnnxConfig::load(c)?,
        None if beside.is_file() => OnnxConfig::load(&beside)?,
        None => OnnxConfig::default(),
    })
}

/// A file that selects its boxes inside runs up to the dense head before the selection (named
/// by the config, or found here and written into `config`); the rest of the graph is never run.
fn stop_before_selection(graph: &OnnxGraph, config: &mut OnnxConfig, src: &str) -> Result<()> {
    let named = config.output.is_some() && config.boxes.is_some();
    if !named {
        if let Some(select) = selection_inside(&graph.model) {
            let found = head_before_selection(&graph.model)
                .ok_or_else(|| anyhow!("{src}: {}", refuse_selection(&select)))?;
            found.apply(&graph.model, config, src)?;
        }
    }
    Ok(())
}

/// The image input (named by the config, or the first), checked to be `[B, 3, H, W]`.
fn image_input(graph: &OnnxGraph, config: &OnnxConfig, src: &str) -> Result<Io> {
    let input_io = match &config.input {
        Some(n) => graph
            .graph_inputs()
            .iter()
            .find(|i| &i.name == n)
            .ok_or_else(|| anyhow!("{src}: no graph input named {n:?}"))?,
        None => graph
            .graph_inputs()
            .first()
            .ok_or_else(|| anyhow!("{src}: the graph has no input"))?,
    }
    .clone();
    ensure!(
        input_io.dims.len() == 4
            && matches!(
                input_io.dims[1],
                Dim::Fixed(3) | Dim::Param(_) | Dim::Unknown
            ),
        "{src}: input {:?} has shape {}; an image input [B, 3, H, W] is expected",
        input_io.name,
        input_io.shape_text()
    );
    Ok(input_io)
}

/// The network input's `(width, height)`: the config's, or the graph's fixed one.
fn input_size(config: &OnnxConfig, input_io: &Io, src: &str) -> Result<(usize, usize)> {
    Ok(
        match (config.input_size, &input_io.dims[2], &input_io.dims[3]) {
            (Some([w, h]), ..) => (w, h),
            (None, Dim::Fixed(h), Dim::Fixed(w)) => (*w, *h),
            _ => bail!(
                "{src}: input {:?} has a dynamic size {}; set input_size = [width, height] in the config",
                input_io.name,
                input_io.shape_text()
            ),
        },
    )
}

/// The head layout and its class count, from the config and the dry run's outputs (the scores
/// `output`, then the boxes where the config names them).
fn dense_head(config: &OnnxConfig, outs: &[Val], output: &str, src: &str) -> Result<(Head, usize)> {
    let shape = outs[0].shape().to_vec();
    ensure!(
        shape.len() == 3,
        "{src}: output {output:?} has shape {shape:?}; a dense [B, A, N] output is expected (set output in the config)"
    );
    let head = match config.head.as_str() {
        "yolov8" => Head::V8,
        "yolov5" => Head::V5,
        "split" => Head::Split,
        _ if config.boxes.is_some() => Head::Split,
        _ if shape[1] < shape[2] => Head::V8,
        _ => Head::V5,
    };
    let n_classes = match head {
        Head::Split => {
            let bs = outs[1].shape();
            ensure!(
                bs.len() == 3 && bs[2] == 4 && bs[..2] == shape[..2],
                "{src}: boxes output {:?} has shape {bs:?}, scores {output:?} {shape:?}; [B, N, 4] and [B, N, C] are expected",
                config.boxes.as_deref().unwrap_or_default()
            );
            shape[2]
        }
        _ => {
            let per = if head == Head::V8 { shape[1] } else { shape[2] };
            let skip = if head == Head::V8 { 4 } else { 5 };
            ensure!(
                per > skip,
                "{src}: output {output:?} of shape {shape:?} has no class scores for a {:?} head",
                head
            );
            per - skip
        }
    };
    Ok((head, n_classes))
}

/// The Sigmoid nodes to tap for the class logits where the scores are sigmoids (none else).
fn logit_taps(
    graph: &OnnxGraph,
    config: &OnnxConfig,
    output: &str,
    src: &str,
) -> Result<Vec<usize>> {
    Ok(if config.scores == "sigmoid" {
        let t = sigmoid_taps(graph, output);
        ensure!(
            !t.is_empty(),
            "{src}: no Sigmoid node feeds {output:?} through layout ops; set scores = \"probabilities\" or \"logits\" in the config"
        );
        t
    } else {
        Vec::new()
    })
}

/// Refuses an ultralytics model of another task (its `task` metadata): a segmentation, pose,
/// oriented-box or classification output read as class scores would be a wrong answer in
/// silence (a pose model's 51 keypoint values read as 51 "classes").
fn not_a_detector(model: &Model, src: &str) -> Result<()> {
    let Some(task) = model.meta("task").map(str::trim) else {
        return Ok(());
    };
    let (what, suffix) = match task {
        "detect" => return Ok(()),
        "segment" => ("32 mask coefficients per box", "-seg"),
        "pose" => ("keypoints", "-pose"),
        "obb" => ("rotation angles", "-obb"),
        "classify" => ("no boxes at all", "-cls"),
        _ => ("outputs of an unknown kind", ""),
    };
    bail!(
        "{src}: an ultralytics {task:?} model (its metadata says task = {task}), not a detection model: \
         its output holds {what} beside the class scores, which cac would misread. cac attacks \
         detectors: export the detection variant of the model (task = detect, e.g. yolo11n.pt \
         rather than yolo11n{suffix}.pt)"
    )
}

/// The first node that selects boxes inside the file, when the file also gathers the kept rows:
/// NMS or top-k, then GatherElements or NonZero (`nms=True` exports, the end-to-end heads of
/// YOLOv10 / YOLO26, RT-DETR). Its output is a short list of chosen boxes, not the dense
/// candidates the attack and the overlap rule work on; read as a dense head it would be
/// misread in silence.
fn selection_inside(model: &Model) -> Option<String> {
    let first = |ops: &[&str]| {
        model
            .nodes
            .iter()
            .find(|n| ops.contains(&n.op.as_str()))
            .map(|n| format!("{} (node {:?})", n.op, n.name))
    };
    let select = first(&["NonMaxSuppression", "TopK"])?;
    let gather = first(&["GatherElements", "NonZero"])?;
    Some(format!("{select}, then {gather}"))
}

/// Why a file that selects inside, with no dense head cac can find before the selection, is
/// refused, and what to do.
fn refuse_selection(select: &str) -> String {
    format!(
        "the file selects boxes inside ({select}) and cac finds no dense head before the \
         selection: an `nms=True` export, or a selection cac does not know. cac needs the dense \
         head, every candidate box with its class scores, because the attack and the overlap \
         rule work on the candidates before any selection. Export the dense head instead: \
         ultralytics `model.export(format=\"onnx\")` with `nms` left at its default (or name \
         the dense values in a config: `output = \"SCORES\"`, `boxes = \"BOXES\"`, with \
         `box_format` and `box_scale`)"
    )
}

/// The dense head a top-k selection reads, found in the graph: the values an end-to-end
/// export (ultralytics' top-k post-processing of YOLOv10 / YOLO26 with `nms=False`, and of
/// RT-DETR) selects its rows from.
struct InsideHead {
    /// Class scores `[B, N, C]` (probabilities).
    scores: String,
    /// Boxes `[B, N, 4]`.
    boxes: String,
}

/// Finds [`InsideHead`] from the graph output back: the output concatenates the gathered
/// boxes (GatherElements of the dense boxes), the top-k scores (TopK of the flattened dense
/// scores, or of their gathered rows) and the class index. `None` for any other shape of
/// selection (NMS exports among them).
fn head_before_selection(model: &Model) -> Option<InsideHead> {
    use super::model::NodeDef;
    use std::collections::HashMap;
    let mut producer: HashMap<&str, &NodeDef> = HashMap::new();
    for n in &model.nodes {
        for o in &n.outputs {
            producer.insert(o.as_str(), n);
        }
    }
    // Follows the data input (0) back through the ops in `through`.
    fn follow<'a>(
        producer: &HashMap<&'a str, &'a NodeDef>,
        mut v: &'a str,
        through: &[&str],
    ) -> Option<&'a str> {
        while let Some(n) = producer.get(v).filter(|n| through.contains(&n.op.as_str())) {
            v = n.inputs.first()?.as_str();
        }
        Some(v)
    }
    let back = |v, through| follow(&producer, v, through);
    const LAYOUT: &[&str] = &[
        "Reshape",
        "Squeeze",
        "Unsqueeze",
        "Identity",
        "Cast",
        "Flatten",
    ];
    let out = back(&model.outputs.first()?.name, LAYOUT)?;
    let cat = producer
        .get(out)
        .filter(|n| n.op == "Concat" && n.inputs.len() >= 3)?;
    let gather = producer.get(back(&cat.inputs[0], LAYOUT)?)?;
    (gather.op == "GatherElements").then_some(())?;
    let boxes = gather.inputs.first()?.clone();
    let topk_out = back(&cat.inputs[1], LAYOUT)?;
    let topk = producer.get(topk_out).filter(|n| n.op == "TopK")?;
    (topk.outputs.first()? == topk_out).then_some(())?;
    let mut scores = back(topk.inputs.first()?, LAYOUT)?;
    if let Some(g) = producer.get(scores).filter(|n| n.op == "GatherElements") {
        scores = back(g.inputs.first()?, LAYOUT)?;
    }
    // The dense values must not come out of a selection themselves.
    let selected = |v: &str| {
        producer.get(v).is_some_and(|n| {
            ["TopK", "GatherElements", "NonMaxSuppression", "NonZero"].contains(&n.op.as_str())
        })
    };
    (!selected(scores) && !selected(&boxes)).then_some(())?;
    Some(InsideHead {
        scores: scores.to_string(),
        boxes,
    })
}

impl InsideHead {
    /// Reads the found head as a `split` head with its exporter's conventions, where the config
    /// does not set them: RT-DETR (ultralytics' `head` metadata `RTDETRDecoder`) writes
    /// `cx, cy, w, h` as fractions of a stretched input; the end-to-end YOLO heads (`end2end`
    /// metadata) `x1, y1, x2, y2` in pixels of a letterboxed input. The rows are one-to-one
    /// predictions (a query or an anchor of the one-to-one head), which their exporter does not
    /// put through NMS: neither does cac (IoU threshold 1) unless the config asks.
    fn apply(self, model: &Model, config: &mut OnnxConfig, src: &str) -> Result<()> {
        let rtdetr = model.meta("head").map(str::trim) == Some("RTDETRDecoder");
        let end2end = model
            .meta("end2end")
            .is_some_and(|v| v.trim().eq_ignore_ascii_case("true"));
        let conventions = if rtdetr {
            [
                ("resize", "stretch"),
                ("box_format", "cxcywh"),
                ("box_scale", "normalized"),
            ]
        } else if end2end {
            [
                ("resize", "letterbox"),
                ("box_format", "xyxy"),
                ("box_scale", "pixels"),
            ]
        } else {
            ensure!(
                ["box_format", "box_scale", "resize"]
                    .iter()
                    .all(|k| config.given(k)),
                "{src}: the file selects boxes inside with top-k; cac found the dense head \
                 before it (scores {:?}, boxes {:?}) but the file does not say how its boxes are \
                 written (no ultralytics `head` / `end2end` metadata): set box_format, box_scale \
                 and resize in a config",
                self.scores,
                self.boxes
            );
            return self.name_in(config);
        };
        for (key, value) in conventions {
            if !config.given(key) {
                match key {
                    "resize" => config.resize = value.into(),
                    "box_format" => config.box_format = value.into(),
                    _ => config.box_scale = value.into(),
                }
            }
        }
        if !config.given("iou_threshold") {
            config.iou_threshold = 1.0;
        }
        self.name_in(config)
    }

    fn name_in(self, config: &mut OnnxConfig) -> Result<()> {
        config.output = Some(self.scores);
        config.boxes = Some(self.boxes);
        if config.head == "auto" {
            config.head = "split".into();
        }
        Ok(())
    }
}

/// Class names: the config's list, ultralytics' `names` metadata, COCO-80, or numbered.
fn class_names(config: &OnnxConfig, meta: Option<&str>, n: usize) -> Result<Vec<&'static str>> {
    let leak = |v: Vec<String>| -> Vec<&'static str> {
        v.into_iter()
            .map(|s| &*Box::leak(s.into_boxed_str()))
            .collect()
    };
    if let Some(c) = &config.classes {
        ensure!(
            c.len() == n,
            "the config names {} classes, the output has {n}",
            c.len()
        );
        return Ok(leak(c.clone()));
    }
    // A `names` list of another length than the class scores: the output is not what it seems.
    if let Some(names) = meta.and_then(parse_names) {
        ensure!(
            names.len() == n,
            "the file's `names` metadata lists {} classes but the output has {n} class scores: \
             the head is not the plain detection head cac reads (name the output and its classes \
             in a config, `output = \"...\"` and `classes = [...]`, if it is)",
            names.len()
        );
    }
    // A model built without a dataset carries its indices as names ("0", "1", ...): no names.
    let numbered = |v: &Vec<String>| v.iter().enumerate().all(|(k, s)| *s == k.to_string());
    if let Some(names) = meta
        .and_then(parse_names)
        .filter(|v| v.len() == n && !numbered(v))
    {
        if n == 80 && names.iter().zip(COCO80).all(|(a, b)| a == b) {
            return Ok(COCO80.to_vec());
        }
        return Ok(leak(names));
    }
    if n == 80 {
        return Ok(COCO80.to_vec());
    }
    Ok(leak((0..n).map(|k| format!("class{k}")).collect()))
}

/// ultralytics' `names` metadata: a Python dict literal `{0: 'person', 1: 'bicycle', ...}`.
fn parse_names(s: &str) -> Option<Vec<String>> {
    let body = s.trim().strip_prefix('{')?.strip_suffix('}')?;
    let mut out = Vec::new();
    let mut rest = body;
    while let Some(colon) = rest.find(':') {
        let key: usize = rest[..colon]
            .trim()
            .trim_start_matches(',')
            .trim()
            .parse()
            .ok()?;
        let after = rest[colon + 1..].trim_start();
        let q = after.chars().next()?;
        if q != '\'' && q != '"' {
            return None;
        }
        let end = after[1..].find(q)? + 1;
        if key != out.len() {
            return None;
        }
        out.push(after[1..end].to_string());
        rest = &after[end + 1..];
    }
    Some(out)
}

/// The Sigmoid nodes whose outputs reach value `output` through layout ops only.
fn sigmoid_taps(g: &OnnxGraph, output: &str) -> Vec<usize> {
    const LAYOUT: &[&str] = &[
        "Concat",
        "Reshape",
        "Transpose",
        "Slice",
        "Split",
        "Identity",
        "Flatten",
        "Squeeze",
        "Unsqueeze",
        // Float casts (an fp16 export's closing Cast to f32): cac computes them in f32 anyway.
        "Cast",
        "CastLike",
    ];
    let mut taps = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut stack: Vec<usize> = g.producer_of(output).into_iter().collect();
    while let Some(k) = stack.pop() {
        if !seen.insert(k) {
            continue;
        }
        let op = g.node(k).op.as_str();
        if op == "Sigmoid" {
            taps.push(k);
        } else if LAYOUT.contains(&op) {
            // Only the data input (0) of ops whose other inputs are shapes or indices.
            let producers = g.input_producers(k);
            let data: Vec<Option<usize>> = if op == "Concat" {
                producers
            } else {
                producers.into_iter().take(1).collect()
            };
            stack.extend(data.into_iter().flatten());
        }
    }
    taps.sort_unstable();
    taps
}

impl Detector for OnnxDetector {
    fn name(&self) -> &str {
        &self.name
    }
    fn classes(&self) -> &[&'static str] {
        &self.classes
    }
    /// The class logits are the tapped sigmoids' inputs (rank <= 4, one axis of the class
    /// count). The default layer: after the neck's last upsampling (where there is one), the
    /// last concatenation on the finest grid (in YOLO necks it feeds every level's head), else
    /// the last feature map of at least 8 × 8.
    fn cam_io(&self, images: Tensor<4>) -> Result<Option<crate::detector::CamIo<'_>>> {
        use crate::detector::CamGraph;
        let (x, _) = self.network_input(images)?;
        let n = self.classes.len();
        let mut logits = Vec::new();
        for &k in &self.taps {
            let Some(name) = self.graph.node(k).inputs.first() else {
                continue;
            };
            let s = self
                .graph
                .run_cam(&[(&self.input, x.clone())], None, &[name])?
                .remove(0)
                .1;
            // A YOLOv5-repository head sigmoids box, objectness and classes at once
            // ([.., 5 + C] last): its classes start at 5.
            if self.head == Head::V5 && s.last() == Some(&(n + 5)) {
                logits.push((name.clone(), s.len() - 1, 5));
            } else if let Some(axis) = s.iter().rposition(|&d| d == n) {
                logits.push((name.clone(), axis, 0));
            }
        }
        if logits.is_empty() {
            bail!(
                "{}: Grad-CAM needs the class logits, and {}",
                self.graph.source(),
                if self.taps.is_empty() {
                    format!(
                        "this model's scores are {:?} with no Sigmoid node cac taps (a softmax head, \
                         such as SSDlite's, has none)",
                        self.config.scores
                    )
                } else {
                    format!(
                        "none of its {} tapped Sigmoid inputs has an axis of its {n} classes",
                        self.taps.len()
                    )
                }
            );
        }
        let outs: Vec<&str> = logits.iter().map(|(n, ..)| n.as_str()).collect();
        let layers = self.graph.feature_layers(&outs)?;
        let names: Vec<&str> = layers.iter().map(|(n, _)| n.as_str()).collect();
        let shapes = self
            .graph
            .run_cam(&[(&self.input, x.clone())], None, &names)?;
        let last_upsample = (0..self.graph.model.nodes.len())
            .filter(|&k| matches!(self.graph.node(k).op.as_str(), "Resize" | "Upsample"))
            .max();
        let maps: Vec<(&str, &str, usize)> = layers
            .iter()
            .zip(&shapes)
            .filter(|(_, (_, s))| s.len() == 4 && s[2] >= 8 && s[3] >= 8)
            .filter(|((n, _), _)| self.graph.producer_of(n) > last_upsample)
            .map(|((n, op), (_, s))| (n.as_str(), op.as_str(), s[2] * s[3]))
            .collect();
        let finest = maps.iter().map(|m| m.2).max().unwrap_or(0);
        let default_layer = maps
            .iter()
            .rfind(|m| m.1 == "Concat" && m.2 == finest)
            .or(maps.last())
            .map(|m| m.0.to_string())
            .ok_or_else(|| anyhow!("{}: no feature map for attention maps", self.name))?;
        Ok(Some(crate::detector::CamIo {
            graph: &self.graph,
            feeds: vec![(self.input.clone(), x)],
            logits,
            default_layer,
        }))
    }
    fn input_size(&self) -> (usize, usize) {
        self.size
    }
    fn candidates(&self, images: Tensor<4>) -> Result<Candidates> {
        self.candidates_with(images, Engine::Executor)
    }
    /// [`OnnxDetector::detect_with`] on the detector's [`OnnxDetector::engine`].
    fn detect(&self, images: Tensor<4>) -> Result<Vec<Vec<Detection>>> {
        self.detect_with(images, self.engine())
    }
    fn raw(&self, image: Tensor<4>) -> Result<RawDump> {
        let [b, _, h, w] = check_images(&image)?;
        ensure!(b == 1, "a raw dump is of one image, got a batch of {b}");
        let (x, _) = self.network_input(image.detach())?;
        let names: Vec<String> = self
            .graph
            .graph_outputs()
            .iter()
            .map(|o| o.name.clone())
            .collect();
        let refs: Vec<&str> = names.iter().map(|s| s.as_str()).collect();
        let vals = self.graph.run_images(&self.input, x.clone(), &refs)?;
        let mut outputs = BTreeMap::new();
        for (name, v) in names.iter().zip(vals) {
            let h = v.host()?;
            outputs.insert(
                name.clone(),
                RawTensor::new(Some(name), h.shape().to_vec(), h.floats()),
            );
        }
        let dims = x.dims().to_vec();
        Ok(RawDump {
            model: self.name.clone(),
            backend: "burn".into(),
            norm: format!("{} {}", self.config.resize, self.config.channels),
            image: RawImage {
                path: None,
                width: w,
                height: h,
            },
            input: RawTensor::new(Some(&self.input), dims, to_vec(&x)?),
            outputs,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ultralytics_names_metadata_parses_in_order() {
        let v = parse_names("{0: 'person', 1: \"traffic light\", 2: 'a:b'}").unwrap();
        assert_eq!(v, ["person", "traffic light", "a:b"]);
        assert_eq!(parse_names("{1: 'x'}"), None); // keys must count from 0
        assert_eq!(parse_names("not a dict"), None);
    }
}
