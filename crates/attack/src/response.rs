//! Training through a full-colour or paper printer's fitted response
//! ([`cac_core::printer::Response`]): the optimiser moves the requested colours (the image sent to
//! the printer, kept in 0..1), every view renders the printed ones, and the gradient reaches the
//! requested colours through the response's per-texel Jacobian. The response clips to what the
//! printer can make, so everything trained on is inside its gamut.

use cac_core::printer::Response;

/// Step of the central differences of the per-texel Jacobian (display units).
const H: f32 = 1e-3;

/// The printed atlas of a requested one (row-major RGB).
pub fn forward(r: &Response, requested: &[f32]) -> Vec<f32> {
    requested
        .chunks_exact(3)
        .flat_map(|c| r.apply([c[0], c[1], c[2]]))
        .collect()
}

/// The gradient with respect to the requested atlas from the gradient with respect to the
/// printed one: `Jᵀ g` per texel, the Jacobian by central differences (one-sided at 0 and 1).
pub fn backward(r: &Response, requested: &[f32], g: &[f32]) -> Vec<f32> {
    let mut out = vec![0.0; requested.len()];
    for ((c, gt), o) in requested
        .chunks_exact(3)
        .zip(g.chunks_exact(3))
        .zip(out.chunks_exact_mut(3))
    {
        let c = [c[0], c[1], c[2]];
        for j in 0..3 {
            let (mut up, mut down) = (c, c);
            up[j] = (c[j] + H).min(1.0);
            down[j] = (c[j] - H).max(0.0);
            let (pu, pd) = (r.apply(up), r.apply(down));
            let step = up[j] - down[j];
            o[j] = (0..3).map(|i| gt[i] * (pu[i] - pd[i]) / step).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_identity_passes_the_gradient_through_and_a_dim_printer_scales_it() {
        let req = vec![0.2, 0.5, 0.8, 0.9, 0.1, 0.4];
        let g = vec![1.0, -2.0, 0.5, 0.3, 0.0, -1.0];
        let id = Response::identity();
        assert_eq!(forward(&id, &req).len(), 6);
        for (a, b) in backward(&id, &req, &g).iter().zip(&g) {
            assert!((a - b).abs() < 1e-2 * (1.0 + b.abs()), "{a} vs {b}");
        }
        // Half the light in every channel: the printed colour changes less than the request.
        let mut half = Response::identity();
        (0..3).for_each(|i| half.matrix[i][i] = 0.5);
        let gh = backward(&half, &req, &g);
        for (a, b) in gh.iter().zip(&g) {
            assert!(a.abs() < b.abs() || *b == 0.0, "{a} vs {b}");
        }
    }
}
