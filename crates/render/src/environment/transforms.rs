//! The photometric part of a [`Condition`] as tensor ops (differentiable almost everywhere; the
//! final clip to [0, 1] passes no gradient where it saturates, as in the paper).

use super::Condition;
use burn::tensor::{Tensor, TensorData};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Print error on the atlas: `clip(atlas · m_c + a_c)` per view and channel.
/// `atlas` is `[1, R, R, 3]`; returns `[V, R, R, 3]`.
pub fn print_error(atlas: Tensor<4>, conds: &[Condition]) -> Tensor<4> {
    let device = atlas.device();
    let dtype = atlas.dtype();
    let v = conds.len();
    let mul: Vec<f32> = conds.iter().flat_map(|c| c.channel_mul).collect();
    let add: Vec<f32> = conds.iter().flat_map(|c| c.channel_add).collect();
    let mul = Tensor::<4>::from_data(TensorData::new(mul, [v, 1, 1, 3]), (&device, dtype));
    let add = Tensor::<4>::from_data(TensorData::new(add, [v, 1, 1, 3]), (&device, dtype));
    (atlas * mul + add).clamp(0.0, 1.0)
}

/// Lighten/darken and sensor noise on the images: `clip(img · m + a + N(0, σ²))`.
/// `images` is `[V, 3, H, W]`; the noise is drawn from each condition's own seed.
pub fn photometric(images: Tensor<4>, conds: &[Condition]) -> Tensor<4> {
    let [v, c, h, w] = images.dims();
    assert_eq!(v, conds.len(), "one condition per image");
    let device = images.device();
    let dtype = images.dtype();
    let mul = Tensor::<4>::from_data(
        TensorData::new(
            conds.iter().map(|c| c.light_mul).collect::<Vec<f32>>(),
            [v, 1, 1, 1],
        ),
        (&device, dtype),
    );
    let add = Tensor::<4>::from_data(
        TensorData::new(
            conds.iter().map(|c| c.light_add).collect::<Vec<f32>>(),
            [v, 1, 1, 1],
        ),
        (&device, dtype),
    );
    let mut noise = Vec::with_capacity(v * c * h * w);
    for cond in conds {
        let mut rng = ChaCha8Rng::seed_from_u64(cond.noise_seed);
        let sd = cond.noise_std.max(0.0);
        match Normal::new(0.0f32, sd) {
            Ok(n) if sd > 0.0 => noise.extend((0..c * h * w).map(|_| n.sample(&mut rng))),
            _ => noise.extend(std::iter::repeat_n(0.0, c * h * w)),
        }
    }
    let noise = Tensor::<4>::from_data(TensorData::new(noise, [v, c, h, w]), (&device, dtype));
    (images * mul + add + noise).clamp(0.0, 1.0)
}
