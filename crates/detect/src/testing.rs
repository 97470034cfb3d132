//! Seeded inputs for the unit tests of the kernel modules.

use burn::tensor::{Device, Tensor, TensorData};
use rand::{Rng, SeedableRng};

/// A uniform tensor in ±`bound` from `seed` (host values: the device's generator is shared
/// by parallel tests).
pub fn seeded(dims: [usize; 4], seed: u64, bound: f32, dev: &Device) -> Tensor<4> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let v: Vec<f32> = (0..dims.iter().product::<usize>())
        .map(|_| rng.random_range(-bound..bound))
        .collect();
    Tensor::from_data(TensorData::new(v, dims), dev)
}
