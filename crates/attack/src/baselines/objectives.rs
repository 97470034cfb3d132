//! The per-method objectives over one detector's dense candidates (lower is better for the
//! attacker). CAC's own loss lives in [`crate::loss`]; this module adds the baselines'
//! and dispatches on [`Method`]. Formulas (`z` logits, `σ` sigmoid, `V` the true classes car,
//! truck, bus, `P` the fixed top-n proposals after NMS, `t` the target class):
//!
//! * CAC: the targeted BCE `Σ_c softplus(z_ic) − z_it` over its proposals, by default the
//!   candidates on the object averaged per image ([`crate::loss`]; `--proposals topn`
//!   gives the paper's literal top-n after NMS).
//! * ShapeShifter: `1/|P| Σ_{i∈P} [Σ_c softplus(z_ic) − z_it]` over the top-n after NMS (its own
//!   paper's choice of what it attacks).
//! * AdvPat: `1/B Σ_b max_i max_{c∈V} σ(z_bic)` (Thys et al.'s max of objectness × class score;
//!   these detectors have no objectness, their per-class sigmoid plays both parts).
//! * CAMOU: `1/(B·N) Σ_{b,i} Σ_{c∈V} softplus(z_bic)`, i.e. `−log(1 − σ)` of the vehicle classes in
//!   every candidate (not only the proposals).
//! * UPC: `L_obj + L_cls + L_reg` over `P`: `L_obj = mean softplus(max_{c≠t} z_ic)` (suppress the
//!   best non-target score, the stand-in for RPN objectness), `L_cls` = the targeted BCE above,
//!   `L_reg = mean_i s_i · Σ_k smoothL1((b_ik − b̄_ik − Δ_ik) / size_ik)` with `b̄` the proposal's box
//!   at selection (no gradient), `Δ` a shift by half the box's width and height, `s_i` its best
//!   non-target score (no gradient) — UPC's confidence-weighted push of the boxes off the object.
//!
//! Not here: rendering, the optimiser, the 2D patch transforms.

use super::Method;
use crate::loss::{self, select_overlapping, select_proposals, softplus, Goal, ProposalRule};
use anyhow::{bail, Result};
use burn::tensor::{activation::sigmoid, Tensor, TensorData};
use cac_detect::Candidates;

/// COCO-80 ids of the vehicle ("true") classes the hiding objectives suppress: car, bus, truck.
pub(crate) const VEHICLE_CLASSES: [usize; 3] = [2, 5, 7];

/// How the proposals are chosen, and the objects' ground-truth boxes (one per image, from the
/// renderer) that [`ProposalRule::Overlap`] needs.
#[derive(Clone, Copy, Debug)]
pub struct Selection<'a> {
    pub rule: ProposalRule,
    pub top_n: usize,
    /// IoU of the class-agnostic NMS of [`ProposalRule::TopN`].
    pub nms_iou: f64,
    /// Least IoU with the object's box of [`ProposalRule::Overlap`].
    pub overlap_iou: f64,
    pub objects: &'a [Option<[f32; 4]>],
    /// Power of the images' power mean under [`ProposalRule::Overlap`] (1: the mean).
    pub image_power: f32,
}

/// The method's loss for one detector's candidates, and the number of candidates it scored.
/// Only CAC follows `sel.rule`; the baselines keep their own papers' choice.
pub fn objective(
    method: Method,
    c: Candidates,
    sel: &Selection,
    goal: Goal,
) -> Result<(Tensor<1>, usize)> {
    let (top_n, nms_iou) = (sel.top_n, sel.nms_iou);
    match method {
        Method::Cac if sel.rule == ProposalRule::Overlap => {
            let p = select_overlapping(&c, sel.objects, top_n, sel.overlap_iou)?;
            let n = p.iter().map(Vec::len).sum();
            Ok((
                loss::proposals_loss_per_image(c.logits, &p, goal, sel.image_power)?,
                n,
            ))
        }
        Method::Cac | Method::Shapeshifter => {
            if method == Method::Shapeshifter && matches!(goal, Goal::Hide(_)) {
                bail!("shapeshifter is a targeted attack: it needs a target class");
            }
            let sel = select_proposals(&c, top_n, nms_iou)?;
            let n = sel.iter().map(Vec::len).sum();
            Ok((loss::proposals_loss(c.logits, &sel, goal)?, n))
        }
        Method::Advpat => {
            let b = c.logits.dims()[0];
            Ok((advpat_loss(c.logits), b))
        }
        Method::Camou => {
            let [b, n, _] = c.logits.dims();
            Ok((camou_loss(c.logits), b * n))
        }
        Method::Upc => {
            let Goal::Targeted(t) = goal else {
                bail!("upc is a targeted attack: it needs a target class");
            };
            let sel = select_proposals(&c, top_n, nms_iou)?;
            let n = sel.iter().map(Vec::len).sum();
            Ok((upc_loss(&c, &sel, t)?, n))
        }
    }
}

/// `[B, N, |V|]` logits of the vehicle classes.
fn vehicle_logits(logits: Tensor<3>) -> Tensor<3> {
    let [b, n, _] = logits.dims();
    Tensor::cat(
        VEHICLE_CLASSES
            .iter()
            .map(|&c| logits.clone().slice([0..b, 0..n, c..c + 1]))
            .collect(),
        2,
    )
}

/// AdvPat: mean over images of the highest vehicle-class probability among all candidates.
pub(crate) fn advpat_loss(logits: Tensor<3>) -> Tensor<1> {
    let best = vehicle_logits(logits).max_dim(2).max_dim(1); // [B, 1, 1]
    sigmoid(best).mean()
}

/// CAMOU: `−log(1 − σ(z))` of every vehicle class in every candidate, averaged over candidates.
pub(crate) fn camou_loss(logits: Tensor<3>) -> Tensor<1> {
    let [b, n, _] = logits.dims();
    softplus(vehicle_logits(logits)).sum() / (b * n) as f64
}

/// Smooth L1 (Huber with δ = 1): `0.5 x²` for `|x| < 1`, else `|x| − 0.5`.
pub(crate) fn smooth_l1<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let a = x.abs();
    let q = a.clone().clamp_max(1.0);
    q.clone() * (a - q * 0.5)
}

/// UPC's joint objectness + targeted classification + box-regression loss over the proposals.
pub(crate) fn upc_loss(c: &Candidates, sel: &[Vec<usize>], target: usize) -> Result<Tensor<1>> {
    let [b, n, classes] = c.logits.dims();
    if target >= classes {
        bail!("target class {target} is out of range for {classes} classes");
    }
    let cls = loss::proposals_loss(c.logits.clone(), sel, Goal::Targeted(target))?;
    let device = c.logits.device();
    let Some(idx) = loss::proposal_rows(sel, n, &device) else {
        return Ok(cls);
    };
    let m = idx.dims()[0];
    let z = c
        .logits
        .clone()
        .reshape([b * n, classes])
        .select(0, idx.clone());
    // Best non-target logit per proposal: mask the target column with a large negative value.
    let mut mask = vec![0.0f32; classes];
    mask[target] = -1e9;
    let mask = Tensor::<2>::from_data(TensorData::new(mask, [1, classes]), (&device, z.dtype()));
    let best = (z + mask).max_dim(1); // [m, 1]
    let obj = softplus(best.clone()).mean();
    // Box regression: push every proposal's box by half its size, weighted by its confidence.
    let boxes = c.boxes.clone().reshape([b * n, 4]).select(0, idx);
    let bh = cac_detect::to_vec(&boxes)?;
    let conf: Vec<f32> = cac_detect::to_vec(&best)?
        .iter()
        .map(|&v| 1.0 / (1.0 + (-v).exp()))
        .collect();
    let mut goal = Vec::with_capacity(m * 4);
    let mut inv_size = Vec::with_capacity(m * 4);
    for q in bh.chunks_exact(4) {
        let (w, h) = ((q[2] - q[0]).abs().max(1.0), (q[3] - q[1]).abs().max(1.0));
        goal.extend([
            q[0] + 0.5 * w,
            q[1] + 0.5 * h,
            q[2] + 0.5 * w,
            q[3] + 0.5 * h,
        ]);
        inv_size.extend([1.0 / w, 1.0 / h, 1.0 / w, 1.0 / h]);
    }
    let (dt, m4) = (boxes.dtype(), [m, 4]);
    let goal = Tensor::<2>::from_data(TensorData::new(goal, m4), (&device, dt));
    let inv_size = Tensor::<2>::from_data(TensorData::new(inv_size, m4), (&device, dt));
    let conf = Tensor::<2>::from_data(TensorData::new(conf, [m, 1]), (&device, dt));
    let reg = (smooth_l1((boxes - goal) * inv_size) * conf).sum() / m as f64;
    Ok(obj + cls + reg)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dev() -> burn::tensor::Device {
        burn::tensor::Device::autodiff(burn::tensor::Device::from(burn::backend::FlexDevice))
    }

    fn value(t: Tensor<1>) -> f64 {
        t.into_data().convert::<f64>().try_to_vec::<f64>().unwrap()[0]
    }

    #[test]
    fn smooth_l1_matches_its_definition() {
        let x = Tensor::<1>::from_data(
            TensorData::new(vec![-3.0f32, -0.5, 0.0, 0.4, 2.0], [5]),
            &dev(),
        );
        let got = cac_detect::to_vec(&smooth_l1(x)).unwrap();
        let want = [2.5f32, 0.125, 0.0, 0.08, 1.5];
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "{got:?}");
        }
    }

    #[test]
    fn advpat_and_camou_score_only_vehicle_classes() {
        let d = dev();
        let mut z = vec![-5.0f32; 2 * 80];
        z[2] = 1.0; // candidate 0: car
        z[80] = 9.0; // candidate 1: person (ignored)
        let t = Tensor::<3>::from_data(TensorData::new(z, [1, 2, 80]), &d).require_grad();
        let a = value(advpat_loss(t.clone()));
        assert!((a - 1.0 / (1.0 + (-1.0f64).exp())).abs() < 1e-6, "{a}");
        let sp = |x: f64| x.max(0.0) + (-x.abs()).exp().ln_1p();
        let want = (sp(1.0) + 5.0 * sp(-5.0)) / 2.0;
        let c = value(camou_loss(t));
        assert!((c - want).abs() < 1e-5, "{c} vs {want}");
    }

    #[test]
    fn upc_loss_is_finite_and_pushes_boxes_and_scores() {
        let d = dev();
        let mut z = vec![-3.0f32; 2 * 80];
        z[7] = 2.0; // a truck
        z[80 + 2] = 1e4; // a certain car
        let logits =
            Tensor::<3>::from_data(TensorData::new(z.clone(), [1, 2, 80]), &d).require_grad();
        let boxes = Tensor::<3>::from_data(
            TensorData::new(
                vec![10.0f32, 10.0, 50.0, 30.0, 0.0, 0.0, 20.0, 20.0],
                [1, 2, 4],
            ),
            &d,
        )
        .require_grad();
        let c = Candidates {
            boxes: boxes.clone(),
            scores: sigmoid(logits.clone()),
            logits: logits.clone(),
        };
        let l = upc_loss(&c, &[vec![0, 1]], 0).unwrap();
        assert!(value(l.clone()).is_finite());
        let g = l.backward();
        let gb = cac_detect::to_vec(&boxes.grad(&g).unwrap()).unwrap();
        // Moving x1 right (towards the shifted goal) lowers the loss: negative gradient.
        assert!(gb[0] < 0.0 && gb[1] < 0.0, "{gb:?}");
        let gz = cac_detect::to_vec(&logits.grad(&g).unwrap()).unwrap();
        assert!(gz.iter().all(|v| v.is_finite()));
        assert!(gz[0] < 0.0 && gz[7] > 0.0, "target up, truck down");
    }
}
