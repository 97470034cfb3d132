//! The layers the Faster R-CNN models are made of: 2-D convolution (optionally followed by an
//! eval-mode / frozen BatchNorm, folded into its weights and bias), and fully connected layers.
//!
//! BatchNorm folding: `y = conv(x) * a + b` with `a = γ / sqrt(var + 1e-5)`, `b = β − mean · a`
//! (torchvision's FrozenBatchNorm2d and eval BatchNorm2d compute the same `a`, `b`).

use super::weights::Loader;
use crate::conv::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Device, Tensor, TensorData};

const BN_EPS: f32 = 1e-5;

/// A convolution with bias (own or folded BatchNorm), padding `(k − 1) / 2 · dilation`.
pub struct Conv {
    w: Tensor<4>,
    b: Option<Tensor<1>>,
    opts: ConvOptions<2>,
}

/// Geometry of a convolution.
#[derive(Clone, Copy, Debug)]
pub struct ConvShape {
    pub cin: usize,
    pub cout: usize,
    pub k: usize,
    pub stride: usize,
    pub groups: usize,
    pub dilation: usize,
}

impl ConvShape {
    pub fn new(cin: usize, cout: usize, k: usize, stride: usize) -> Self {
        ConvShape {
            cin,
            cout,
            k,
            stride,
            groups: 1,
            dilation: 1,
        }
    }

    pub fn groups(mut self, g: usize) -> Self {
        self.groups = g;
        self
    }

    fn weight_shape(&self) -> [usize; 4] {
        [self.cout, self.cin / self.groups, self.k, self.k]
    }

    fn options(&self) -> ConvOptions<2> {
        let p = (self.k - 1) / 2 * self.dilation;
        ConvOptions::new([self.stride; 2], [p; 2], [self.dilation; 2], self.groups)
    }
}

impl Conv {
    /// `{name}.weight` and, if `bias`, `{name}.bias`.
    pub fn load(l: &mut Loader, name: &str, s: ConvShape, bias: bool, dev: &Device) -> Self {
        let ws = s.weight_shape();
        let w = l.take(&format!("{name}.weight"), &ws);
        let b = bias.then(|| l.take(&format!("{name}.bias"), &[s.cout]));
        Conv {
            w: Tensor::from_data(TensorData::new(w, ws), dev),
            b: b.map(|b| Tensor::from_data(TensorData::new(b, [s.cout]), dev)),
            opts: s.options(),
        }
    }

    /// A bias-free convolution `{conv}.weight` followed by the BatchNorm `{bn}.*`, folded.
    pub(crate) fn load_bn(
        l: &mut Loader,
        conv: &str,
        bn: &str,
        s: ConvShape,
        dev: &Device,
    ) -> Self {
        let ws = s.weight_shape();
        let mut w = l.take(&format!("{conv}.weight"), &ws);
        let c = [s.cout];
        let gamma = l.take(&format!("{bn}.weight"), &c);
        let beta = l.take(&format!("{bn}.bias"), &c);
        let mean = l.take(&format!("{bn}.running_mean"), &c);
        let var = l.take(&format!("{bn}.running_var"), &c);
        let per = w.len() / s.cout;
        let mut bias = vec![0f32; s.cout];
        for o in 0..s.cout {
            let a = gamma[o] * (1.0 / (var[o] + BN_EPS).sqrt());
            bias[o] = beta[o] - mean[o] * a;
            for v in &mut w[o * per..(o + 1) * per] {
                *v *= a;
            }
        }
        Conv {
            w: Tensor::from_data(TensorData::new(w, ws), dev),
            b: Some(Tensor::from_data(TensorData::new(bias, c), dev)),
            opts: s.options(),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        conv2d(x, self.w.clone(), self.b.clone(), self.opts.clone())
    }
}

/// A fully connected layer `y = x Wᵀ + b` (`{name}.weight` is `[out, in]` as in PyTorch).
pub struct Linear {
    wt: Tensor<2>,
    b: Tensor<2>,
}

impl Linear {
    pub fn load(l: &mut Loader, name: &str, cin: usize, cout: usize, dev: &Device) -> Self {
        let w = l.take(&format!("{name}.weight"), &[cout, cin]);
        let b = l.take(&format!("{name}.bias"), &[cout]);
        let w: Tensor<2> = Tensor::from_data(TensorData::new(w, [cout, cin]), dev);
        Linear {
            wt: w.transpose(),
            b: Tensor::from_data(TensorData::new(b, [1, cout]), dev),
        }
    }

    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        x.matmul(self.wt.clone()) + self.b.clone()
    }
}
