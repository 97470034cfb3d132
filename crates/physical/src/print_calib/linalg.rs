//! The little linear algebra calibration needs, on `nalgebra` (a maintained dense linear algebra
//! crate; chosen over hand-written elimination for its pivoted LU and Householder QR): a dense
//! solve, weighted least squares, and the plane homography of four point pairs.

use nalgebra::{DMatrix, DVector};

/// Solves `a · x = b` (`a` is n×n, row-major) by LU with partial pivoting; `None` when `a` is
/// singular (a pivot below 1e-13 of its largest entry).
pub(crate) fn solve(a: Vec<f64>, b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    debug_assert_eq!(a.len(), n * n);
    let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    let lu = DMatrix::from_row_slice(n, n, &a).lu();
    let u = lu.u();
    if (0..n).any(|i| u[(i, i)].abs() <= 1e-13 * scale) {
        return None;
    }
    lu.solve(&DVector::from_vec(b))
        .map(|x| x.as_slice().to_vec())
}

/// Weighted least squares: the `x` minimising `Σ w_i (rows_i · x − y_i)²`, by Householder QR of
/// the weighted design (not the normal equations, whose condition number is the square); `None`
/// when the design is rank-deficient.
pub(crate) fn least_squares(rows: &[Vec<f64>], y: &[f64], w: &[f64]) -> Option<Vec<f64>> {
    let n = rows.first()?.len();
    let m = rows.len();
    if m < n {
        return None;
    }
    let sw: Vec<f64> = w.iter().map(|v| v.max(0.0).sqrt()).collect();
    let a = DMatrix::from_fn(m, n, |i, j| rows[i][j] * sw[i]);
    let b = DVector::from_fn(m, |i, _| y[i] * sw[i]);
    let scale = a.iter().fold(0.0f64, |s, v| s.max(v.abs())).max(1e-300);
    let qr = a.qr();
    let r = qr.r();
    if (0..n).any(|i| r[(i, i)].abs() <= 1e-12 * scale) {
        return None;
    }
    let qtb = qr.q().transpose() * b;
    let x = r.solve_upper_triangular(&qtb)?;
    Some(x.as_slice().to_vec())
}

/// The homography `H` (row-major, `h[8] = 1`) with `H · [from, 1] ∝ [to, 1]` for four pairs.
pub(crate) fn homography(from: &[[f64; 2]; 4], to: &[[f64; 2]; 4]) -> Option<[f64; 9]> {
    let mut a = Vec::with_capacity(64);
    let mut b = Vec::with_capacity(8);
    for (&[x, y], &[u, v]) in from.iter().zip(to) {
        a.extend_from_slice(&[x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y]);
        b.push(u);
        a.extend_from_slice(&[0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y]);
        b.push(v);
    }
    let h = solve(a, b)?;
    Some([h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0])
}

/// `H · [p, 1]`, dehomogenised.
pub(crate) fn apply(h: &[f64; 9], p: [f64; 2]) -> [f64; 2] {
    let w = h[6] * p[0] + h[7] * p[1] + h[8];
    [
        (h[0] * p[0] + h[1] * p[1] + h[2]) / w,
        (h[3] * p[0] + h[4] * p[1] + h[5]) / w,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_homography_maps_its_four_points_and_the_lines_between_them() {
        let from = [[0.0, 0.0], [297.0, 0.0], [297.0, 210.0], [0.0, 210.0]];
        let to = [[101.5, 80.2], [530.0, 60.0], [560.3, 420.0], [90.0, 380.7]];
        let h = homography(&from, &to).unwrap();
        for (f, t) in from.iter().zip(&to) {
            let p = apply(&h, *f);
            assert!((p[0] - t[0]).abs() < 1e-8 && (p[1] - t[1]).abs() < 1e-8);
        }
        // The page's centre lands where the diagonals cross.
        let c = apply(&h, [148.5, 105.0]);
        let cross = |a: [f64; 2], b: [f64; 2], p: [f64; 2]| {
            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
        };
        assert!(cross(to[0], to[2], c).abs() < 1e-6 && cross(to[1], to[3], c).abs() < 1e-6);
    }

    #[test]
    fn least_squares_recovers_a_linear_map_and_solve_refuses_a_singular_one() {
        let rows: Vec<Vec<f64>> = (0..20)
            .map(|i| vec![1.0, i as f64, (i * i % 7) as f64])
            .collect();
        let y: Vec<f64> = rows.iter().map(|r| 2.0 - 0.5 * r[1] + 3.0 * r[2]).collect();
        let x = least_squares(&rows, &y, &[1.0; 20]).unwrap();
        assert!(
            (x[0] - 2.0).abs() < 1e-6 && (x[1] + 0.5).abs() < 1e-6 && (x[2] - 3.0).abs() < 1e-6
        );
        assert!(solve(vec![1.0, 2.0, 2.0, 4.0], vec![1.0, 2.0]).is_none());
    }
}
