//! The dense-proposals objective: fix the top-n proposals after NMS (no gradient through the
//! selection), then score the class prediction in every one of them.
//!
//! The two detectors here classify with independent per-class sigmoids, not a softmax, so the
//! paper's "targeted cross-entropy" becomes the binary cross-entropy of every class against the
//! one-hot target: raise the target class and suppress all others, in every fixed proposal,
//!
//! `L = 1/|P| Σ_{i∈P} Σ_c [ softplus(z_ic) − y_c · z_ic ]`,  `y = onehot(target)`,
//!
//! which is `−log σ(z_it) − Σ_{c≠t} log(1 − σ(z_ic))` per proposal. The non-targeted "hide" mode
//! uses `y = 0` (suppress every class). `softplus(x) = max(x, 0) + log1p(exp(−|x|))` never
//! overflows, so logits of ±1e4 give finite losses and gradients.

use crate::detect::{nms, Candidates};
use anyhow::{bail, Result};
use burn::tensor::{Int, Tensor, TensorData};

/// What the loss pushes towards.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Goal {
    /// Every fixed proposal classified as this COCO-80 class.
    Targeted(usize),
    /// Every class suppressed in every fixed proposal.
    Hide,
}

/// Per image, the indices of the fixed proposals: candidates ranked by their best class score,
/// class-agnostic NMS at `iou`, the top `n` kept. Read from host copies: no gradient flows
/// through the selection.
pub fn select_proposals(c: &Candidates, n: usize, iou: f64) -> Result<Vec<Vec<usize>>> {
    let [b, num, classes] = c.scores.dims();
    let scores = host(&c.scores)?;
    let boxes = host(&c.boxes)?;
    let mut out = Vec::with_capacity(b);
    for k in 0..b {
        let best: Vec<f32> = (0..num)
            .map(|i| {
                scores[(k * num + i) * classes..(k * num + i + 1) * classes]
                    .iter()
                    .copied()
                    .fold(f32::MIN, f32::max)
            })
            .collect();
        // tfjs NMS takes [y1, x1, y2, x2].
        let bx: Vec<[f32; 4]> = (0..num)
            .map(|i| {
                let q = &boxes[(k * num + i) * 4..(k * num + i + 1) * 4];
                [q[1], q[0], q[3], q[2]]
            })
            .collect();
        out.push(nms::non_max_suppression(
            &bx,
            &best,
            n,
            iou,
            f64::NEG_INFINITY,
        ));
    }
    Ok(out)
}

fn host<const D: usize>(t: &Tensor<D>) -> Result<Vec<f32>> {
    t.to_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("cannot read tensor: {e:?}"))
}

/// Numerically stable softplus.
pub fn softplus<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    x.clone().clamp_min(0.0) + x.abs().neg().exp().log1p()
}

/// The dense-proposals loss over the fixed proposals `sel` of `logits` (`[B, N, C]`).
pub fn proposals_loss(logits: Tensor<3>, sel: &[Vec<usize>], goal: Goal) -> Result<Tensor<1>> {
    let [b, n, classes] = logits.dims();
    if sel.len() != b {
        bail!("{} proposal sets for {b} images", sel.len());
    }
    let rows: Vec<i64> = sel
        .iter()
        .enumerate()
        .flat_map(|(k, s)| s.iter().map(move |&i| (k * n + i) as i64))
        .collect();
    let device = logits.device();
    if rows.is_empty() {
        // No proposal at all: a zero loss that still depends on the logits (zero gradient).
        return Ok(logits.sum() * 0.0);
    }
    let m = rows.len();
    let idx = Tensor::<1, Int>::from_data(TensorData::new(rows, [m]), &device);
    let z = logits.reshape([b * n, classes]).select(0, idx);
    let mut loss = softplus(z.clone());
    if let Goal::Targeted(t) = goal {
        if t >= classes {
            bail!("target class {t} is out of range for {classes} classes");
        }
        let zt = z.slice([0..m, t..t + 1]);
        loss = loss.sum_dim(1) - zt;
        return Ok(loss.sum() / m as f64);
    }
    Ok(loss.sum() / m as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dev() -> burn::tensor::Device {
        burn::tensor::Device::autodiff(burn::tensor::Device::from(burn::backend::FlexDevice))
    }

    #[test]
    fn loss_matches_the_formula_and_stays_finite_for_huge_logits() {
        let d = dev();
        let z = vec![2.0f32, -1.0, 0.5, 1e4, -1e4, 3.0];
        let t = Tensor::<3>::from_data(TensorData::new(z.clone(), [1, 2, 3]), &d).require_grad();
        let l = proposals_loss(t.clone(), &[vec![0, 1]], Goal::Targeted(1)).unwrap();
        let sp = |x: f64| x.max(0.0) + (-x.abs()).exp().ln_1p();
        let want = ((sp(2.0) + sp(-1.0) + sp(0.5) - (-1.0))
            + (sp(1e4) + sp(-1e4) + sp(3.0) - (-1e4)))
            / 2.0;
        let got = l
            .clone()
            .into_data()
            .convert::<f64>()
            .try_to_vec::<f64>()
            .unwrap()[0];
        assert!((got - want).abs() / want < 1e-5, "{got} vs {want}");
        let g = t
            .grad(&l.backward())
            .unwrap()
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .unwrap();
        assert!(g.iter().all(|v| v.is_finite()));
        // d/dz of the target's term is σ(z) − 1 (< 0: raising z lowers the loss); others σ(z) > 0.
        assert!(g[1] < 0.0 && g[0] > 0.0 && g[2] > 0.0, "{g:?}");
    }

    #[test]
    fn empty_proposal_sets_give_a_zero_loss() {
        let d = dev();
        let t =
            Tensor::<3>::from_data(TensorData::new(vec![1.0f32; 6], [2, 1, 3]), &d).require_grad();
        let l = proposals_loss(t.clone(), &[vec![], vec![]], Goal::Hide).unwrap();
        assert_eq!(
            l.clone()
                .into_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .unwrap()[0],
            0.0
        );
        assert!(t.grad(&l.backward()).is_some());
    }
}
