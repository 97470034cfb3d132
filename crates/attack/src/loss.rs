//! The dense-proposals objective: fix a set of proposals (no gradient through the selection),
//! then score the class prediction in every one of them.
//!
//! **Which proposals** ([`ProposalRule`]). The paper fixes Faster R-CNN's top-n RPN proposals
//! after NMS; those sit on objects. A one-stage detector's top-n over the whole image do not:
//! most are small or off the object, and asking every one of them to be the target teaches the
//! texture to paint a crowd of little targets instead of turning the object into one. cac's
//! default ([`ProposalRule::Overlap`]) is the one-stage counterpart of the paper's proposals: per
//! image, every candidate whose box overlaps the object's ground-truth box (from the renderer)
//! with IoU ≥ `overlap_iou` (0.5, the protocol's own threshold), the `n` best by class score when
//! more; where none reaches it, the single best-overlapping candidate. [`ProposalRule::TopN`] is
//! the literal rule (top-n after class-agnostic NMS over the whole image), kept for the ablation
//! and for the baselines that attack proposals (ShapeShifter, UPC).
//!
//! **The loss.** The detectors here classify with independent per-class sigmoids, not a softmax,
//! so the paper's "targeted cross-entropy" becomes the binary cross-entropy of every class
//! against the one-hot target: raise the target class and suppress all others, in every fixed
//! proposal,
//!
//! `ℓ_i = Σ_c [ softplus(z_ic) − y_c · z_ic ]`,  `y = onehot(target)`,
//!
//! which is `−log σ(z_it) − Σ_{c≠t} log(1 − σ(z_ic))`. The non-targeted "hide" mode uses `y = 0`
//! over a set `H` of classes (every class, or the object's true classes): `ℓ_i = Σ_{c∈H} softplus(z_ic)`. Under `TopN` the loss is the mean of `ℓ_i` over all fixed proposals of
//! the batch; under `Overlap` it is the mean over images of each image's mean (images with the
//! object far away, and so few overlapping candidates, weigh as much as close ones):
//!
//! `L = 1/|B'| Σ_{b∈B'} 1/|P_b| Σ_{i∈P_b} ℓ_i`, `B'` the images with at least one proposal.
//!
//! `softplus(x) = max(x, 0) + log1p(exp(−|x|))` never overflows, so logits of ±1e4 give finite
//! losses and gradients.
//!
//! **The logit target** ([`Goal::TargetedLogit`], `cac train --target-loss logit`). The BCE's
//! target term `softplus(−z_it)` stops pulling once the source model is sure (its gradient is
//! `σ(z_it) − 1`): a texture the white-box model already reads as the target is not pushed
//! further. Zhao et al. (NeurIPS 2021, "On success and simplicity: a second look at
//! transferable targeted attacks") found that the plain target logit, which never saturates,
//! transfers a targeted attack to other models far better given enough iterations. Here the
//! target term becomes `−z_it`; the other classes keep their `softplus(z_ic)` (the vehicle must
//! still be suppressed, and a per-class sigmoid does not lower one class by raising another):
//!
//! `ℓ_i = Σ_{c≠t} softplus(z_ic) − z_it`.
//!
//! It is unbounded below, so it has no power mean over images (the power mean needs
//! non-negative image losses).

use anyhow::{bail, Result};
use burn::tensor::{Int, Tensor, TensorData};
use cac_detect::{nms, Candidates};

/// What the loss pushes towards.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Goal {
    /// Every fixed proposal classified as this COCO-80 class.
    Targeted(usize),
    /// As [`Goal::Targeted`], with the target's term the plain logit `−z_it` (module docs).
    TargetedLogit(usize),
    /// The classes of the set suppressed in every fixed proposal.
    Hide(ClassSet),
}

/// A set of COCO-80 class ids (bit `c` set: class `c` is in the set).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ClassSet(pub u128);

impl ClassSet {
    /// Every class.
    pub const ALL: ClassSet = ClassSet(u128::MAX);

    pub fn of(ids: &[usize]) -> ClassSet {
        ClassSet(
            ids.iter()
                .filter(|&&c| c < 128)
                .fold(0, |m, &c| m | 1u128 << c),
        )
    }

    pub fn contains(self, c: usize) -> bool {
        c < 128 && (self.0 >> c) & 1 == 1
    }

    /// `[1, classes]` of 1 where the class is in the set, 0 elsewhere; `None` when every one of
    /// the `classes` is in it (no mask needed).
    fn mask(self, classes: usize, device: &burn::tensor::Device) -> Option<Tensor<2>> {
        if (0..classes).all(|c| self.contains(c)) {
            return None;
        }
        let m: Vec<f32> = (0..classes)
            .map(|c| if self.contains(c) { 1.0 } else { 0.0 })
            .collect();
        Some(Tensor::<2>::from_data(
            TensorData::new(m, [1, classes]),
            device,
        ))
    }
}

/// `Σ_c softplus(z_ic)` over the classes the goal scores (`[m, 1]`), minus `z_it` when targeted
/// (with the logit target, the target's own `softplus(z_it)` left out).
fn per_proposal(z: Tensor<2>, goal: Goal) -> Result<Tensor<2>> {
    let [m, classes] = z.dims();
    let sp = softplus(z.clone());
    match goal {
        Goal::Targeted(t) | Goal::TargetedLogit(t) => {
            if t >= classes {
                bail!("target class {t} is out of range for {classes} classes");
            }
            let device = z.device();
            let zt = z.slice([0..m, t..t + 1]);
            Ok(match goal {
                Goal::TargetedLogit(_) => {
                    // The other classes by a 0/1 weight, not by subtracting the target's softplus
                    // from the sum: at a huge z_it that difference loses them to rounding.
                    let w: Vec<f32> = (0..classes).map(|c| f32::from(c != t)).collect();
                    let w = Tensor::<2>::from_data(
                        TensorData::new(w, [1, classes]),
                        (&device, sp.dtype()),
                    );
                    (sp * w).sum_dim(1) - zt
                }
                _ => sp.sum_dim(1) - zt,
            })
        }
        Goal::Hide(set) => Ok(match set.mask(classes, &z.device()) {
            Some(w) => (sp * w).sum_dim(1),
            None => sp.sum_dim(1),
        }),
    }
}

/// The target class's term in a targeted proposal's loss (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TargetLoss {
    /// `softplus(−z_it)`: the binary cross-entropy, the paper's targeted loss.
    #[default]
    Bce,
    /// `−z_it`: the plain target logit, which does not saturate ([`Goal::TargetedLogit`]).
    Logit,
}

/// Which candidates the loss fixes as proposals (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProposalRule {
    /// Candidates whose box overlaps the object's box (IoU ≥ the threshold), top n of them.
    #[default]
    Overlap,
    /// Top n after class-agnostic NMS over the whole image (the paper's literal rule).
    #[serde(rename = "topn")]
    TopN,
}

cac_core::choices!(TargetLoss {
    Bce => "bce": "`softplus(−z_it)`: the binary cross-entropy, the paper's targeted loss",
    Logit => "logit": "`−z_it`: the plain target logit, which does not saturate ([`Goal::TargetedLogit`])",
});

cac_core::choices!(ProposalRule {
    Overlap => "overlap": "Candidates whose box overlaps the object's box (IoU ≥ the threshold), top n of them",
    TopN => "topn": "Top n after class-agnostic NMS over the whole image (the paper's literal rule)",
});

/// IoU of two `x1, y1, x2, y2` boxes (0 for empty ones).
pub fn iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let area = |q: &[f32; 4]| (q[2] - q[0]).max(0.0) * (q[3] - q[1]).max(0.0);
    let union = area(a) + area(b) - inter;
    if union > 0.0 && union.is_finite() {
        inter / union
    } else {
        0.0
    }
}

/// Per image, the candidates overlapping its object's box: IoU ≥ `min_iou`, the `n` with the
/// highest best-class score among them; where none reaches `min_iou`, the one with the highest
/// IoU (if any overlaps at all). An image without an object (`None`) gets none. Read from host
/// copies: no gradient flows through the selection.
pub fn select_overlapping(
    c: &Candidates,
    objects: &[Option<[f32; 4]>],
    n: usize,
    min_iou: f64,
) -> Result<Vec<Vec<usize>>> {
    let [b, num, classes] = c.scores.dims();
    if objects.len() != b {
        bail!("{} object boxes for {b} images", objects.len());
    }
    let scores = host(&c.scores)?;
    let boxes = host(&c.boxes)?;
    let mut out = Vec::with_capacity(b);
    for (k, obj) in objects.iter().enumerate() {
        let Some(obj) = obj else {
            out.push(vec![]);
            continue;
        };
        let overlaps: Vec<(usize, f32)> = (0..num)
            .map(|i| {
                let q = &boxes[(k * num + i) * 4..(k * num + i + 1) * 4];
                let o = iou(&[q[0], q[1], q[2], q[3]], obj);
                (i, if o.is_finite() { o } else { 0.0 })
            })
            .collect();
        let mut sel: Vec<usize> = overlaps
            .iter()
            .filter(|(_, o)| *o as f64 >= min_iou)
            .map(|(i, _)| *i)
            .collect();
        if sel.is_empty() {
            let best =
                overlaps
                    .iter()
                    .copied()
                    .fold((usize::MAX, 0.0f32), |a, x| if x.1 > a.1 { x } else { a });
            if best.0 != usize::MAX {
                sel.push(best.0);
            }
        }
        if sel.len() > n {
            let best = |i: usize| {
                scores[(k * num + i) * classes..(k * num + i + 1) * classes]
                    .iter()
                    .copied()
                    .filter(|v| v.is_finite())
                    .fold(f32::MIN, f32::max)
            };
            sel.sort_by(|&x, &y| best(y).total_cmp(&best(x)).then(x.cmp(&y)));
            sel.truncate(n);
            sel.sort_unstable();
        }
        out.push(sel);
    }
    Ok(out)
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

/// Row `k·N + i` of a `[B·N, ·]` view of per-candidate tensors for proposal `i` of image `k`, in
/// the order of `sel`, as an index tensor; `None` when `sel` holds no proposal.
pub(crate) fn proposal_rows(
    sel: &[Vec<usize>],
    n: usize,
    device: &burn::tensor::Device,
) -> Option<Tensor<1, Int>> {
    let rows: Vec<i64> = sel
        .iter()
        .enumerate()
        .flat_map(|(k, s)| s.iter().map(move |&i| (k * n + i) as i64))
        .collect();
    let m = rows.len();
    (m > 0).then(|| Tensor::<1, Int>::from_data(TensorData::new(rows, [m]), device))
}

/// The fixed proposals' logits (`[m, C]`, in the order of `sel`) out of `logits` (`[B, N, C]`);
/// `None` when `sel` holds none.
fn gather(logits: &Tensor<3>, sel: &[Vec<usize>]) -> Result<Option<Tensor<2>>> {
    let [b, n, classes] = logits.dims();
    if sel.len() != b {
        bail!("{} proposal sets for {b} images", sel.len());
    }
    Ok(proposal_rows(sel, n, &logits.device())
        .map(|idx| logits.clone().reshape([b * n, classes]).select(0, idx)))
}

/// The dense-proposals loss over the fixed proposals `sel` of `logits` (`[B, N, C]`).
pub fn proposals_loss(logits: Tensor<3>, sel: &[Vec<usize>], goal: Goal) -> Result<Tensor<1>> {
    let Some(z) = gather(&logits, sel)? else {
        // No proposal at all: a zero loss that still depends on the logits (zero gradient).
        return Ok(logits.sum() * 0.0);
    };
    let m = z.dims()[0];
    Ok(per_proposal(z, goal)?.sum() / m as f64)
}

/// The per-image-mean loss of [`ProposalRule::Overlap`]: each image's proposals averaged, then
/// the images that have any (module docs). Empty everywhere: a zero loss (zero gradient).
/// `power` p ≠ 1 takes the images' power mean `(1/|B'| Σ_b L_b^p)^(1/p)` instead of their mean:
/// p > 1 weighs each image's gradient by `(L_b / L)^(p−1)`, so the views the texture fails on
/// most (far, dark) pull harder; p = 1 is the plain mean.
pub fn proposals_loss_per_image(
    logits: Tensor<3>,
    sel: &[Vec<usize>],
    goal: Goal,
    power: f32,
) -> Result<Tensor<1>> {
    if !(power.is_finite() && power >= 1.0) {
        bail!("the images' power mean needs a finite power >= 1, got {power}");
    }
    if power != 1.0 && matches!(goal, Goal::TargetedLogit(_)) {
        bail!(
            "the logit target is unbounded below: it has no power mean over images (power {power})"
        );
    }
    let Some(z) = gather(&logits, sel)? else {
        return Ok(logits.sum() * 0.0);
    };
    let per = per_proposal(z, goal)?; // [m, 1], positive but for the logit target
    let (m, device) = (per.dims()[0], logits.device());
    let images: Vec<&Vec<usize>> = sel.iter().filter(|s| !s.is_empty()).collect();
    if power == 1.0 {
        let weights: Vec<f32> = images
            .iter()
            .flat_map(|s| std::iter::repeat_n(1.0 / (s.len() * images.len()) as f32, s.len()))
            .collect();
        let w = Tensor::<2>::from_data(TensorData::new(weights, [m, 1]), (&device, per.dtype()));
        return Ok((per * w).sum());
    }
    // The per-image means L_b as a [B', m] selection-weight matrix times the per-proposal losses.
    let mut w = vec![0f32; images.len() * m];
    let mut col = 0;
    for (r, s) in images.iter().enumerate() {
        for _ in s.iter() {
            w[r * m + col] = 1.0 / s.len() as f32;
            col += 1;
        }
    }
    let w = Tensor::<2>::from_data(
        TensorData::new(w, [images.len(), m]),
        (&device, per.dtype()),
    );
    let l_b = w.matmul(per); // [B', 1]
                             // Scaled by the largest L_b (a constant: the power mean is homogeneous of degree 1, so value
                             // and gradient are unchanged) so that L_b^p cannot overflow for large losses and powers.
    let top = host(&l_b)?.into_iter().fold(0f32, f32::max);
    if !top.is_finite() {
        bail!("a per-image loss is not finite ({top})");
    }
    if top == 0.0 {
        return Ok(l_b.sum() * 0.0); // every image won outright: zero loss, zero gradient
    }
    let mean = (l_b / top as f64).powf_scalar(power).mean();
    Ok(mean.powf_scalar(1.0 / power) * top as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Softplus in f64, the formula's reference.
    fn sp(x: f64) -> f64 {
        x.max(0.0) + (-x.abs()).exp().ln_1p()
    }

    fn scalar(l: &Tensor<1>) -> f64 {
        l.clone()
            .into_data()
            .convert::<f64>()
            .try_to_vec::<f64>()
            .unwrap()[0]
    }

    /// d`l`/d`t`, read back.
    fn grad(t: &Tensor<3>, l: Tensor<1>) -> Vec<f32> {
        let g = t.grad(&l.backward()).unwrap();
        g.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
    }

    fn dev() -> burn::tensor::Device {
        burn::tensor::Device::autodiff(burn::tensor::Device::from(burn::backend::FlexDevice))
    }

    #[test]
    fn loss_matches_the_formula_and_stays_finite_for_huge_logits() {
        let d = dev();
        let z = vec![2.0f32, -1.0, 0.5, 1e4, -1e4, 3.0];
        let t = Tensor::<3>::from_data(TensorData::new(z.clone(), [1, 2, 3]), &d).require_grad();
        let l = proposals_loss(t.clone(), &[vec![0, 1]], Goal::Targeted(1)).unwrap();
        let want = ((sp(2.0) + sp(-1.0) + sp(0.5) - (-1.0))
            + (sp(1e4) + sp(-1e4) + sp(3.0) - (-1e4)))
            / 2.0;
        let got = scalar(&l);
        assert!((got - want).abs() / want < 1e-5, "{got} vs {want}");
        let g = grad(&t, l);
        assert!(g.iter().all(|v| v.is_finite()));
        // d/dz of the target's term is σ(z) − 1 (< 0: raising z lowers the loss); others σ(z) > 0.
        assert!(g[1] < 0.0 && g[0] > 0.0 && g[2] > 0.0, "{g:?}");
    }

    #[test]
    fn the_logit_target_keeps_pulling_where_the_bce_has_stopped() {
        let d = dev();
        // Two proposals: the target (class 1) already sure in the second (z = 40, σ = 1 - 4e-18).
        let z = vec![2.0f32, -1.0, 0.5, -3.0, 40.0, 1e4];
        let t = Tensor::<3>::from_data(TensorData::new(z.clone(), [1, 2, 3]), &d).require_grad();
        let l = proposals_loss(t.clone(), &[vec![0, 1]], Goal::TargetedLogit(1)).unwrap();
        let want = ((sp(2.0) + sp(0.5) - (-1.0)) + (sp(-3.0) + sp(1e4) - 40.0)) / 2.0;
        let got = scalar(&l);
        assert!((got - want).abs() / want.abs() < 1e-5, "{got} vs {want}");
        let g = grad(&t, l);
        assert!(g.iter().all(|v| v.is_finite()), "{g:?}");
        // d/dz_t = −1/m in every proposal, however sure the model is; the others as the BCE's.
        assert!(
            (g[1] + 0.5).abs() < 1e-6 && (g[4] + 0.5).abs() < 1e-6,
            "{g:?}"
        );
        assert!(
            (g[5] - 0.5).abs() < 1e-6 && g[0] > 0.0 && g[3] > 0.0,
            "{g:?}"
        );
        let gb = grad(
            &t,
            proposals_loss(t.clone(), &[vec![0, 1]], Goal::Targeted(1)).unwrap(),
        );
        assert!(gb[4].abs() < 1e-12 && gb[1] < -0.1, "{gb:?}");
        for (k, (a, b)) in g.iter().zip(&gb).enumerate() {
            if k != 1 && k != 4 {
                assert!((a - b).abs() < 1e-6, "class term {k}: {a} vs {b}");
            }
        }
        // A target logit of 1e4: the formula's value, to f32's resolution there.
        let huge = Tensor::<3>::from_data(TensorData::new(vec![-3.0f32, 1e4, -3.0], [1, 1, 3]), &d);
        let got = scalar(&proposals_loss(huge, &[vec![0]], Goal::TargetedLogit(1)).unwrap());
        let want = 2.0 * sp(-3.0) - 1e4;
        assert!((got - want).abs() < 1e-3, "{got} vs {want}");
        // Negative losses are allowed (the target's logit is unbounded); the power mean is not.
        let sure =
            Tensor::<3>::from_data(TensorData::new(vec![-9.0f32, 30.0, -9.0], [1, 1, 3]), &d);
        assert!(
            scalar(
                &proposals_loss_per_image(sure.clone(), &[vec![0]], Goal::TargetedLogit(1), 1.0)
                    .unwrap()
            ) < -29.0
        );
        let e =
            proposals_loss_per_image(sure, &[vec![0]], Goal::TargetedLogit(1), 2.0).unwrap_err();
        assert!(e.to_string().contains("no power mean"), "{e}");
    }

    #[test]
    fn hide_over_a_class_set_scores_only_those_classes() {
        let d = dev();
        let z = vec![2.0f32, -1.0, 0.5, 3.0, 1e4, -2.0];
        let t = Tensor::<3>::from_data(TensorData::new(z.clone(), [1, 2, 3]), &d).require_grad();
        let set = ClassSet::of(&[0, 2]);
        assert!(set.contains(0) && !set.contains(1) && set.contains(2) && !set.contains(200));
        let l = proposals_loss(t.clone(), &[vec![0, 1]], Goal::Hide(set)).unwrap();
        let want = (sp(2.0) + sp(0.5) + sp(3.0) + sp(-2.0)) / 2.0;
        let got = scalar(&l);
        assert!((got - want).abs() / want < 1e-5, "{got} vs {want}");
        let g = grad(&t, l);
        // Class 1 is outside the set: no gradient, even at a logit of 1e4.
        assert_eq!((g[1], g[4]), (0.0, 0.0), "{g:?}");
        assert!(
            g[0] > 0.0 && g[2] > 0.0 && g[3] > 0.0 && g[5] > 0.0,
            "{g:?}"
        );
        // Every class: the plain sum, which does see class 1.
        let all = proposals_loss(t.clone(), &[vec![0, 1]], Goal::Hide(ClassSet::ALL)).unwrap();
        let all = all
            .into_data()
            .convert::<f64>()
            .try_to_vec::<f64>()
            .unwrap()[0];
        assert!((all - (want + (sp(-1.0) + sp(1e4)) / 2.0)).abs() / all < 1e-5);
    }

    #[test]
    fn overlap_rule_keeps_the_candidates_on_the_object() {
        let d = dev();
        // Four candidates: on the object, mostly on it, off it, a huge box around everything.
        let boxes = vec![
            10.0f32, 10.0, 50.0, 50.0, 10.0, 10.0, 40.0, 50.0, 60.0, 60.0, 90.0, 90.0, 0.0, 0.0,
            100.0, 100.0,
        ];
        let scores = vec![0.1f32, 0.9, 0.2, 0.8, 0.7, 0.3, 0.05, 0.01];
        let c = Candidates {
            boxes: Tensor::<3>::from_data(TensorData::new(boxes, [1, 4, 4]), &d),
            scores: Tensor::<3>::from_data(TensorData::new(scores.clone(), [1, 4, 2]), &d),
            logits: Tensor::<3>::from_data(TensorData::new(scores, [1, 4, 2]), &d),
        };
        let obj = [Some([12.0f32, 10.0, 50.0, 48.0])];
        assert_eq!(
            select_overlapping(&c, &obj, 10, 0.5).unwrap(),
            vec![vec![0, 1]]
        );
        // Capped at n by best class score: candidate 0 (0.9) beats 1 (0.8).
        assert_eq!(select_overlapping(&c, &obj, 1, 0.5).unwrap(), vec![vec![0]]);
        // Nothing at IoU >= 0.99: the best-overlapping one alone.
        assert_eq!(
            select_overlapping(&c, &obj, 10, 0.99).unwrap(),
            vec![vec![0]]
        );
        // No object in view: no proposals; a wrong count of boxes is an error.
        assert_eq!(
            select_overlapping(&c, &[None], 10, 0.5).unwrap(),
            vec![Vec::<usize>::new()]
        );
        assert!(select_overlapping(&c, &[], 10, 0.5).is_err());
        assert_eq!(iou(&[0.0, 0.0, 0.0, 0.0], &[0.0, 0.0, 0.0, 0.0]), 0.0);
    }

    #[test]
    fn per_image_loss_weighs_images_equally() {
        let d = dev();
        let z = vec![2.0f32, -1.0, 0.5, 8.0, -1e4, 3.0, -2.0, 1.0];
        let t = Tensor::<3>::from_data(TensorData::new(z, [2, 2, 2]), &d).require_grad();
        let l = |a: f64, b: f64| sp(a) + sp(b) - b;
        // Target class 1. Image 0 has two proposals, image 1 one: each image's mean, then the
        // mean of images.
        let got =
            proposals_loss_per_image(t.clone(), &[vec![0, 1], vec![1]], Goal::Targeted(1), 1.0)
                .unwrap();
        let want = ((l(2.0, -1.0) + l(0.5, 8.0)) / 2.0 + l(-2.0, 1.0)) / 2.0;
        let v = got
            .clone()
            .into_data()
            .convert::<f64>()
            .try_to_vec::<f64>()
            .unwrap()[0];
        assert!((v - want).abs() / want < 1e-5, "{v} vs {want}");
        let g = t
            .grad(&got.backward())
            .unwrap()
            .into_data()
            .convert::<f32>();
        assert!(g.try_to_vec::<f32>().unwrap().iter().all(|v| v.is_finite()));
        let e =
            proposals_loss_per_image(t, &[vec![], vec![]], Goal::Hide(ClassSet::ALL), 1.0).unwrap();
        assert_eq!(
            e.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()[0],
            0.0
        );
    }

    #[test]
    fn power_mean_over_images_weighs_the_harder_image_more() {
        let d = dev();
        let z = vec![2.0f32, -1.0, 0.5, 8.0, -1e4, 3.0, -2.0, 1.0];
        let t = Tensor::<3>::from_data(TensorData::new(z, [2, 2, 2]), &d).require_grad();
        let l = |a: f64, b: f64| sp(a) + sp(b) - b;
        let sel = [vec![0, 1], vec![1]];
        let (l0, l1) = ((l(2.0, -1.0) + l(0.5, 8.0)) / 2.0, l(-2.0, 1.0));
        for p in [1.0f32, 2.0, 4.0] {
            let got = proposals_loss_per_image(t.clone(), &sel, Goal::Targeted(1), p).unwrap();
            let pf = p as f64;
            let want = ((l0.powf(pf) + l1.powf(pf)) / 2.0).powf(1.0 / pf);
            let v = scalar(&got);
            assert!((v - want).abs() / want < 1e-5, "p {p}: {v} vs {want}");
            let g = grad(&t, got);
            // dL/dL_b = (L_b / L)^(p-1) / |B'|: the ratio of the two images' weights.
            let w = |lb: f64| (lb / want).powf(pf - 1.0) / 2.0;
            // Image 1's only proposal, target logit: dL_1/dz = σ(z) − 1 at z = 1.
            let dz = 1.0 / (1.0 + (-1.0f64).exp()) - 1.0;
            let want_g = w(l1) * dz;
            assert!(
                (g[7] as f64 - want_g).abs() < 1e-5,
                "p {p}: {} vs {want_g}",
                g[7]
            );
            assert!(g.iter().all(|v| v.is_finite()));
        }
        // Huge logits stay finite; no proposals give zero; p < 1 is refused.
        let h = Tensor::<3>::from_data(
            TensorData::new(vec![1e4f32, -1e4, -1e4, 1e4], [2, 1, 2]),
            &d,
        );
        for p in [3.0, 16.0] {
            let l = proposals_loss_per_image(h.clone(), &[vec![0], vec![0]], Goal::Targeted(1), p)
                .unwrap();
            // Image 0: z = (1e4, −1e4) gives L_0 = 2e4; image 1: (−1e4, 1e4) gives L_1 = 0.
            let (v, want) = (scalar(&l), 2e4 * 0.5f64.powf(1.0 / p as f64));
            assert!((v - want).abs() / want < 1e-4, "p {p}: {v} vs {want}");
        }
        // Both images won outright: zero.
        let won = proposals_loss_per_image(h.clone(), &[vec![], vec![0]], Goal::Targeted(1), 2.0);
        assert_eq!(scalar(&won.unwrap()), 0.0);
        assert_eq!(
            scalar(
                &proposals_loss_per_image(h.clone(), &[vec![], vec![]], Goal::Targeted(1), 2.0)
                    .unwrap()
            ),
            0.0
        );
        assert!(proposals_loss_per_image(h, &[vec![0], vec![0]], Goal::Targeted(1), 0.5).is_err());
    }

    #[test]
    fn empty_proposal_sets_give_a_zero_loss() {
        let d = dev();
        let t =
            Tensor::<3>::from_data(TensorData::new(vec![1.0f32; 6], [2, 1, 3]), &d).require_grad();
        let l = proposals_loss(t.clone(), &[vec![], vec![]], Goal::Hide(ClassSet::ALL)).unwrap();
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
