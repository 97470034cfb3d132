//! The multi-scale parameterisation of the atlas: the atlas is the sum of `K` levels, level `k`
//! an `(r/2^k)²` RGB image upsampled to `r²` by repeating each texel over a `2^k × 2^k` block,
//!
//! `A = Σ_k U_k(P_k)`,  `∂L/∂P_k = U_kᵀ(∂L/∂A)` (the sum of the atlas gradient over each block).
//!
//! Optimised texel by texel (`K = 1`), a 256² atlas learns small repeated motifs that only close
//! views resolve; coarse levels give the optimiser directions that change whole regions at once,
//! which far views (and other detectors) still see. Adam normalises each parameter's step, so a
//! coarse texel moves as far per step as a fine one while covering `4^k` atlas texels.
//!
//! Coarse levels act only on the texels that paintable surfaces can sample (`mask`, from
//! [`super::baselines::atlas::paintable_texels`]): the rest of the atlas keeps its colours, as
//! with texel-by-texel optimisation.
//!
//! The atlas must stay in [0, 1]: after each step [`project`] clips the composed atlas and puts
//! the difference into the finest level, so the composition is exactly the clipped atlas and the
//! coarse levels keep their values. Level 0 starts as the initial atlas, the others at zero.
//! Not here: the optimiser ([`super::adam`]), rendering.

use anyhow::{bail, Result};

/// Number of parameters of a `res²` RGB atlas in `scales` levels.
pub fn len(res: usize, scales: usize) -> usize {
    (0..scales).map(|k| 3 * (res >> k) * (res >> k)).sum()
}

/// Checks that `res` halves cleanly `scales - 1` times.
pub fn check(res: usize, scales: usize) -> Result<()> {
    if !(1..=8).contains(&scales) {
        bail!("--scales must be 1..=8, got {scales}");
    }
    if res % (1 << (scales - 1)) != 0 {
        bail!(
            "a {res}² atlas cannot be split into {scales} levels (its side must be a multiple of {})",
            1 << (scales - 1)
        );
    }
    Ok(())
}

/// The parameters of an initial atlas (row-major RGB, `res²`): level 0 = the atlas, others 0.
pub(crate) fn from_atlas(atlas: &[f32], res: usize, scales: usize) -> Vec<f32> {
    let mut p = atlas.to_vec();
    p.resize(len(res, scales), 0.0);
    p
}

/// Iterates the levels: `(offset in params, side)`.
fn levels(res: usize, scales: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..scales).scan(0usize, move |off, k| {
        let side = res >> k;
        let here = *off;
        *off += 3 * side * side;
        Some((here, side))
    })
}

/// The atlas `Σ_k U_k(P_k)` (row-major RGB, `res²`), coarse levels only where `mask` is set.
pub fn compose(params: &[f32], res: usize, scales: usize, mask: &[bool]) -> Vec<f32> {
    let mut a = params[..3 * res * res].to_vec();
    for (off, side) in levels(res, scales).skip(1) {
        let f = res / side;
        for y in 0..res {
            for x in (0..res).filter(|x| mask[y * res + x]) {
                let s = off + 3 * ((y / f) * side + x / f);
                let d = 3 * (y * res + x);
                for c in 0..3 {
                    a[d + c] += params[s + c];
                }
            }
        }
    }
    a
}

/// The gradient with respect to the parameters from the atlas gradient: level 0 takes it as it
/// is, level `k` the sum over each `2^k × 2^k` block (the transpose of [`compose`]).
pub fn adjoint(grad: &[f32], res: usize, scales: usize, mask: &[bool]) -> Vec<f32> {
    let mut g = vec![0.0f32; len(res, scales)];
    g[..3 * res * res].copy_from_slice(grad);
    for (off, side) in levels(res, scales).skip(1) {
        let f = res / side;
        for y in 0..res {
            for x in (0..res).filter(|x| mask[y * res + x]) {
                let d = off + 3 * ((y / f) * side + x / f);
                let s = 3 * (y * res + x);
                for c in 0..3 {
                    g[d + c] += grad[s + c];
                }
            }
        }
    }
    g
}

/// Clips the composed atlas to [0, 1] by changing level 0 alone (see the module docs).
pub fn project(params: &mut [f32], res: usize, scales: usize, mask: &[bool]) {
    let a = compose(params, res, scales, mask);
    for (i, v) in a.iter().enumerate() {
        let c = v.clamp(0.0, 1.0);
        params[i] += c - v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn adjoint_is_the_transpose_of_compose_and_project_clips() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (res, scales) = (8, 3);
        let all = vec![true; res * res];
        // A mask with holes: every third texel is not paintable.
        let some: Vec<bool> = (0..res * res).map(|i| i % 3 != 0).collect();
        assert_eq!(len(res, scales), 3 * (64 + 16 + 4));
        let p: Vec<f32> = (0..len(res, scales))
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let y: Vec<f32> = (0..3 * res * res)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x * y) as f64).sum::<f64>();
        for m in [&all, &some] {
            let lhs = dot(&compose(&p, res, scales, m), &y);
            let rhs = dot(&p, &adjoint(&y, res, scales, m));
            assert!((lhs - rhs).abs() < 1e-4, "{lhs} vs {rhs}");
        }
        // Texels outside the mask are level 0 alone.
        let a = compose(&p, res, scales, &some);
        assert_eq!(a[0..3], p[0..3]);
        // A coarse texel covers its block: texel (0, 0) of level 2 sits in atlas texels 0..4².
        let mut q = vec![0.0; len(res, scales)];
        q[3 * (64 + 16)] = 0.5;
        let a = compose(&q, res, scales, &all);
        assert_eq!(a[3 * (3 * res + 3)], 0.5);
        assert_eq!(a[3 * (4 * res + 3)], 0.0);
        // Projection: the composition ends in [0, 1]; coarse levels keep their values.
        let mut r = p.clone();
        project(&mut r, res, scales, &some);
        assert!(compose(&r, res, scales, &some)
            .iter()
            .all(|v| (-1e-6..=1.0 + 1e-6).contains(v)));
        assert_eq!(r[3 * res * res..], p[3 * res * res..]);
        // One level is the atlas itself.
        assert_eq!(compose(&y, res, 1, &all), y);
        assert!(check(256, 4).is_ok() && check(100, 4).is_err() && check(256, 0).is_err());
    }
}
