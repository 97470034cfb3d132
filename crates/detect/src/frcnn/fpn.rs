//! torchvision's `FeaturePyramidNetwork` (1×1 lateral + 3×3 output convs, nearest top-down
//! upsampling) with `LastLevelMaxPool` (the `pool` level: every other pixel of the last level).

use super::layers::{Conv, ConvShape};
use super::weights::Loader;
use burn::tensor::{Device, Int, Tensor, TensorData};

pub(crate) const CHANNELS: usize = 256;

pub(crate) struct Fpn {
    inner: Vec<Conv>,
    layer: Vec<Conv>,
}

/// PyTorch's `interpolate(mode="nearest", size=out)` source index of each output index.
pub(crate) fn nearest_index(input: usize, output: usize) -> Vec<i64> {
    if input == output {
        return (0..output as i64).collect();
    }
    if output == 2 * input {
        return (0..output as i64).map(|i| i >> 1).collect();
    }
    let scale = input as f32 / output as f32;
    (0..output)
        .map(|i| ((i as f32 * scale).floor() as i64).min(input as i64 - 1))
        .collect()
}

fn gather(x: Tensor<4>, axis: usize, idx: Vec<i64>) -> Tensor<4> {
    let n = idx.len();
    if n == x.dims()[axis] && idx.iter().enumerate().all(|(i, &v)| v == i as i64) {
        return x;
    }
    let dev = x.device();
    x.select(
        axis,
        Tensor::<1, Int>::from_data(TensorData::new(idx, [n]), &dev),
    )
}

impl Fpn {
    pub fn load(l: &mut Loader, p: &str, in_channels: &[usize], dev: &Device) -> Self {
        let inner = in_channels
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                Conv::load(
                    l,
                    &format!("{p}.inner_blocks.{i}.0"),
                    ConvShape::new(c, CHANNELS, 1, 1),
                    true,
                    dev,
                )
            })
            .collect();
        let layer = (0..in_channels.len())
            .map(|i| {
                Conv::load(
                    l,
                    &format!("{p}.layer_blocks.{i}.0"),
                    ConvShape::new(CHANNELS, CHANNELS, 3, 1),
                    true,
                    dev,
                )
            })
            .collect();
        Fpn { inner, layer }
    }

    /// The FPN levels for the backbone outputs `xs`, then the `pool` level.
    pub fn forward(&self, xs: Vec<Tensor<4>>) -> Vec<Tensor<4>> {
        let n = xs.len();
        let mut last = self.inner[n - 1].forward(xs[n - 1].clone());
        let mut out = vec![self.layer[n - 1].forward(last.clone())];
        for i in (0..n - 1).rev() {
            let lateral = self.inner[i].forward(xs[i].clone());
            let [_, _, h, w] = lateral.dims();
            let [_, _, lh, lw] = last.dims();
            let up = gather(
                gather(last, 2, nearest_index(lh, h)),
                3,
                nearest_index(lw, w),
            );
            last = lateral + up;
            out.insert(0, self.layer[i].forward(last.clone()));
        }
        // max_pool2d(kernel 1, stride 2): rows and columns 0, 2, 4, ...
        let top = out[n - 1].clone();
        let [_, _, h, w] = top.dims();
        let pool = gather(
            gather(top, 2, (0..h as i64).step_by(2).collect()),
            3,
            (0..w as i64).step_by(2).collect(),
        );
        out.push(pool);
        out
    }
}
