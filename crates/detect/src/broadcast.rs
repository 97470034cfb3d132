//! Broadcast addition and multiplication whose gradients reduce the broadcast axes in one pass:
//! a convolution's bias, MobileNetV3's squeeze-and-excitation scale (`[N, C, 1, 1]` times the
//! feature map). burn's autodiff reduces such a gradient with `float_sum_dims`, which libtorch's
//! backend leaves at burn's default of one reduction per axis (the first, over H of a
//! channels-last map, a strided pass that writes an intermediate the size of a row of the map);
//! here [`BroadcastKernels::cac_sum_dims`] is one ATen `sum` over all of them. Likewise the
//! mean over several axes (the squeeze of squeeze-and-excitation, [`mean_dims`]): burn takes one
//! axis at a time forward, and backward fills a tensor of ones per axis; libtorch takes one ATen
//! `mean`, and its gradient is one expanded multiplication. The other backends keep burn's
//! arithmetic, so their values and gradients are as before bit for bit.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{binary, unary, Backward, Ops, OpsKind};
use burn::backend::autodiff::NodeId;
use burn::backend::tensor::FloatTensor;
use burn::backend::TensorMetadata;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex};
use burn::tensor::{Shape, Tensor};

/// `x + y` with numpy broadcasting (equal ranks); the gradient of a broadcast operand is one
/// reduction.
pub fn add<const D: usize>(x: Tensor<D>, y: Tensor<D>) -> Tensor<D> {
    let (xs, ys) = (x.dims(), y.dims());
    if let Err(e) = crate::kernels::broadcast_shape(&xs, &ys) {
        panic!("add: {e}");
    }
    match xs == ys {
        true => x + y,
        false => Tensor::from_dispatch(<Dispatch as BroadcastKernels>::cac_add(
            x.into_dispatch(),
            y.into_dispatch(),
        )),
    }
}

/// `x · y` with numpy broadcasting (equal ranks); the gradient of a broadcast operand is one
/// reduction.
pub fn mul<const D: usize>(x: Tensor<D>, y: Tensor<D>) -> Tensor<D> {
    let (xs, ys) = (x.dims(), y.dims());
    if let Err(e) = crate::kernels::broadcast_shape(&xs, &ys) {
        panic!("mul: {e}");
    }
    match xs == ys {
        true => x * y,
        false => Tensor::from_dispatch(<Dispatch as BroadcastKernels>::cac_mul(
            x.into_dispatch(),
            y.into_dispatch(),
        )),
    }
}

/// `x` averaged over `dims` (each kept with length 1; an axis listed twice counts once), in one
/// reduction where the backend has one; on Flex the same values as burn's `mean_dims`.
pub fn mean_dims<const D: usize>(x: Tensor<D>, dims: &[usize]) -> Tensor<D> {
    assert!(
        dims.iter().all(|&d| d < D),
        "axes {dims:?} of a rank-{D} tensor"
    );
    // In the order given (burn's reduction order), each axis once.
    let mut dims = dims.to_vec();
    let mut seen = [false; D];
    dims.retain(|&d| !std::mem::replace(&mut seen[d], true));
    match dims.is_empty() {
        true => x,
        false => Tensor::from_dispatch(<Dispatch as BroadcastKernels>::cac_mean_dims(
            x.into_dispatch(),
            dims,
        )),
    }
}

/// The broadcast ops and the reductions their gradients use, per backend.
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "gpu"), LibTorch: cfg(feature = "tch"))]
pub(crate) trait BroadcastKernels: Backend {
    /// `x` summed over `dims`, each kept with length 1.
    fn cac_sum_dims(x: FloatTensor<Self>, dims: Vec<usize>) -> FloatTensor<Self> {
        Self::float_sum_dims(x, &dims)
    }
    fn cac_add(x: FloatTensor<Self>, y: FloatTensor<Self>) -> FloatTensor<Self> {
        Self::float_add(x, y)
    }
    fn cac_mul(x: FloatTensor<Self>, y: FloatTensor<Self>) -> FloatTensor<Self> {
        Self::float_mul(x, y)
    }
    /// `x` averaged over `dims`, each kept with length 1 (burn's: one axis after the other).
    fn cac_mean_dims(x: FloatTensor<Self>, dims: Vec<usize>) -> FloatTensor<Self> {
        dims.iter().fold(x, |x, &d| Self::float_mean_dim(x, d))
    }
    /// The input gradient of [`BroadcastKernels::cac_mean_dims`] for an input of `shape`
    /// (burn's: per axis, last first, a tensor of `1/n` times the gradient).
    fn cac_mean_dims_backward(
        g: FloatTensor<Self>,
        shape: Vec<usize>,
        dims: Vec<usize>,
    ) -> FloatTensor<Self> {
        // The input shape of each axis's mean, first to last.
        let mut shapes = vec![shape];
        for &d in &dims[..dims.len() - 1] {
            let mut s = shapes.last().unwrap().clone();
            s[d] = 1;
            shapes.push(s);
        }
        dims.iter().zip(shapes).rev().fold(g, |g, (&d, s)| {
            let n = s[d];
            let ones = Self::float_ones(Shape::from(s), &g.device(), g.dtype().into());
            Self::float_mul(Self::float_mul_scalar(ones, (1.0 / n as f64).into()), g)
        })
    }
}

impl BroadcastKernels for Flex {}

#[cfg(feature = "gpu")]
impl BroadcastKernels for burn::backend::Cube {}

/// `g` (of the broadcast result's shape) reduced to `shape`: summed over the axes where `shape`
/// has length 1 and `g` does not, as burn's autodiff does, in one [`BroadcastKernels`] call.
fn reduce_to<B: BroadcastKernels>(g: FloatTensor<B>, shape: &[usize]) -> FloatTensor<B> {
    let dims: Vec<usize> = (0..shape.len())
        .filter(|&a| shape[a] == 1 && g.shape()[a] != 1)
        .collect();
    match dims.is_empty() {
        true => g,
        false => B::cac_sum_dims(g, dims),
    }
}

#[derive(Debug)]
struct Add {
    shapes: [Vec<usize>; 2],
}

impl<B: Backend + BroadcastKernels> Backward<B, 2> for Add {
    type State = ();

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [xs, ys] = self.shapes;
        binary::<B, _, _>(
            ops.parents,
            ops.node,
            grads,
            |g| reduce_to::<B>(g, &xs),
            |g| reduce_to::<B>(g, &ys),
        );
    }
}

#[derive(Debug)]
struct Mul {
    shapes: [Vec<usize>; 2],
}

impl<B: Backend + BroadcastKernels> Backward<B, 2> for Mul {
    /// Each operand, kept only where the other one needs a gradient (as burn's own `mul`).
    type State = (Option<NodeId>, Option<NodeId>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, cp: &mut Checkpointer) {
        let x: Option<FloatTensor<B>> = ops.state.0.map(|n| cp.retrieve_node_output(n));
        let y: Option<FloatTensor<B>> = ops.state.1.map(|n| cp.retrieve_node_output(n));
        let [xs, ys] = self.shapes;
        binary::<B, _, _>(
            ops.parents,
            ops.node,
            grads,
            |g| reduce_to::<B>(B::float_mul(g, y.expect("kept for x's gradient")), &xs),
            |g| reduce_to::<B>(B::float_mul(g, x.expect("kept for y's gradient")), &ys),
        );
    }
}

#[derive(Debug)]
struct MeanDims {
    shape: Vec<usize>,
    dims: Vec<usize>,
}

impl<B: Backend + BroadcastKernels> Backward<B, 1> for MeanDims {
    type State = ();

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        unary::<B, _>(ops.parents, ops.node, grads, |g| {
            B::cac_mean_dims_backward(g, self.shape, self.dims)
        });
    }
}

impl<B: Backend + BroadcastKernels, C: CheckpointStrategy> BroadcastKernels for Autodiff<B, C> {
    fn cac_mean_dims(x: FloatTensor<Self>, dims: Vec<usize>) -> FloatTensor<Self> {
        let op = MeanDims {
            shape: x.shape().to_vec(),
            dims: dims.clone(),
        };
        let prep = op.prepare::<C>([x.node()]).compute_bound();
        prep.stateless(B::cac_mean_dims(x.into_primitive(), dims))
    }
    fn cac_add(x: FloatTensor<Self>, y: FloatTensor<Self>) -> FloatTensor<Self> {
        let shapes = [x.shape().to_vec(), y.shape().to_vec()];
        let prep = Add { shapes }
            .prepare::<C>([x.node(), y.node()])
            .compute_bound();
        prep.stateless(B::cac_add(x.into_primitive(), y.into_primitive()))
    }
    fn cac_mul(x: FloatTensor<Self>, y: FloatTensor<Self>) -> FloatTensor<Self> {
        let shapes = [x.shape().to_vec(), y.shape().to_vec()];
        let op = Mul { shapes };
        match op
            .prepare::<C>([x.node(), y.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let (x_tracked, y_tracked) = (x.is_tracked(), y.is_tracked());
                let state = (
                    y_tracked.then(|| prep.checkpoint(&x)),
                    x_tracked.then(|| prep.checkpoint(&y)),
                );
                prep.finish(state, B::cac_mul(x.into_primitive(), y.into_primitive()))
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::cac_mul(x.into_primitive(), y.into_primitive()))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::seeded;
    use burn::tensor::Device;

    /// The mean over one, two and three axes (in any order) and its gradient are burn's
    /// `mean_dims` to the bit on Flex.
    #[test]
    fn mean_over_axes_and_its_gradient_are_burns() {
        let dev = Device::autodiff(Device::from(burn::backend::FlexDevice));
        for (k, dims) in [vec![2], vec![2, 3], vec![3, 1], vec![0, 2, 3]]
            .into_iter()
            .enumerate()
        {
            let x = seeded([2, 3, 5, 7], k as u64, 2.0, &dev).require_grad();
            let (got, want) = (mean_dims(x.clone(), &dims), x.clone().mean_dims(&dims));
            let up = seeded(got.dims(), 50, 2.0, &dev);
            let gg = x
                .grad(&(got.clone() * up.clone()).sum().backward())
                .unwrap();
            let gw = x.grad(&(want.clone() * up).sum().backward()).unwrap();
            assert_eq!(got.into_data(), want.into_data(), "{dims:?}");
            assert_eq!(gg.into_data(), gw.into_data(), "gradient, {dims:?}");
        }
        // An axis listed twice is averaged once.
        let x = seeded([2, 3, 5, 7], 9, 2.0, &dev);
        let (got, want) = (mean_dims(x.clone(), &[2, 3, 2]), x.mean_dims(&[2, 3]));
        assert_eq!(got.into_data(), want.into_data());
    }

    /// Values and both gradients are burn's own broadcast ops' to the bit (Flex keeps burn's
    /// reduction), for a bias, a squeeze-and-excitation scale, a row and equal shapes.
    #[test]
    fn broadcast_ops_and_gradients_are_burns() {
        let dev = Device::autodiff(Device::from(burn::backend::FlexDevice));
        let cases = [
            ([2, 3, 4, 5], [1, 3, 1, 1]),
            ([2, 3, 4, 5], [2, 3, 1, 1]),
            ([1, 3, 4, 5], [1, 1, 1, 5]),
            ([1, 3, 1, 5], [2, 3, 4, 1]), // both broadcast
            ([2, 3, 4, 5], [2, 3, 4, 5]),
        ];
        for (k, (xs, ys)) in cases.into_iter().enumerate() {
            for op in ["add", "mul"] {
                let x = seeded(xs, 2 * k as u64, 2.0, &dev).require_grad();
                let y = seeded(ys, 2 * k as u64 + 1, 2.0, &dev).require_grad();
                let (got, want) = match op {
                    "add" => (add(x.clone(), y.clone()), x.clone() + y.clone()),
                    _ => (mul(x.clone(), y.clone()), x.clone() * y.clone()),
                };
                assert_eq!(got.dims(), want.dims());
                let up = seeded(got.dims(), 99, 2.0, &dev);
                let (gg, gw) = (
                    (got.clone() * up.clone()).sum().backward(),
                    (want.clone() * up).sum().backward(),
                );
                let what = format!("{op} {xs:?} {ys:?}");
                assert_eq!(got.into_data(), want.into_data(), "{what}");
                for t in [&x, &y] {
                    let (a, b) = (t.grad(&gg).unwrap(), t.grad(&gw).unwrap());
                    assert_eq!(a.into_data(), b.into_data(), "gradient, {what}");
                }
            }
        }
    }
}
