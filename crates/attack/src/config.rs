//! [`AttackConfig`]: what a run is asked to do (a run's `attack` in run.json, `cac train`'s
//! flags), its defaults, its checks, and the goal it resolves against each detector's classes.

use crate::baselines::Method;
use crate::loss::{ClassSet, Goal, ProposalRule, TargetLoss};
use anyhow::{bail, Context, Result};
use cac_core::choice::Choice;
use cac_detect::Detector;
use cac_render::environment::ViewpointSet;
use serde::{Deserialize, Serialize};

/// Attack settings: a run's `attack` in run.json (`cac train`'s flags map onto them).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AttackConfig {
    /// The attack: cac (this paper) or a baseline (advpat, shapeshifter: 2D patch tiled on the
    /// object; upc, camou: full atlas in 3D). See docs/attack.md.
    pub method: Method,
    /// Source detectors, comma-separated (an ensemble when several).
    pub models: Vec<String>,
    /// Target class every proposal is pushed towards, by name: one of each source model's
    /// classes (COCO-80 labels for the built-in detectors); ignored with --hide.
    pub target: String,
    /// Non-targeted mode: hide the object (suppress --hide-classes in the proposals).
    pub hide: bool,
    /// The classes --hide suppresses: comma-separated class names (default the vehicle classes
    /// P@0.5 counts), or `all` (every class; it does not hide the pickup: docs/attack.md).
    // Runs written before the setting existed suppressed every class: a run.json without it
    // reads as `all`.
    #[serde(default = "all_classes")]
    pub hide_classes: String,
    /// Which candidates the loss fixes: `overlap` (those on the object's box, IoU >=
    /// --overlap-iou) or `topn` (the top n after NMS over the whole image); see docs/attack.md.
    // Runs written before the rule existed used top-n: a run.json without it reads as `topn`.
    #[serde(default = "legacy_rule")]
    pub proposals: ProposalRule,
    /// Fixed proposals per image at most (the paper's n).
    pub top_n: usize,
    /// IoU of the class-agnostic NMS that picks the `topn` proposals.
    pub nms_iou: f64,
    /// Least IoU with the object's box of an `overlap` proposal.
    pub overlap_iou: f64,
    pub batch: usize,
    pub iterations: usize,
    pub lr: f32,
    /// Learning-rate schedule: constant, or cosine (annealed from --lr to 0 over --iterations).
    // Runs written before the setting existed used a constant one (the default).
    pub lr_decay: LrDecay,
    pub seed: u64,
    /// Write a checkpoint every this many iterations (0: only at the end).
    pub checkpoint_every: usize,
    /// Where the training views are drawn (`cac train --restricted`: side views only).
    pub viewpoints: ViewpointSet,
    /// Power of the mean over images of their losses (overlap rule): 1 is the mean, p > 1
    /// weighs the views the texture fails on more ([`loss::proposals_loss_per_image`],
    /// docs/attack.md).
    pub image_power: f32,
    /// The target class's term in every proposal: `bce` (−log σ(z), which stops pulling once
    /// the source model is sure) or `logit` (−z, which does not: the targeted-transfer loss of
    /// Zhao et al. 2021). The other classes are suppressed by their BCE either way (--method cac
    /// only; docs/attack.md).
    // Runs written before the setting existed used the BCE (the default).
    pub target_loss: TargetLoss,
    /// Share of the training views drawn within 30° of the front or the back (free viewpoints;
    /// default: azimuth uniform, a share of 1/3; the evaluation's views stay uniform;
    /// [`cac_render::environment::azimuth_with_front_back_share`]).
    #[serde(default)]
    pub front_back_share: Option<f32>,
    /// Levels of the atlas's multi-scale parameterisation: 1 optimises texel by texel; K adds
    /// K-1 coarser levels (each half the side of the last) whose sum is the atlas ([`pyramid`]).
    pub scales: usize,
    /// Train through this printer (a profile, docs/formats.md "Printer profile"): every view
    /// renders what the printer makes. An FDM profile makes the atlas a choice among its
    /// filaments per region ([`filaments`]); the texture written is the one printed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub printer: Option<std::path::PathBuf>,
    /// Train through these input defences (an adaptive attack; docs/eval.md "Defences"): each
    /// training view goes through one of them, drawn per view, in front of every source model;
    /// gradients pass exactly (blur, resize-pad), through the mask held fixed (lgs) or straight
    /// through (the others).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub defences: Vec<String>,
    /// 2D methods: side of the trained patch in texels.
    pub patch_res: usize,
    /// 2D methods: copies of the patch across the atlas side when it is put on the object.
    pub patch_tiles: usize,
}

impl Default for AttackConfig {
    /// `cac train`'s defaults: CAC against NanoDet towards "person", the candidates on the
    /// object's box (IoU >= 0.5, at most 300 per image), batch 2, 200 iterations of Adam at a
    /// constant learning rate 0.02, seed 0, a checkpoint every 10 iterations, free viewpoints,
    /// the plain mean over images, the BCE target term, one scale; 2D methods: a 128² patch tiled
    /// 4 times across the atlas.
    fn default() -> Self {
        AttackConfig {
            method: Method::Cac,
            models: vec!["nanodet".into()],
            target: "person".into(),
            hide: false,
            hide_classes: "car,bus,truck".into(),
            proposals: ProposalRule::Overlap,
            top_n: 300,
            nms_iou: 0.7,
            overlap_iou: 0.5,
            batch: 2,
            iterations: 200,
            lr: 0.02,
            lr_decay: LrDecay::Constant,
            seed: 0,
            checkpoint_every: 10,
            viewpoints: ViewpointSet::Free,
            image_power: 1.0,
            target_loss: TargetLoss::Bce,
            front_back_share: None,
            scales: 1,
            printer: None,
            defences: vec![],
            patch_res: 128,
            patch_tiles: 4,
        }
    }
}

/// The learning-rate schedule over a run's iterations.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LrDecay {
    /// `lr` at every iteration.
    #[default]
    Constant,
    /// Cosine annealing to zero (Loshchilov & Hutter 2017, without restarts):
    /// `lr_i = lr · (1 + cos(π i / iterations)) / 2`. A run grown on resume stretches the rest
    /// of its schedule to the new `iterations`.
    Cosine,
}

cac_core::choices!(LrDecay {
    Constant => "constant": "`lr` at every iteration",
    Cosine => "cosine": "Cosine annealing to zero (Loshchilov & Hutter 2017, without restarts): \
        `lr_i = lr · (1 + cos(π i / iterations)) / 2`. A run grown on resume stretches the rest \
        of its schedule to the new `iterations`",
});

fn all_classes() -> String {
    "all".into()
}

fn legacy_rule() -> ProposalRule {
    ProposalRule::TopN
}

/// `all`, or comma-separated class names, as a set of a model's classes (`classes`, its class
/// list; `model` names it in errors).
fn hide_set(labels: &str, classes: &[&str], model: &str) -> Result<ClassSet> {
    if labels.trim().eq_ignore_ascii_case("all") {
        return Ok(ClassSet::ALL);
    }
    let mut ids = Vec::new();
    for l in hide_labels(labels)? {
        ids.push(
            cac_detect::labels::resolve(l, classes, model)
                .with_context(|| format!("--hide-classes {labels:?}"))?,
        );
    }
    if ids.iter().any(|&c| c >= 128) {
        bail!("--hide-classes: {model} has {} classes; a hidden class must be one of the first 128 (use `all`)", classes.len());
    }
    Ok(ClassSet::of(&ids))
}

/// The names of `--hide-classes` (not `all`), checked to be a non-empty list.
fn hide_labels(labels: &str) -> Result<Vec<&str>> {
    let v: Vec<&str> = labels
        .split(',')
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect();
    if v.is_empty() {
        bail!("--hide-classes is empty (use `all` or class names such as \"car,bus,truck\")");
    }
    Ok(v)
}

impl AttackConfig {
    /// The learning rate of iteration `i` (from 0) under [`Self::lr_decay`].
    pub(crate) fn lr_at(&self, i: usize) -> f32 {
        match self.lr_decay {
            LrDecay::Constant => self.lr,
            LrDecay::Cosine => {
                let t = (i as f64 / self.iterations.max(1) as f64).min(1.0);
                (self.lr as f64 * 0.5 * (1.0 + (std::f64::consts::PI * t).cos())) as f32
            }
        }
    }

    /// The goal against one detector: the target or hidden classes named by the config,
    /// resolved by name against the detector's classes ([`Detector::classes`]), so each model
    /// of an ensemble gets its own class ids; a name the model lacks is an error that lists
    /// the model's classes.
    pub fn goal_for(&self, detector: &dyn Detector) -> Result<Goal> {
        self.goal_in(detector.classes(), detector.name())
    }

    /// [`Self::goal_for`] with a class list `classes` of model `model`.
    pub(crate) fn goal_in(&self, classes: &[&str], model: &str) -> Result<Goal> {
        if !self.method.is_targeted() {
            return Ok(Goal::Hide(ClassSet::ALL));
        }
        if self.hide {
            return Ok(Goal::Hide(hide_set(&self.hide_classes, classes, model)?));
        }
        let t = cac_detect::labels::resolve(&self.target, classes, model)
            .context("the attack's target class (--target)")?;
        Ok(match self.target_loss {
            TargetLoss::Bce => Goal::Targeted(t),
            TargetLoss::Logit => Goal::TargetedLogit(t),
        })
    }

    pub fn validate(&self) -> Result<()> {
        if self.models.is_empty() {
            bail!("at least one source model is needed");
        }
        cac_detect::defence::parse_chains(&self.defences).context("--defence")?;
        if self.batch == 0 || self.top_n == 0 {
            bail!("batch and top_n must be positive");
        }
        if let Some(p) = &self.printer {
            cac_core::printer::Profile::load(p)?;
        }
        if self.printer.is_some() && (self.method.is_2d() || self.scales != 1) {
            bail!(
                "--printer trains the whole atlas through the printer: it needs a full-atlas \
                 method (cac, upc, camou) at --scales 1 (got {} at {} scales)",
                self.method.name(),
                self.scales
            );
        }
        if !(self.overlap_iou > 0.0 && self.overlap_iou <= 1.0) {
            bail!("--overlap-iou must be in (0, 1], got {}", self.overlap_iou);
        }
        if !(self.image_power >= 1.0 && self.image_power <= 16.0) {
            bail!("--image-power must be in [1, 16], got {}", self.image_power);
        }
        if self.image_power != 1.0
            && (self.method != Method::Cac || self.proposals != ProposalRule::Overlap)
        {
            bail!(
                "--image-power weighs the per-image losses of the overlap rule: it needs --method cac \
                 --proposals overlap (got {} with {})",
                self.method.name(),
                self.proposals.name()
            );
        }
        if self.target_loss == TargetLoss::Logit {
            if self.method != Method::Cac || self.hide {
                bail!(
                    "--target-loss logit is CAC's targeted loss: it needs --method cac without --hide \
                     (got {}{})",
                    self.method.name(),
                    if self.hide { " with --hide" } else { "" }
                );
            }
            if self.image_power != 1.0 {
                bail!(
                    "--target-loss logit is unbounded below: it has no power mean over images \
                     (--image-power {} needs --target-loss bce)",
                    self.image_power
                );
            }
        }
        if let Some(share) = self.front_back_share {
            if !(0.0..=1.0).contains(&share) {
                bail!("--front-back-share must be in [0, 1], got {share}");
            }
            if self.viewpoints != ViewpointSet::Free {
                bail!("--front-back-share weighs the free viewpoints' azimuth: it cannot be used with --restricted");
            }
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            bail!("learning rate must be positive");
        }
        if self.hide && self.method != Method::Cac {
            bail!(
                "--hide applies to --method cac only: {} {}",
                self.method.name(),
                if self.method.is_targeted() {
                    "is a targeted attack (it needs --target)"
                } else {
                    "already hides the vehicle (it is non-targeted)"
                }
            );
        }
        if self.scales != 1 && (self.method.is_2d() || !(1..=8).contains(&self.scales)) {
            bail!(
                "--scales must be 1..=8, and 1 for the 2D methods (got {} with {})",
                self.scales,
                self.method.name()
            );
        }
        if self.method.is_2d() && !(4..=2048).contains(&self.patch_res) {
            bail!("--patch-res must be 4..=2048, got {}", self.patch_res);
        }
        if self.method.is_2d() && !(1..=64).contains(&self.patch_tiles) {
            bail!("--patch-tiles must be 1..=64, got {}", self.patch_tiles);
        }
        // The class names are resolved against each model when the models are loaded
        // (`goal_for`); here only their form is checked.
        if self.method.is_targeted() {
            if self.hide && !self.hide_classes.trim().eq_ignore_ascii_case("all") {
                hide_labels(&self.hide_classes)?;
            } else if !self.hide && self.target.trim().is_empty() {
                bail!("--target is empty (name one of the model's classes, e.g. \"person\")");
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn cosine_decay_and_image_power_are_checked() {
        let c = AttackConfig {
            lr: 0.02,
            lr_decay: LrDecay::Cosine,
            iterations: 100,
            ..Default::default()
        };
        assert_eq!(c.lr_at(0), 0.02);
        assert!((c.lr_at(50) - 0.01).abs() < 1e-7, "{}", c.lr_at(50));
        assert!(c.lr_at(99) > 0.0 && c.lr_at(99) < 1e-4);
        assert_eq!(c.lr_at(100), 0.0);
        assert_eq!(c.lr_at(500), 0.0, "past the end it stays at zero");
        assert!((1..100).all(|i| c.lr_at(i) < c.lr_at(i - 1)), "decreasing");
        let k = AttackConfig::default();
        assert!((0..300).all(|i| k.lr_at(i) == k.lr), "constant by default");
        // --image-power: in [1, 16], and only where there are per-image losses to weigh.
        let p = |image_power, proposals| AttackConfig {
            image_power,
            proposals,
            ..Default::default()
        };
        assert!(p(3.0, ProposalRule::Overlap).validate().is_ok());
        for bad in [0.5, f32::NAN, 17.0] {
            assert!(p(bad, ProposalRule::Overlap).validate().is_err(), "{bad}");
        }
        let e = p(2.0, ProposalRule::TopN)
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("--proposals overlap"), "{e}");
        // A run.json written before the setting existed reads as constant.
        let old: AttackConfig = serde_json::from_str(r#"{"lr": 0.02}"#).unwrap();
        assert_eq!(old.lr_decay, LrDecay::Constant);
        assert_eq!(old.front_back_share, None);
    }

    #[test]
    fn the_defaults_and_a_run_json_without_a_setting_reads_as_before_it() {
        let d = AttackConfig::default();
        assert_eq!(
            (
                d.method,
                d.models.clone(),
                d.target.as_str(),
                d.lr,
                d.iterations,
                d.batch
            ),
            (
                Method::Cac,
                vec!["nanodet".to_string()],
                "person",
                0.02,
                200,
                2
            )
        );
        assert_eq!(
            (d.nms_iou, d.viewpoints, d.scales, d.image_power),
            (0.7, ViewpointSet::Free, 1, 1.0)
        );
        assert_eq!(
            (d.hide_classes.as_str(), d.proposals),
            ("car,bus,truck", ProposalRule::Overlap)
        );
        // A run.json written before these settings existed keeps what those runs did.
        let old: AttackConfig = serde_json::from_str("{}").unwrap();
        assert_eq!(
            (old.hide_classes.as_str(), old.proposals),
            ("all", ProposalRule::TopN)
        );
        assert_eq!((old.scales, old.image_power, old.lr), (1, 1.0, 0.02));
        assert_eq!(
            (d.target_loss, old.target_loss),
            (TargetLoss::Bce, TargetLoss::Bce)
        );
    }

    #[test]
    fn the_logit_target_is_cacs_targeted_loss_with_a_plain_mean() {
        let logit = AttackConfig {
            target_loss: TargetLoss::Logit,
            ..AttackConfig::default()
        };
        logit.validate().unwrap();
        let classes = ["person", "bicycle", "car"];
        assert_eq!(
            logit.goal_in(&classes, "m").unwrap(),
            Goal::TargetedLogit(0)
        );
        let bce = AttackConfig::default();
        assert_eq!(bce.goal_in(&classes, "m").unwrap(), Goal::Targeted(0));
        for (bad, says) in [
            (
                AttackConfig {
                    method: Method::Upc,
                    ..logit.clone()
                },
                "needs --method cac",
            ),
            (
                AttackConfig {
                    hide: true,
                    ..logit.clone()
                },
                "with --hide",
            ),
            (
                AttackConfig {
                    image_power: 2.0,
                    ..logit.clone()
                },
                "no power mean",
            ),
        ] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains("--target-loss logit") && e.contains(says), "{e}");
        }
    }

    #[test]
    fn front_back_share_sets_the_share_of_end_on_views() {
        use cac_render::environment::azimuth_with_front_back_share as draw;
        let near_ends = |a: f32| {
            let d = (a.rem_euclid(180.0) - 90.0).abs(); // 90 at front/back, 0 at the sides
            d > 60.0
        };
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for share in [0.0f32, 1.0 / 3.0, 0.6, 1.0] {
            let n = 20_000;
            let az: Vec<f32> = (0..n).map(|_| draw(share, &mut rng)).collect();
            assert!(az.iter().all(|a| (0.0..360.0).contains(a)), "{share}");
            let f = az.iter().filter(|&&a| near_ends(a)).count() as f32 / n as f32;
            assert!((f - share).abs() < 0.015, "share {share}: {f}");
            // Both ends and both sides are drawn alike.
            let back = az.iter().filter(|&&a| (90.0..270.0).contains(&a)).count() as f32;
            assert!(
                (back / n as f32 - 0.5).abs() < 0.015,
                "share {share}: back {back}"
            );
        }
        // Off by default (no extra draws: the runs of before are unchanged), checked when set.
        let c = |share, viewpoints| AttackConfig {
            front_back_share: share,
            viewpoints,
            ..Default::default()
        };
        assert!(c(Some(0.5), ViewpointSet::Free).validate().is_ok());
        assert!(c(Some(1.5), ViewpointSet::Free).validate().is_err());
        assert!(c(Some(f32::NAN), ViewpointSet::Free).validate().is_err());
        assert!(c(Some(0.5), ViewpointSet::Restricted).validate().is_err());
    }
}
