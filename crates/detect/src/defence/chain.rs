//! The defences, their names and parameters, and a chain of them applied to one image.

use super::{filters, image_hash, jpeg, lgs, tv, Planes};
use crate::{conv, kernels, preprocess};
use anyhow::{bail, Context, Result};
use burn::tensor::ops::{ConvOptions, PadMode};
use burn::tensor::{Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Every accepted defence with its parameter's range and default: the text errors name.
pub const ACCEPTED: &str = "jpeg[:QUALITY 1-100, default 75], blur[:SIGMA px 0.1-10, 1], \
     median[:SIZE odd 3-9, 3], bits[:BITS 1-8, 5], resize-pad[:MIN_SCALE 0.5-1, 0.9], \
     tv[:WEIGHT 0.001-1, 0.03], lgs[:STRENGTH 0.1-10, 2.3], or none; several chained with '+'";

/// One input defence and its parameter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Defence {
    /// JPEG re-compression at this quality (the `image` crate's baseline encoder, 4:2:0).
    Jpeg { quality: u8 },
    /// Gaussian blur of this standard deviation in pixels (edges repeated), per channel.
    Blur { sigma: f32 },
    /// Median filter over a `size`×`size` window (edges repeated), per channel.
    Median { size: usize },
    /// Bit-depth reduction to `bits` per channel (feature squeezing, Xu et al. 2018).
    BitDepth { bits: u8 },
    /// Random resize and pad (Xie et al. 2018): the image shrunk by a scale drawn in
    /// `[min_scale, 1]` and placed at a random offset on a black canvas of its own size.
    ResizePad { min_scale: f32 },
    /// Total-variation minimisation over a random half of the pixels (Guo et al. 2018).
    TotalVariation { weight: f32 },
    /// Local gradient smoothing (Naseer et al. 2019), a training-free patch defence.
    LocalGradientSmoothing { strength: f32 },
}

impl Defence {
    /// Parses `NAME[:PARAM]`; an error names what is wrong and every accepted defence.
    pub fn parse(text: &str) -> Result<Defence> {
        let (name, param) = match text.split_once(':') {
            Some((n, p)) => (n.trim(), Some(p.trim())),
            None => (text.trim(), None),
        };
        let num = |default: f32, lo: f32, hi: f32| -> Result<f32> {
            let Some(p) = param else { return Ok(default) };
            let v: f32 = p
                .parse()
                .with_context(|| format!("defence {text:?}: {p:?} is not a number"))?;
            if !(lo..=hi).contains(&v) {
                bail!("defence {text:?}: {v} is outside {lo}-{hi} (accepted: {ACCEPTED})");
            }
            Ok(v)
        };
        let whole = |v: f32| -> Result<f32> {
            match v.fract() == 0.0 {
                true => Ok(v),
                false => bail!("defence {text:?}: the parameter must be a whole number"),
            }
        };
        Ok(match name {
            "jpeg" => Defence::Jpeg {
                quality: whole(num(75.0, 1.0, 100.0)?)? as u8,
            },
            "blur" => Defence::Blur {
                sigma: num(1.0, 0.1, 10.0)?,
            },
            "median" => {
                let size = whole(num(3.0, 3.0, 9.0)?)? as usize;
                if size % 2 == 0 {
                    bail!("defence {text:?}: the window's size must be odd (3, 5, 7 or 9)");
                }
                Defence::Median { size }
            }
            "bits" => Defence::BitDepth {
                bits: whole(num(5.0, 1.0, 8.0)?)? as u8,
            },
            "resize-pad" => Defence::ResizePad {
                min_scale: num(0.9, 0.5, 1.0)?,
            },
            "tv" => Defence::TotalVariation {
                weight: num(0.03, 0.001, 1.0)?,
            },
            "lgs" => Defence::LocalGradientSmoothing {
                strength: num(2.3, 0.1, 10.0)?,
            },
            _ => bail!("unknown defence {name:?} in {text:?}; accepted: {ACCEPTED}"),
        })
    }

    /// `NAME:PARAM`, as [`Defence::parse`] reads it back.
    pub fn name(&self) -> String {
        match self {
            Defence::Jpeg { quality } => format!("jpeg:{quality}"),
            Defence::Blur { sigma } => format!("blur:{sigma}"),
            Defence::Median { size } => format!("median:{size}"),
            Defence::BitDepth { bits } => format!("bits:{bits}"),
            Defence::ResizePad { min_scale } => format!("resize-pad:{min_scale}"),
            Defence::TotalVariation { weight } => format!("tv:{weight}"),
            Defence::LocalGradientSmoothing { strength } => format!("lgs:{strength}"),
        }
    }

    /// This defence applied to one image (`[1, 3, H, W]`), its random choices drawn from
    /// `seed`; with `grad`, the output passes gradients (exact or straight-through). The
    /// second value is where the image's points moved (resize-and-pad), else the identity.
    fn apply(&self, x: Tensor<4>, seed: u64, grad: bool) -> (Tensor<4>, Affine) {
        let same = Affine::IDENTITY;
        match *self {
            Defence::Blur { sigma } => (blur(x, sigma), same),
            Defence::ResizePad { min_scale } => resize_pad(x, min_scale, seed),
            Defence::Jpeg { quality } => (on_host(x, grad, |p| jpeg::jpeg(p, quality)), same),
            Defence::Median { size } => (on_host(x, grad, |p| filters::median(p, size)), same),
            Defence::BitDepth { bits } => (on_host(x, grad, |p| filters::bit_depth(p, bits)), same),
            Defence::TotalVariation { weight } => {
                let s = tv::TvSettings::guo(weight, seed);
                (on_host(x, grad, |p| tv::tv_minimise(p, &s)), same)
            }
            Defence::LocalGradientSmoothing { strength } => (smooth_gradients(x, strength), same),
        }
    }
}

/// Where a defence moved the image's points: `x' = sx·x + dx`, `y' = sy·y + dy`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Affine {
    pub sx: f32,
    pub sy: f32,
    pub dx: f32,
    pub dy: f32,
}

impl Affine {
    pub const IDENTITY: Affine = Affine {
        sx: 1.0,
        sy: 1.0,
        dx: 0.0,
        dy: 0.0,
    };

    /// `self`, then `next`.
    fn then(self, next: Affine) -> Affine {
        Affine {
            sx: next.sx * self.sx,
            sy: next.sy * self.sy,
            dx: next.sx * self.dx + next.dx,
            dy: next.sy * self.dy + next.dy,
        }
    }

    /// A box `x1, y1, x2, y2` in the defended image, in the input image's pixels.
    pub fn box_back(&self, b: [f32; 4]) -> [f32; 4] {
        [
            (b[0] - self.dx) / self.sx,
            (b[1] - self.dy) / self.sy,
            (b[2] - self.dx) / self.sx,
            (b[3] - self.dy) / self.sy,
        ]
    }

    /// Boxes `[B, N, 4]` in the defended image, in the input image's pixels.
    pub fn boxes_back(&self, boxes: Tensor<3>) -> Tensor<3> {
        if *self == Affine::IDENTITY {
            return boxes;
        }
        let dev = boxes.device();
        let row =
            |v: [f32; 4]| Tensor::<3>::from_data(TensorData::new(v.to_vec(), [1, 1, 4]), &dev);
        let shift = row([self.dx, self.dy, self.dx, self.dy]);
        let scale = row([1.0 / self.sx, 1.0 / self.sy, 1.0 / self.sx, 1.0 / self.sy]);
        (boxes - shift) * scale
    }
}

/// Defences applied in turn; empty is `none`.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Chain(pub Vec<Defence>);

impl Chain {
    /// Parses `none` or `NAME[:PARAM]+NAME[:PARAM]...`.
    pub fn parse(text: &str) -> Result<Chain> {
        if text.trim() == "none" {
            return Ok(Chain(vec![]));
        }
        Ok(Chain(
            text.split('+').map(Defence::parse).collect::<Result<_>>()?,
        ))
    }

    /// `none`, or the defences' names joined by `+`.
    pub fn name(&self) -> String {
        match self.0.is_empty() {
            true => "none".into(),
            false => self
                .0
                .iter()
                .map(Defence::name)
                .collect::<Vec<_>>()
                .join("+"),
        }
    }

    /// The chain applied to one image (`[1, 3, H, W]`) whose hash is `seed`.
    pub fn apply(&self, mut x: Tensor<4>, seed: u64, grad: bool) -> (Tensor<4>, Affine) {
        let mut moved = Affine::IDENTITY;
        for (i, d) in self.0.iter().enumerate() {
            let (y, m) = d.apply(x, mix(seed, i as u64), grad);
            (x, moved) = (y, moved.then(m));
        }
        (x, moved)
    }
}

/// Parses a comma-separated list of chains (`jpeg:75,blur:1+bits:4,none`), each once.
pub fn parse_chains(list: &[String]) -> Result<Vec<Chain>> {
    let mut out: Vec<Chain> = vec![];
    for text in list
        .iter()
        .flat_map(|s| s.split(','))
        .filter(|s| !s.trim().is_empty())
    {
        let c = Chain::parse(text)?;
        if out.contains(&c) {
            bail!("defence {:?} is named twice", c.name());
        }
        out.push(c);
    }
    Ok(out)
}

/// A seed for step `i` of a chain on an image whose hash is `seed` (splitmix64).
pub(crate) fn mix(seed: u64, i: u64) -> u64 {
    let mut z = seed ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// One image's values on the host.
pub(crate) fn host(x: &Tensor<4>) -> Vec<f32> {
    x.clone()
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("an f32 image")
}

/// `f` of one image's host values as a constant tensor of the image's shape (no gradient).
fn host_map(x: &Tensor<4>, f: impl FnOnce(Planes) -> Vec<f32>) -> Tensor<4> {
    let [b, c, h, w] = x.dims();
    assert_eq!((b, c), (1, 3), "a defence takes one RGB image at a time");
    let data = host(x);
    let y = f(Planes {
        data: &data,
        height: h,
        width: w,
    });
    Tensor::<4>::from_data(TensorData::new(y, [b, c, h, w]), &x.device())
}

/// A transform computed on the host; with `grad` its gradient is the identity
/// (`x + (f(x) - x)` with the difference detached: BPDA).
fn on_host(x: Tensor<4>, grad: bool, f: impl FnOnce(Planes) -> Vec<f32>) -> Tensor<4> {
    let y = host_map(&x, f);
    match grad {
        true => x.clone() + (y - x.detach()),
        false => y,
    }
}

/// Local gradient smoothing as `x · M`, the mask `M` computed on the host from `x`: exact in
/// `x` with the mask held fixed (BPDA through the mask only).
fn smooth_gradients(x: Tensor<4>, strength: f32) -> Tensor<4> {
    let mask = host_map(&x, |p| {
        let m = lgs::lgs_mask(p, strength);
        (0..3).flat_map(|_| m.iter().copied()).collect()
    });
    x * mask
}

/// Separable Gaussian blur, edges repeated; a tensor operation (exact gradient).
fn blur(x: Tensor<4>, sigma: f32) -> Tensor<4> {
    let r = (3.0 * sigma).ceil() as usize;
    let c = x.dims()[1];
    let taps: Vec<f32> = (0..=2 * r)
        .map(|i| (-((i as f32 - r as f32).powi(2)) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f32 = taps.iter().sum();
    let taps: Vec<f32> = taps.iter().map(|t| t / sum).collect();
    let dev = x.device();
    let kernel = |shape: [usize; 4]| {
        let v: Vec<f32> = (0..c).flat_map(|_| taps.iter().copied()).collect();
        Tensor::<4>::from_data(TensorData::new(v, shape), &dev)
    };
    let x = x.pad([(r, r), (0, 0)], PadMode::Edge);
    let x = x.pad([(0, 0), (r, r)], PadMode::Edge);
    let options = ConvOptions::new([1, 1], [0, 0], [1, 1], c);
    let x = conv::conv2d(x, kernel([c, 1, 2 * r + 1, 1]), None, options.clone());
    conv::conv2d(x, kernel([c, 1, 1, 2 * r + 1]), None, options)
}

/// Random resize and pad: a tensor operation (exact gradient through the bilinear resize).
fn resize_pad(x: Tensor<4>, min_scale: f32, seed: u64) -> (Tensor<4>, Affine) {
    let [_, _, h, w] = x.dims();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let s = match min_scale < 1.0 {
        true => rng.random_range(min_scale..=1.0),
        false => 1.0,
    };
    let nh = ((h as f32 * s).round() as usize).clamp(1, h);
    let nw = ((w as f32 * s).round() as usize).clamp(1, w);
    let oy = rng.random_range(0..=h - nh);
    let ox = rng.random_range(0..=w - nw);
    let small = preprocess::resize_bilinear(x, 2, 3, nh, nw, false, true);
    let placed = kernels::pad_constant(small, &[(oy, h - nh - oy), (ox, w - nw - ox)], 0.0);
    let moved = Affine {
        sx: nw as f32 / w as f32,
        sy: nh as f32 / h as f32,
        dx: ox as f32,
        dy: oy as f32,
    };
    (placed, moved)
}

/// The seed of the defences for one image: the hash of its values.
pub(crate) fn seed_of(x: &Tensor<4>) -> u64 {
    image_hash(&host(x))
}
