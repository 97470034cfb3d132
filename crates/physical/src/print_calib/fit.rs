//! The fits: the camera's correction from the ColorChecker, the printer's response from the
//! printed patches, and ΔE2000 summaries.
//!
//! **Camera.** Each channel is first linearised through the card's grey row: the six greys'
//! photographed and published linear values, joined piecewise linearly in log–log and extended
//! with the end segments' slopes, undo the camera's tone curve and white balance; a 3×3 matrix in
//! linear light, fitted by weighted least squares on all 24 patches, then undoes the channels'
//! crosstalk. (A 3×3 alone leaves the tone curve: for a camera that scales display values, as
//! the twin's shading does, under a warm lamp, a NumPy prototype of this fit gave 0.7 ΔE2000 on
//! fresh colours with the matrix alone against 0.06 with the grey row first.)
//!
//! **Printer.** The 3×6 root-polynomial of `cac_core::printer::Response`, fitted by least squares
//! in linear light with each patch weighted by `(Y + 0.01)^(-4/3)` (Y its printed luminance):
//! about the square of dL*/dY, so dark patches count as much as they are seen to. In a NumPy
//! prototype on a printer like `simulate::SimulatedPrinter`, this lowered the mean ΔE2000 on
//! fresh colours by 0.17 to 0.32 (192 to 24 patches) against unweighted least squares, and came
//! within 0.05 of minimising the error in CIELAB itself by Levenberg–Marquardt.

use super::chart::{CHECKER_GREYS, COLORCHECKER};
use super::linalg;
use anyhow::{bail, Result};
use cac_core::colour;
use cac_core::printer::Response;

/// Luminance of linear sRGB.
fn luminance(c: [f32; 3]) -> f64 {
    0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64
}

/// The weight of a patch of printed (or published) linear colour `c` in a fit.
fn weight(c: [f32; 3]) -> f64 {
    (luminance(c).max(0.0) + 0.01).powf(-4.0 / 3.0)
}

/// The camera's correction: per-channel tone curves from the grey row, then a 3×3 matrix.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraCorrection {
    /// Per channel, the greys' `(ln photographed, ln published)` linear values, ascending.
    curves: [Vec<[f64; 2]>; 3],
    /// Rows: corrected linear R, G, B from the linearised channels.
    matrix: [[f64; 3]; 3],
}

impl CameraCorrection {
    /// Fits the correction from the 24 ColorChecker patches as photographed (linear light, in
    /// the card's reading order).
    pub fn fit(photographed: &[[f32; 3]; 24]) -> Result<Self> {
        let published: Vec<[f32; 3]> = COLORCHECKER
            .iter()
            .map(|(_, hex)| colour::from_hex(hex).expect("valid").map(colour::decode))
            .collect();
        let curves: [Vec<[f64; 2]>; 3] = std::array::from_fn(|c| {
            let mut k: Vec<[f64; 2]> = CHECKER_GREYS
                .map(|i| {
                    [
                        (photographed[i][c] as f64).max(1e-5).ln(),
                        (published[i][c] as f64).max(1e-5).ln(),
                    ]
                })
                .collect();
            k.reverse(); // black to white
            k
        });
        for (c, k) in curves.iter().enumerate() {
            if k.windows(2).any(|w| w[1][0] - w[0][0] < 0.02) {
                bail!(
                    "the ColorChecker's grey row does not run from white to black in the photo (channel {}): is a ColorChecker Classic laid on the chart's 24 squares, the right way round and evenly lit?",
                    ["red", "green", "blue"][c]
                );
            }
        }
        let mut fit = CameraCorrection {
            curves,
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        };
        let rows: Vec<Vec<f64>> = photographed
            .iter()
            .map(|&p| fit.linearise(p).to_vec())
            .collect();
        let w: Vec<f64> = published.iter().map(|&c| weight(c)).collect();
        for o in 0..3 {
            let y: Vec<f64> = published.iter().map(|c| c[o] as f64).collect();
            let Some(m) = linalg::least_squares(&rows, &y, &w) else {
                bail!(
                    "the ColorChecker's colours in the photo do not determine a camera correction"
                );
            };
            fit.matrix[o] = [m[0], m[1], m[2]];
        }
        Ok(fit)
    }

    /// The per-channel tone curves alone.
    fn linearise(&self, lin: [f32; 3]) -> [f64; 3] {
        std::array::from_fn(|c| {
            let k = &self.curves[c];
            let x = (lin[c] as f64).max(1e-5).ln();
            let seg = k
                .windows(2)
                .position(|w| x <= w[1][0])
                .unwrap_or(k.len() - 2);
            let (a, b) = (k[seg], k[seg + 1]);
            (a[1] + (x - a[0]) * (b[1] - a[1]) / (b[0] - a[0])).exp()
        })
    }

    /// A photographed linear colour, corrected to what the card's reference would read.
    pub fn apply(&self, lin: [f32; 3]) -> [f32; 3] {
        let l = self.linearise(lin);
        self.matrix
            .map(|m| (m[0] * l[0] + m[1] * l[1] + m[2] * l[2]).max(0.0) as f32)
    }
}

/// Fits the printer's response from requested sRGB colours and their printed linear colours:
/// the 3×6 matrix by weighted least squares (see the module's note) for given tone curves, and
/// the per-channel exponents of the curves by coordinate descent on that fit's weighted residual
/// (steps of 0.1, then 0.02, within 0.4..2.5). `None` when the patches do not determine it.
pub fn fit_response(requested: &[[f32; 3]], printed: &[[f32; 3]]) -> Option<Response> {
    let mut gamma = [1.0f32; 3];
    let (mut best, mut matrix) = fit_matrix(requested, printed, gamma)?;
    for step in [0.1f32, 0.02] {
        loop {
            let mut moved = false;
            for c in 0..3 {
                for d in [-step, step] {
                    let mut g = gamma;
                    g[c] = (g[c] + d).clamp(0.4, 2.5);
                    if let Some((r, m)) = fit_matrix(requested, printed, g) {
                        if r < best * (1.0 - 1e-6) {
                            (best, matrix, gamma, moved) = (r, m, g, true);
                        }
                    }
                }
            }
            if !moved {
                break;
            }
        }
    }
    Some(Response {
        gamma,
        matrix,
        held_out_de2000: None,
    })
}

/// The weighted least-squares matrix for tone curves `gamma`, and its weighted residual.
fn fit_matrix(
    requested: &[[f32; 3]],
    printed: &[[f32; 3]],
    gamma: [f32; 3],
) -> Option<(f64, [[f32; 6]; 3])> {
    let rows: Vec<Vec<f64>> = requested
        .iter()
        .map(|&s| {
            Response::terms(s.map(colour::decode), gamma)
                .map(f64::from)
                .to_vec()
        })
        .collect();
    let w: Vec<f64> = printed.iter().map(|&c| weight(c)).collect();
    let mut m = [[0.0f32; 6]; 3];
    let mut residual = 0.0;
    for (o, row) in m.iter_mut().enumerate() {
        let y: Vec<f64> = printed.iter().map(|c| c[o] as f64).collect();
        let x = linalg::least_squares(&rows, &y, &w)?;
        for ((r, yi), wi) in rows.iter().zip(&y).zip(&w) {
            let p: f64 = r.iter().zip(&x).map(|(a, b)| a * b).sum();
            residual += wi * (p - yi).powi(2);
        }
        *row = std::array::from_fn(|k| x[k] as f32);
    }
    Some((residual, m))
}

/// Mean and 95th percentile (nearest rank) of some ΔE values; zeros for none.
pub fn mean_p95(v: &[f32]) -> [f32; 2] {
    if v.is_empty() {
        return [0.0; 2];
    }
    let mut s = v.to_vec();
    s.sort_by(f32::total_cmp);
    let rank = ((0.95 * s.len() as f32).ceil() as usize).clamp(1, s.len());
    [s.iter().sum::<f32>() / s.len() as f32, s[rank - 1]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_camera_correction_undoes_a_tone_curve_a_cast_and_crosstalk() {
        // A camera that scales display values (as the twin's shading does), tints them and
        // mixes its channels a little.
        let camera = |s: [f32; 3]| {
            let d = [0.8 * s[0], 0.76 * s[1], 0.68 * s[2]].map(colour::decode);
            [
                0.92 * d[0] + 0.08 * d[1],
                0.05 * d[0] + 0.9 * d[1] + 0.05 * d[2],
                0.07 * d[1] + 0.93 * d[2],
            ]
        };
        let card: Vec<[f32; 3]> = COLORCHECKER
            .iter()
            .map(|(_, h)| colour::from_hex(h).unwrap())
            .collect();
        let seen: [[f32; 3]; 24] = std::array::from_fn(|i| camera(card[i]));
        let fit = CameraCorrection::fit(&seen).unwrap();
        let mut de = vec![];
        for k in 0..200 {
            let s = [k % 7, (k / 7) % 7, (k / 49) % 5].map(|v| 0.05 + v as f32 * 0.14);
            let back = fit.apply(camera(s)).map(colour::encode);
            de.push(colour::delta_e2000_srgb(s, back));
        }
        let [mean, p95] = mean_p95(&de);
        assert!(mean < 0.5 && p95 < 1.2, "{mean} {p95}");
        let mut flipped = seen;
        flipped.swap(18, 23);
        assert!(format!("{:#}", CameraCorrection::fit(&flipped).unwrap_err()).contains("grey row"));
    }

    #[test]
    fn a_root_polynomial_printer_is_recovered_exactly() {
        let r = Response {
            gamma: [1.0; 3],
            matrix: MATRIX,
            held_out_de2000: None,
        };
        let (req, printed) = grid_prints(&r, 4);
        let m = fit_response(&req, &printed).unwrap();
        assert_eq!(m.gamma, [1.0; 3]);
        for (a, b) in m.matrix.iter().flatten().zip(MATRIX.iter().flatten()) {
            assert!((a - b).abs() < 1e-3, "{m:?}");
        }
    }

    #[test]
    fn a_printer_with_dot_gain_is_recovered_through_its_tone_curves() {
        let truth = Response {
            gamma: [1.3, 1.2, 1.4],
            matrix: MATRIX,
            held_out_de2000: None,
        };
        let (req, printed) = grid_prints(&truth, 5);
        let fit = fit_response(&req, &printed).unwrap();
        let de = |r: &Response| -> f32 {
            (0..200)
                .map(|k| {
                    let s = [k % 7, (k / 7) % 7, (k / 49) % 5].map(|v| 0.05 + v as f32 * 0.14);
                    colour::delta_e2000_srgb(r.apply(s), truth.apply(s))
                })
                .sum::<f32>()
                / 200.0
        };
        for (a, b) in fit.gamma.iter().zip(&truth.gamma) {
            assert!((a - b).abs() <= 0.021, "{:?}", fit.gamma);
        }
        assert!(de(&fit) < 0.3, "{}", de(&fit));
        // Without the curves the best matrix leaves a floor (the old model).
        let (_, m) = fit_matrix(&req, &printed, [1.0; 3]).unwrap();
        let old = Response {
            gamma: [1.0; 3],
            matrix: m,
            held_out_de2000: None,
        };
        assert!(de(&old) > 3.0 * de(&fit), "{} vs {}", de(&old), de(&fit));
    }

    /// A printer's response matrix with some crosstalk between the channels.
    const MATRIX: [[f32; 6]; 3] = [
        [0.85, 0.05, 0.02, 0.03, 0.0, 0.02],
        [0.04, 0.8, 0.06, 0.02, 0.03, 0.0],
        [0.01, 0.07, 0.78, 0.0, 0.04, 0.03],
    ];

    /// A `steps`³ grid of requested colours and what `printer` prints of them (linear light).
    fn grid_prints(printer: &Response, steps: usize) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
        let n = steps * steps * steps;
        let req: Vec<[f32; 3]> = (0..n)
            .map(|k| [k % steps, (k / steps) % steps, k / (steps * steps)])
            .map(|i| i.map(|v| v as f32 / (steps - 1) as f32))
            .collect();
        let printed = req
            .iter()
            .map(|&s| printer.apply(s).map(colour::decode))
            .collect();
        (req, printed)
    }

    #[test]
    fn the_95th_percentile_is_by_nearest_rank() {
        let v: Vec<f32> = (1..=20).map(|k| k as f32).collect();
        assert_eq!(mean_p95(&v), [10.5, 19.0]);
        assert_eq!(mean_p95(&[]), [0.0, 0.0]);
    }
}
