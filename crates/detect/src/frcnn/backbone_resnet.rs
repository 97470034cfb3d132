//! torchvision's ResNet-50 body (Bottleneck v1.5, stride in the 3×3 conv) for detection:
//! returns `layer1..layer4` (256, 512, 1024, 2048 channels at strides 4, 8, 16, 32).

use super::layers::{Conv, ConvShape};
use super::weights::Loader;
use burn::tensor::activation::relu;
use burn::tensor::module::max_pool2d;
use burn::tensor::ops::MaxPoolOptions;
use burn::tensor::{Device, Tensor};

struct Bottleneck {
    conv1: Conv,
    conv2: Conv,
    conv3: Conv,
    downsample: Option<Conv>,
}

pub struct ResNet50 {
    stem: Conv,
    layers: Vec<Vec<Bottleneck>>,
}

impl ResNet50 {
    pub(crate) const CHANNELS: [usize; 4] = [256, 512, 1024, 2048];

    pub fn load(l: &mut Loader, p: &str, dev: &Device) -> Self {
        let stem = Conv::load_bn(
            l,
            &format!("{p}.conv1"),
            &format!("{p}.bn1"),
            ConvShape::new(3, 64, 7, 2),
            dev,
        );
        let mut layers = Vec::new();
        let mut cin = 64;
        for (li, (&blocks, width)) in [3usize, 4, 6, 3]
            .iter()
            .zip([64usize, 128, 256, 512])
            .enumerate()
        {
            let cout = width * 4;
            let mut layer = Vec::new();
            for bi in 0..blocks {
                let b = format!("{p}.layer{}.{bi}", li + 1);
                let stride = if bi == 0 && li > 0 { 2 } else { 1 };
                let c = |l: &mut Loader, n: usize, s: ConvShape| {
                    Conv::load_bn(l, &format!("{b}.conv{n}"), &format!("{b}.bn{n}"), s, dev)
                };
                let conv1 = c(l, 1, ConvShape::new(cin, width, 1, 1));
                let conv2 = c(l, 2, ConvShape::new(width, width, 3, stride));
                let conv3 = c(l, 3, ConvShape::new(width, cout, 1, 1));
                let downsample = (bi == 0).then(|| {
                    Conv::load_bn(
                        l,
                        &format!("{b}.downsample.0"),
                        &format!("{b}.downsample.1"),
                        ConvShape::new(cin, cout, 1, stride),
                        dev,
                    )
                });
                layer.push(Bottleneck {
                    conv1,
                    conv2,
                    conv3,
                    downsample,
                });
                cin = cout;
            }
            layers.push(layer);
        }
        ResNet50 { stem, layers }
    }

    pub fn forward(&self, x: Tensor<4>) -> Vec<Tensor<4>> {
        let x = relu(self.stem.forward(x));
        let opts = MaxPoolOptions::new([3, 3])
            .with_stride([2, 2])
            .with_padding([1, 1]);
        let mut x = max_pool2d(x, opts);
        let mut out = Vec::new();
        for layer in &self.layers {
            for b in layer {
                let identity = match &b.downsample {
                    Some(d) => d.forward(x.clone()),
                    None => x.clone(),
                };
                let y = relu(b.conv1.forward(x));
                let y = relu(b.conv2.forward(y));
                x = relu(b.conv3.forward(y) + identity);
            }
            out.push(x.clone());
        }
        out
    }
}
