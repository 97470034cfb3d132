//! The atlas gradient of an image-forming function against central differences in f64: the
//! check the renderer's tests share.

use burn::tensor::{DType, Device, Tensor, TensorData};
use rand::Rng;

/// `form` maps an atlas `[1, R, R, 3]` to images of `image_dims`; the loss is their sum
/// weighted by seeded random weights. Returns the worst relative error of autodiff's gradient
/// against central differences (step 1e-6) over `probes` random texels among those with a
/// gradient above 1e-6 (of which there must be more than 50).
pub fn worst_atlas_gradient_error(
    form: &dyn Fn(Tensor<4>) -> Tensor<4>,
    atlas: &[f64],
    res: usize,
    image_dims: [usize; 4],
    probes: usize,
    rng: &mut impl Rng,
) -> f64 {
    let dev = Device::autodiff(super::device());
    let n: usize = image_dims.iter().product();
    let wimg: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let loss_of = |a: &[f64], grad: bool| -> (f64, Option<Vec<f64>>) {
        let t = Tensor::<4>::from_data(
            TensorData::new(a.to_vec(), [1, res, res, 3]),
            (&dev, DType::F64),
        );
        let t = if grad { t.require_grad() } else { t };
        let w = Tensor::<4>::from_data(
            TensorData::new(wimg.clone(), image_dims),
            (&dev, DType::F64),
        );
        let loss = (form(t.clone()) * w).sum();
        let v = loss
            .clone()
            .into_data()
            .convert::<f64>()
            .try_to_vec::<f64>()
            .unwrap()[0];
        let g = grad.then(|| {
            let gr = loss.backward();
            t.grad(&gr)
                .unwrap()
                .into_data()
                .convert::<f64>()
                .try_to_vec::<f64>()
                .unwrap()
        });
        (v, g)
    };
    let g = loss_of(atlas, true).1.unwrap();
    let mut idx: Vec<usize> = (0..g.len()).filter(|&i| g[i].abs() > 1e-6).collect();
    assert!(
        idx.len() > 50,
        "too few texels with a gradient: {}",
        idx.len()
    );
    let mut worst = 0.0f64;
    for _ in 0..probes {
        let i = idx.swap_remove(rng.random_range(0..idx.len()));
        let (h, mut a) = (1e-6, atlas.to_vec());
        a[i] += h;
        let (lp, _) = loss_of(&a, false);
        a[i] -= 2.0 * h;
        let (lm, _) = loss_of(&a, false);
        worst = worst.max(((lp - lm) / (2.0 * h) - g[i]).abs() / g[i].abs().max(1e-8));
    }
    worst
}
