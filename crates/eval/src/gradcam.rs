//! Grad-CAM attention maps of a detector's class score (the paper's Figure 7).
//!
//! The class score is the largest pre-sigmoid logit of the class over all of the detector's
//! dense outputs (the most confident candidate of that class). For a layer with activation
//! `A` (`h × w × C`), its gradient `∂score/∂A` is taken by running the graph a second time with
//! `A` re-injected as an autodiff leaf ([`CamGraph::run_cam`](cac_detect::CamGraph::run_cam),
//! TFJS and ONNX graphs alike);
//! channel weights are the spatially averaged gradients `α_k = mean_ij ∂score/∂A_ijk`, the map is
//! `ReLU(Σ_k α_k A_k)`, normalised to [0, 1] and bilinearly upsampled to the image.

use anyhow::{anyhow, bail, Context, Result};
use burn::tensor::{Device, Tensor, TensorData};
use cac_detect::{CamIo, Detector};
use image::RgbImage;

/// A layer that can be explained: a rank-4 feature map with spatial extent.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    pub name: String,
    pub op: String,
    /// Logical NHWC shape.
    pub shape: Vec<usize>,
}

fn io<'a>(det: &'a dyn Detector, image: Tensor<4>) -> Result<CamIo<'a>> {
    det.cam_io(image)?.ok_or_else(|| {
        anyhow!(
            "{} does not expose its graph for attention maps",
            det.name()
        )
    })
}

fn feeds(io: &CamIo, device: &Device) -> Vec<(String, Tensor<4>)> {
    io.feeds
        .iter()
        .map(|(n, t)| (n.clone(), Tensor::from_data(t.to_data(), device)))
        .collect()
}

/// The feature maps of `det`'s graph for `image` (`[1, 3, H, W]`), in graph order.
pub fn layers(det: &dyn Detector, image: Tensor<4>) -> Result<Vec<Layer>> {
    let io = io(det, image)?;
    let g = io.graph;
    // Only the ancestors of the class logits can carry their gradient.
    let outs: Vec<&str> = io.logits.iter().map(|(n, ..)| n.as_str()).collect();
    let found = g.feature_layers(&outs)?;
    let names: Vec<&str> = found.iter().map(|(n, _)| n.as_str()).collect();
    let f = feeds(&io, &g.device());
    let fr: Vec<(&str, Tensor<4>)> = f.iter().map(|(n, t)| (n.as_str(), t.clone())).collect();
    let vals = g.run_cam(&fr, None, &names)?;
    Ok(found
        .into_iter()
        .zip(vals)
        .filter(|(_, (_, s))| g.channel_axis(s).is_some() && s[2] > 1)
        .map(|((name, op), (_, shape))| Layer { name, op, shape })
        .collect())
}

/// A layer's activation for one image: logical shape `[1, h, w, C]` (NHWC) or `[1, C, h, w]`
/// (graphs converted from ONNX hold some maps channels-first), host values.
#[derive(Clone, Debug)]
pub struct Activation {
    pub shape: [usize; 4],
    /// The channel axis: 3 (NHWC) or 1 (NCHW).
    pub channel_axis: usize,
    pub values: Vec<f32>,
}

impl Activation {
    /// `(h, w, C)`.
    pub fn dims(&self) -> (usize, usize, usize) {
        let s = self.shape;
        if self.channel_axis == 1 {
            (s[2], s[3], s[1])
        } else {
            (s[1], s[2], s[3])
        }
    }
    /// Index of channel `k` at grid position `p` (row-major over `h × w`).
    pub fn index(&self, p: usize, k: usize) -> usize {
        let (h, w, c) = self.dims();
        if self.channel_axis == 1 {
            k * h * w + p
        } else {
            p * c + k
        }
    }
}

/// The activation of `layer` for `io`'s inputs.
pub fn activation(io: &CamIo, layer: &str) -> Result<Activation> {
    let f = feeds(io, &io.graph.device());
    let fr: Vec<(&str, Tensor<4>)> = f.iter().map(|(n, t)| (n.as_str(), t.clone())).collect();
    let (t, s) = io.graph.run_cam(&fr, None, &[layer])?.remove(0);
    let Some(channel_axis) = io.graph.channel_axis(&s) else {
        bail!(
            "layer {layer:?} has shape {s:?}: Grad-CAM needs a [1, h, w, C] or [1, C, h, w] \
             feature map with a square grid (see --list-layers)"
        );
    };
    let shape = [s[0], s[1], s[2], s[3]];
    let values = cac_detect::to_vec(&t)?;
    Ok(Activation {
        shape,
        channel_axis,
        values,
    })
}

/// The class score (largest logit of `class`) with `layer`'s output replaced by `act`; with
/// `grad`, also `∂score/∂act` (same layout as `act.values`).
pub fn class_score(
    io: &CamIo,
    layer: &str,
    act: &Activation,
    class: usize,
    grad: bool,
) -> Result<(f32, Option<Vec<f32>>)> {
    let dev = if grad {
        Device::autodiff(io.graph.device())
    } else {
        io.graph.device()
    };
    let mut a = Tensor::<4>::from_data(TensorData::new(act.values.clone(), act.shape), &dev);
    if grad {
        a = a.require_grad();
    }
    let f = feeds(io, &dev);
    let fr: Vec<(&str, Tensor<4>)> = f.iter().map(|(n, t)| (n.as_str(), t.clone())).collect();
    let outs: Vec<&str> = io.logits.iter().map(|(n, ..)| n.as_str()).collect();
    let vals = io
        .graph
        .run_cam(&fr, Some((layer, a.clone(), &act.shape)), &outs)?;
    let mut maxes = vec![];
    for ((t, shape), (name, axis, first)) in vals.into_iter().zip(&io.logits) {
        let dim = 4 - shape.len() + axis;
        if first + class >= shape[*axis] {
            bail!(
                "class id {class} is out of range: {name:?} holds {} classes",
                shape[*axis] - first
            );
        }
        maxes.push(t.narrow(dim, first + class, 1).max());
    }
    let score = Tensor::cat(maxes, 0).max();
    let s = cac_detect::to_vec(&score)?[0];
    if !grad {
        return Ok((s, None));
    }
    let g = score.backward();
    let ga = a.grad(&g).context("no gradient reached the layer")?;
    Ok((s, Some(cac_detect::to_vec(&ga)?)))
}

/// A Grad-CAM map.
#[derive(Clone, Debug)]
pub struct Cam {
    pub layer: String,
    pub class: usize,
    /// The class score (logit) explained.
    pub score: f32,
    /// Grid of the layer `(h, w)` and the map on it, in [0, 1] (row-major).
    pub grid: (usize, usize),
    pub map: Vec<f32>,
}

/// Grad-CAM of `class` for `image` (`[1, 3, H, W]` in [0, 1]) at `layer` (None: the detector's
/// default layer).
pub fn grad_cam(
    det: &dyn Detector,
    image: Tensor<4>,
    class: usize,
    layer: Option<&str>,
) -> Result<Cam> {
    let io = io(det, image)?;
    let layer = layer.unwrap_or(&io.default_layer).to_string();
    let act = activation(&io, &layer)?;
    let (score, g) = class_score(&io, &layer, &act, class, true)?;
    let g = g.expect("gradient requested");
    let (h, w, c) = act.dims();
    let alpha: Vec<f32> = (0..c)
        .map(|k| (0..h * w).map(|p| g[act.index(p, k)]).sum::<f32>() / (h * w) as f32)
        .collect();
    let mut map: Vec<f32> = (0..h * w)
        .map(|p| {
            (0..c)
                .map(|k| alpha[k] * act.values[act.index(p, k)])
                .sum::<f32>()
                .max(0.0)
        })
        .collect();
    let m = map.iter().copied().fold(0.0f32, f32::max);
    if m > 0.0 {
        map.iter_mut().for_each(|v| *v /= m);
    }
    Ok(Cam {
        layer,
        class,
        score,
        grid: (h, w),
        map,
    })
}

impl Cam {
    /// The map bilinearly upsampled to `width × height` (the grid spans the whole image).
    pub fn upsampled(&self, width: u32, height: u32) -> Vec<f32> {
        let (gh, gw) = self.grid;
        let at = |x: isize, y: isize| {
            self.map
                [(y.clamp(0, gh as isize - 1) as usize) * gw + x.clamp(0, gw as isize - 1) as usize]
        };
        let mut out = Vec::with_capacity((width * height) as usize);
        for y in 0..height {
            let fy = (y as f32 + 0.5) * gh as f32 / height as f32 - 0.5;
            let (y0, ty) = (fy.floor(), fy - fy.floor());
            for x in 0..width {
                let fx = (x as f32 + 0.5) * gw as f32 / width as f32 - 0.5;
                let (x0, tx) = (fx.floor(), fx - fx.floor());
                let (x0, y0) = (x0 as isize, y0 as isize);
                let top = at(x0, y0) * (1.0 - tx) + at(x0 + 1, y0) * tx;
                let bot = at(x0, y0 + 1) * (1.0 - tx) + at(x0 + 1, y0 + 1) * tx;
                out.push(top * (1.0 - ty) + bot * ty);
            }
        }
        out
    }

    /// The pixel of the map's maximum at image size `width × height`.
    pub fn peak(&self, width: u32, height: u32) -> (u32, u32) {
        let up = self.upsampled(width, height);
        let i = up
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map_or(0, |(i, _)| i);
        (i as u32 % width, i as u32 / width)
    }

    /// `img` blended with the map in a jet colour ramp (`alpha` = the map's weight at 1).
    pub fn overlay(&self, img: &RgbImage, alpha: f32) -> RgbImage {
        let up = self.upsampled(img.width(), img.height());
        let mut out = img.clone();
        for (p, v) in out.pixels_mut().zip(up) {
            let c = jet(v);
            let a = alpha * v.clamp(0.0, 1.0).sqrt();
            for k in 0..3 {
                p[k] = (p[k] as f32 * (1.0 - a) + c[k] * a)
                    .round()
                    .clamp(0.0, 255.0) as u8;
            }
        }
        out
    }
}

/// The jet colour ramp: 0 blue, 0.5 green-yellow, 1 red.
fn jet(v: f32) -> [f32; 3] {
    let v = v.clamp(0.0, 1.0);
    let f = |c: f32| (1.5 - (4.0 * v - c).abs()).clamp(0.0, 1.0) * 255.0;
    [f(3.0), f(2.0), f(1.0)]
}
