//! The pieces of one iteration the trainer puts together: the conditions it draws
//! ([`draw_conditions`]), the objective over the source detectors ([`ensemble_loss`]), the
//! numerical health check ([`check_health`]) and the record it logs ([`IterationLog`]).

use crate::baselines;
use crate::config::AttackConfig;
use anyhow::{bail, Context, Result};
use burn::tensor::Tensor;
use cac_detect::Detector;
use cac_render::environment::{Brightness, Condition, Environment};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// One iteration's record in `run.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct IterationLog {
    pub iteration: usize,
    pub loss: f64,
    pub grad_norm: f64,
    /// Candidates the objective scored, summed over the batch and source models: the fixed
    /// proposals (CAC, ShapeShifter, UPC), every candidate (CAMOU) or one per image (AdvPat).
    pub proposals: usize,
    /// Forming the images: the composite, plus planning the views where they were not planned
    /// during the previous step, plus any wait for the next step's views ([`Trainer::step`]).
    /// The four times add up to the iteration's wall time.
    pub ms_render: f64,
    pub ms_forward: f64,
    pub ms_backward: f64,
    pub ms_optimiser: f64,
    /// The range of the atlas this iteration rendered (its least and greatest channel value):
    /// the run's numerical health beside the loss and the gradient's norm. Runs logged before
    /// the field existed read as 0 and 1.
    #[serde(default)]
    pub atlas_min: f32,
    #[serde(default = "one")]
    pub atlas_max: f32,
}

fn one() -> f32 {
    1.0
}

/// The least and greatest of `values`; NaN for both where any value is not finite.
pub fn value_range(values: &[f32]) -> (f32, f32) {
    if values.iter().any(|v| !v.is_finite()) {
        return (f32::NAN, f32::NAN);
    }
    values
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)))
}

/// The run's numerical health at iteration `i`: the loss, every gradient component and the
/// atlas's range (from [`value_range`]) finite; otherwise an error that says which and where,
/// before any step is taken with it.
pub fn check_health(i: usize, loss: f64, gradient: &[f32], atlas_range: (f32, f32)) -> Result<()> {
    if !loss.is_finite() {
        bail!("iteration {i}: the loss is not finite ({loss})");
    }
    if let Some(k) = gradient.iter().position(|g| !g.is_finite()) {
        bail!(
            "iteration {i}: the gradient is not finite ({} at parameter {k} of {})",
            gradient[k],
            gradient.len()
        );
    }
    if !(atlas_range.0.is_finite() && atlas_range.1.is_finite()) {
        bail!("iteration {i}: the atlas holds a value that is not finite");
    }
    Ok(())
}

/// The batch of conditions of iteration `i`: a pure function of the run seed and `i`, so a
/// resumed run draws the same batches; brightness alternates bright, dark.
pub fn draw_conditions(env: &Environment, config: &AttackConfig, i: usize) -> Vec<Condition> {
    let mut rng = ChaCha8Rng::seed_from_u64(
        config.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (i as u64).wrapping_add(1),
    );
    (0..config.batch)
        .map(|k| {
            let b = if k % 2 == 0 {
                Brightness::Bright
            } else {
                Brightness::Dark
            };
            let mut c = env.sample(config.viewpoints, b, &mut rng);
            if let Some(share) = config.front_back_share {
                c.viewpoint.azimuth_deg =
                    cac_render::environment::azimuth_with_front_back_share(share, &mut rng);
            }
            c
        })
        .collect()
}

/// The loss of one image batch averaged over the source detectors (an ensemble), and the number of
/// fixed proposals it was taken over; `objects` are the object's boxes in the images. The trainer's
/// objective for every method; each detector's goal is the config's classes resolved against its
/// own class list ([`AttackConfig::goal_for`]).
pub fn ensemble_loss(
    detectors: &[&dyn Detector],
    images: &Tensor<4>,
    objects: &[Option<[f32; 4]>],
    config: &AttackConfig,
) -> Result<(Tensor<1>, usize)> {
    let mut total: Option<Tensor<1>> = None;
    let mut proposals = 0;
    let sel = baselines::objectives::Selection {
        rule: config.proposals,
        top_n: config.top_n,
        nms_iou: config.nms_iou,
        overlap_iou: config.overlap_iou,
        objects,
        image_power: config.image_power,
    };
    for det in detectors {
        let goal = config.goal_for(*det)?;
        let c = det.candidates(images.clone())?;
        let (l, n) = baselines::objective(config.method, c, &sel, goal)?;
        proposals += n;
        total = Some(match total {
            Some(t) => t + l,
            None => l,
        });
    }
    Ok((
        total.context("no detector")? / detectors.len() as f64,
        proposals,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn health_names_the_first_value_that_is_not_finite() {
        assert_eq!(value_range(&[0.25, -1.0, 3.0]), (-1.0, 3.0));
        assert!(value_range(&[0.25, f32::NAN]).0.is_nan());
        assert!(value_range(&[f32::INFINITY]).1.is_nan());
        check_health(3, 0.5, &[0.0, -1e30], (0.0, 1.0)).unwrap();
        let e = |l, g: &[f32], a: &[f32]| {
            check_health(7, l, g, value_range(a))
                .unwrap_err()
                .to_string()
        };
        assert!(e(f64::NAN, &[], &[]).contains("iteration 7: the loss is not finite (NaN)"));
        assert!(e(f64::INFINITY, &[], &[]).contains("loss is not finite (inf)"));
        let g = e(1.0, &[0.0, 2.0, f32::NEG_INFINITY], &[0.5]);
        assert!(
            g.contains("gradient is not finite (-inf at parameter 2 of 3)"),
            "{g}"
        );
        let a = e(1.0, &[0.0], &[f32::NAN, 0.5]);
        assert!(
            a.contains("iteration 7: the atlas holds a value that is not finite"),
            "{a}"
        );
        // A run.json logged before the range existed reads as the full range.
        let old: IterationLog = serde_json::from_str(
            r#"{"iteration": 0, "loss": 1.0, "grad_norm": 0.0, "proposals": 3, "ms_render": 1.0,
                "ms_forward": 1.0, "ms_backward": 1.0, "ms_optimiser": 1.0}"#,
        )
        .unwrap();
        assert_eq!((old.atlas_min, old.atlas_max), (0.0, 1.0));
    }
}
