//! What both graph executors (TFJS and ONNX) compute the same way: numpy broadcasting of two
//! shapes ([`broadcast_shape`]) and constant padding on the device ([`pad_constant`], through the
//! [`PadKernels`] backend extension and its autodiff op). Not here: layouts or attribute parsing
//! (the executors' own).

use anyhow::{bail, Result};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{unary, Backward, Ops};
use burn::backend::tensor::FloatTensor;
use burn::backend::TensorMetadata;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex};
use burn::tensor::{Shape, Slice, Tensor};

/// `x` with `pairs[i]` = (before, after) values of `value` added along its last `pairs.len()`
/// axes, as burn's `pad` with `PadMode::Constant`, through [`PadKernels`]. The gradient is the
/// slice of the output's.
pub fn pad_constant<const D: usize>(
    x: Tensor<D>,
    pairs: &[(usize, usize)],
    value: f32,
) -> Tensor<D> {
    assert!(
        pairs.len() <= D,
        "{} padding pairs for a rank-{D} tensor",
        pairs.len()
    );
    if pairs.iter().all(|&(b, a)| b == 0 && a == 0) {
        return x;
    }
    let mut all = vec![(0, 0); D - pairs.len()];
    all.extend_from_slice(pairs);
    Tensor::from_dispatch(<Dispatch as PadKernels>::cac_pad(
        x.into_dispatch(),
        all,
        value,
    ))
}

/// Constant padding per backend: `pairs` holds one (before, after) pair for every axis. The
/// default body is zeros, a scalar add and a slice assignment, all on the device: burn's own
/// `pad` builds its constant on the host on backends without a native `full` (libtorch: a host
/// buffer the size of the output, then a copy), which was most of NanoDet's pads there. libtorch
/// pads with ATen's `constant_pad_nd`, which also keeps the input's memory format (channels
/// last, `detect::libtorch`).
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "gpu"), LibTorch: cfg(feature = "tch"))]
pub(crate) trait PadKernels: Backend {
    fn cac_pad(x: FloatTensor<Self>, pairs: Vec<(usize, usize)>, value: f32) -> FloatTensor<Self> {
        let dims = x.shape().to_vec();
        let out: Vec<usize> = dims
            .iter()
            .zip(&pairs)
            .map(|(d, (b, a))| d + b + a)
            .collect();
        let base = Self::float_zeros(Shape::from(out), &x.device(), x.dtype().into());
        let base = match value == 0.0 {
            true => base,
            false => Self::float_add_scalar(base, value.into()),
        };
        Self::float_slice_assign(base, &centre(&dims, &pairs), x)
    }
}

/// The slices of a padded tensor that hold the input.
fn centre(dims: &[usize], pairs: &[(usize, usize)]) -> Vec<Slice> {
    dims.iter()
        .zip(pairs)
        .map(|(&d, &(b, _))| Slice::from(b..b + d))
        .collect()
}

impl PadKernels for Flex {}

#[cfg(feature = "gpu")]
impl PadKernels for burn::backend::Cube {}

/// The pad as an autodiff op: the gradient is the centre of the output's.
#[derive(Debug)]
struct Pad(Vec<Slice>);

impl<B: Backend> Backward<B, 1> for Pad {
    type State = ();

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        unary::<B, _>(ops.parents, ops.node, grads, |g| B::float_slice(g, &self.0));
    }
}

impl<B: Backend + PadKernels, C: CheckpointStrategy> PadKernels for Autodiff<B, C> {
    fn cac_pad(x: FloatTensor<Self>, pairs: Vec<(usize, usize)>, value: f32) -> FloatTensor<Self> {
        let op = Pad(centre(&x.shape(), &pairs));
        let prep = op.prepare::<C>([x.node()]).compute_bound();
        prep.stateless(B::cac_pad(x.into_primitive(), pairs, value))
    }
}

/// numpy's broadcast of two shapes (aligned at the last axis; a 1 stretches).
pub fn broadcast_shape(a: &[usize], b: &[usize]) -> Result<Vec<usize>> {
    let r = a.len().max(b.len());
    let at = |s: &[usize], k: usize| {
        if k + s.len() >= r {
            s[k + s.len() - r]
        } else {
            1
        }
    };
    (0..r)
        .map(|k| match (at(a, k), at(b, k)) {
            (x, y) if x == y => Ok(x),
            (1, y) => Ok(y),
            (x, 1) => Ok(x),
            _ => bail!("shapes {a:?} and {b:?} do not broadcast"),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::ops::PadMode;
    use burn::tensor::{Device, TensorData};

    /// The same values as burn's constant `pad` (zero, a value, −∞; two and all four axes),
    /// and the gradient of the input is the output gradient's centre.
    #[test]
    fn pad_constant_equals_burns_pad_and_its_gradient_is_the_centre() {
        let dev = Device::autodiff(Device::from(burn::backend::FlexDevice));
        let v: Vec<f32> = (0..2 * 3 * 4 * 5)
            .map(|i| (i as f32 * 0.37).sin())
            .collect();
        let x = Tensor::<4>::from_data(TensorData::new(v, [2, 3, 4, 5]), &dev).require_grad();
        for value in [0.0f32, 2.5, f32::NEG_INFINITY] {
            for pairs in [vec![(1, 2), (0, 3)], vec![(0, 1), (2, 0), (1, 1), (3, 2)]] {
                let got = pad_constant(x.clone(), &pairs, value);
                let want = match pairs.len() {
                    2 => x
                        .clone()
                        .pad([pairs[0], pairs[1]], PadMode::Constant(value)),
                    _ => x.clone().pad(
                        [pairs[0], pairs[1], pairs[2], pairs[3]],
                        PadMode::Constant(value),
                    ),
                };
                assert_eq!(got.dims(), want.dims());
                let (g, w) = (got.to_data(), want.to_data());
                assert_eq!(g, w, "value {value}, pairs {pairs:?}");
            }
        }
        let y = pad_constant(x.clone(), &[(1, 2), (2, 3)], 0.0);
        let n: usize = y.dims().iter().product();
        let ramp: Vec<f32> = (0..n).map(|i| i as f32).collect();
        let up = Tensor::<4>::from_data(TensorData::new(ramp, y.dims()), &dev);
        let g = x.grad(&(y * up.clone()).sum().backward()).unwrap();
        let centre = up.slice([0..2, 0..3, 1..5, 2..7]);
        assert_eq!(g.into_data(), centre.into_data());
    }
}
