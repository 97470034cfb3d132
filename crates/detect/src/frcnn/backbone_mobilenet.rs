//! torchvision's MobileNetV3-Large feature extractor for detection (`mobilenet_backbone`,
//! not dilated): `features[0..=16]`, returning the outputs of `features[13]` (160 channels)
//! and `features[16]` (960 channels), both at stride 32, as FPN inputs `0` and `1`.

use super::layers::{Conv, ConvShape};
use super::weights::Loader;
use burn::tensor::activation::{hard_sigmoid, hard_swish, relu};
use burn::tensor::{Device, Tensor};

/// `(input, kernel, expanded, output, squeeze-excite, hard-swish, stride)` of torchvision's
/// `_mobilenet_v3_conf("mobilenet_v3_large")`.
const LARGE: [(usize, usize, usize, usize, bool, bool, usize); 15] = [
    (16, 3, 16, 16, false, false, 1),
    (16, 3, 64, 24, false, false, 2),
    (24, 3, 72, 24, false, false, 1),
    (24, 5, 72, 40, true, false, 2),
    (40, 5, 120, 40, true, false, 1),
    (40, 5, 120, 40, true, false, 1),
    (40, 3, 240, 80, false, true, 2),
    (80, 3, 200, 80, false, true, 1),
    (80, 3, 184, 80, false, true, 1),
    (80, 3, 184, 80, false, true, 1),
    (80, 3, 480, 112, true, true, 1),
    (112, 3, 672, 112, true, true, 1),
    (112, 5, 672, 160, true, true, 2),
    (160, 5, 960, 160, true, true, 1),
    (160, 5, 960, 160, true, true, 1),
];

/// torchvision's `_make_divisible(v, 8)`.
fn make_divisible(v: usize) -> usize {
    let nv = 8usize.max((v + 4) / 8 * 8);
    if (nv as f64) < 0.9 * v as f64 {
        nv + 8
    } else {
        nv
    }
}

struct Se {
    fc1: Conv,
    fc2: Conv,
}

struct Block {
    expand: Option<Conv>,
    depthwise: Conv,
    se: Option<Se>,
    project: Conv,
    hswish: bool,
    residual: bool,
}

pub struct MobileNetV3 {
    stem: Conv,
    blocks: Vec<Block>,
    last: Conv,
}

fn act(x: Tensor<4>, hswish: bool) -> Tensor<4> {
    if hswish {
        hard_swish(x)
    } else {
        relu(x)
    }
}

impl MobileNetV3 {
    /// Output channels of the two returned levels.
    pub(crate) const CHANNELS: [usize; 2] = [160, 960];

    pub fn load(l: &mut Loader, p: &str, dev: &Device) -> Self {
        let cbn = |l: &mut Loader, name: String, s: ConvShape| {
            Conv::load_bn(l, &format!("{name}.0"), &format!("{name}.1"), s, dev)
        };
        let stem = cbn(l, format!("{p}.0"), ConvShape::new(3, 16, 3, 2));
        let mut blocks = Vec::new();
        for (i, &(cin, k, exp, cout, se, hs, stride)) in LARGE.iter().enumerate() {
            let b = format!("{p}.{}.block", i + 1);
            let mut j = 0;
            let expand = (exp != cin).then(|| {
                j += 1;
                cbn(l, format!("{b}.0"), ConvShape::new(cin, exp, 1, 1))
            });
            let depthwise = cbn(
                l,
                format!("{b}.{j}"),
                ConvShape::new(exp, exp, k, stride).groups(exp),
            );
            j += 1;
            let se = se.then(|| {
                let sq = make_divisible(exp / 4);
                let s = Se {
                    fc1: Conv::load(
                        l,
                        &format!("{b}.{j}.fc1"),
                        ConvShape::new(exp, sq, 1, 1),
                        true,
                        dev,
                    ),
                    fc2: Conv::load(
                        l,
                        &format!("{b}.{j}.fc2"),
                        ConvShape::new(sq, exp, 1, 1),
                        true,
                        dev,
                    ),
                };
                j += 1;
                s
            });
            let project = cbn(l, format!("{b}.{j}"), ConvShape::new(exp, cout, 1, 1));
            blocks.push(Block {
                expand,
                depthwise,
                se,
                project,
                hswish: hs,
                residual: stride == 1 && cin == cout,
            });
        }
        let last = cbn(l, format!("{p}.16"), ConvShape::new(160, 960, 1, 1));
        MobileNetV3 { stem, blocks, last }
    }

    /// `[features[13] output, features[16] output]`.
    pub fn forward(&self, x: Tensor<4>) -> Vec<Tensor<4>> {
        let mut x = hard_swish(self.stem.forward(x));
        let mut c4 = None;
        for (i, b) in self.blocks.iter().enumerate() {
            let input = x.clone();
            let mut y = x;
            if let Some(e) = &b.expand {
                y = act(e.forward(y), b.hswish);
            }
            y = act(b.depthwise.forward(y), b.hswish);
            if let Some(se) = &b.se {
                let [n, c, h, w] = y.dims();
                let s = y
                    .clone()
                    .reshape([n, c, h * w])
                    .mean_dim(2)
                    .reshape([n, c, 1, 1]);
                let s = relu(se.fc1.forward(s));
                let s = hard_sigmoid(se.fc2.forward(s), 1.0 / 6.0, 0.5);
                y = y * s;
            }
            y = b.project.forward(y);
            x = if b.residual { y + input } else { y };
            if i + 1 == 13 {
                c4 = Some(x.clone());
            }
        }
        let last = hard_swish(self.last.forward(x));
        vec![c4.expect("15 blocks"), last]
    }
}
