//! The little linear algebra calibration needs: a dense solve, least squares by the normal
//! equations, and the plane homography of four point pairs.

/// Solves `a · x = b` (`a` is n×n, row-major) by Gaussian elimination with partial pivoting;
/// `None` when `a` is singular.
pub(crate) fn solve(mut a: Vec<f64>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    debug_assert_eq!(a.len(), n * n);
    let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    for col in 0..n {
        let piv =
            (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if a[piv * n + col].abs() <= 1e-13 * scale {
            return None;
        }
        if piv != col {
            for k in 0..n {
                a.swap(piv * n + k, col * n + k);
            }
            b.swap(piv, col);
        }
        for r in col + 1..n {
            let f = a[r * n + col] / a[col * n + col];
            if f != 0.0 {
                for k in col..n {
                    a[r * n + k] -= f * a[col * n + k];
                }
                b[r] -= f * b[col];
            }
        }
    }
    let mut x = vec![0.0; n];
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|k| a[r * n + k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r * n + r];
    }
    Some(x)
}

/// Weighted least squares: the `x` minimising `Σ w_i (rows_i · x − y_i)²`, by the normal
/// equations (a tiny ridge keeps a rank-deficient design solvable).
pub(crate) fn least_squares(rows: &[Vec<f64>], y: &[f64], w: &[f64]) -> Option<Vec<f64>> {
    let n = rows.first()?.len();
    let mut ata = vec![0.0; n * n];
    let mut aty = vec![0.0; n];
    for ((r, &yi), &wi) in rows.iter().zip(y).zip(w) {
        for i in 0..n {
            aty[i] += wi * r[i] * yi;
            for j in 0..n {
                ata[i * n + j] += wi * r[i] * r[j];
            }
        }
    }
    let trace: f64 = (0..n).map(|i| ata[i * n + i]).sum();
    for i in 0..n {
        ata[i * n + i] += 1e-10 * trace / n as f64;
    }
    solve(ata, aty)
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
