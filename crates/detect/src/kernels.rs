//! What both graph executors (TFJS and ONNX) compute the same way: numpy broadcasting of two
//! shapes ([`broadcast_shape`]) and constant padding on the device ([`pad_constant`]). Not here:
//! layouts or attribute parsing (the executors' own).

use anyhow::{bail, Result};
use burn::tensor::Tensor;

/// `x` with `pairs[i]` = (before, after) values of `value` added along its last `pairs.len()`
/// axes, as burn's `pad` with `PadMode::Constant`. burn builds that constant on the host on
/// backends without a native `full` (libtorch: a host buffer the size of the output, then a
/// copy), which was most of NanoDet's pads there; zeros, a scalar add and a slice assignment stay
/// on the device. The gradient is the slice of the output's.
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
    let dims = x.dims();
    let first = D - pairs.len();
    let (mut out, mut centre) = (dims, dims.map(|d| 0..d));
    for (i, &(before, after)) in pairs.iter().enumerate() {
        out[first + i] += before + after;
        centre[first + i] = before..before + dims[first + i];
    }
    if out == dims {
        return x;
    }
    let base = Tensor::<D>::zeros(out, &x.device());
    let base = match value == 0.0 {
        true => base,
        false => base.add_scalar(value),
    };
    base.slice_assign(centre, x)
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
