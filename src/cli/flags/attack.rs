//! `cac train`'s attack flags, mapped onto [`AttackConfig`].

use cac::attack::baselines::Method;
use cac::attack::loss::{ProposalRule, TargetLoss};
use cac::attack::{AttackConfig, LrDecay};

/// `AttackConfig`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct AttackFlags {
    /// The attack: cac (this paper) or a baseline (advpat, shapeshifter: 2D patch tiled on the
    /// object; upc, camou: full atlas in 3D). See docs/attack.md.
    #[arg(long, value_parser = crate::cli::values::choice::<Method>(), default_value_t = AttackConfig::default().method)]
    pub method: Method,
    /// Source detectors, comma-separated (an ensemble when several).
    #[arg(long, default_value = "nanodet", value_delimiter = ',', value_parser = crate::cli::values::MODEL_SPECS)]
    pub models: Vec<String>,
    /// Target class every proposal is pushed towards, by name: one of each source model's
    /// classes (COCO-80 labels for the built-in detectors); ignored with --hide.
    #[arg(long, default_value = "person")]
    pub target: String,
    /// Non-targeted mode: hide the object (suppress --hide-classes in the proposals).
    #[arg(long)]
    pub hide: bool,
    /// The classes --hide suppresses: comma-separated class names (default the vehicle classes
    /// P@0.5 counts), or `all` (every class; it does not hide the pickup: docs/attack.md).
    #[arg(long, default_value = "car,bus,truck")]
    pub hide_classes: String,
    /// Which candidates the loss fixes: `overlap` (those on the object's box, IoU >=
    /// --overlap-iou) or `topn` (the top n after NMS over the whole image); see docs/attack.md.
    #[arg(long, value_parser = crate::cli::values::choice::<ProposalRule>(), default_value_t = AttackConfig::default().proposals)]
    pub proposals: ProposalRule,
    /// Fixed proposals per image at most (the paper's n).
    #[arg(long, default_value_t = AttackConfig::default().top_n)]
    pub top_n: usize,
    /// Least IoU with the object's box of an `overlap` proposal.
    #[arg(long, default_value_t = AttackConfig::default().overlap_iou)]
    pub overlap_iou: f64,
    #[arg(long, default_value_t = AttackConfig::default().batch)]
    pub batch: usize,
    #[arg(long, default_value_t = AttackConfig::default().iterations)]
    pub iterations: usize,
    #[arg(long, default_value_t = AttackConfig::default().lr)]
    pub lr: f32,
    /// Learning-rate schedule: constant, or cosine (annealed from --lr to 0 over --iterations).
    #[arg(long, value_parser = crate::cli::values::choice::<LrDecay>(), default_value_t = AttackConfig::default().lr_decay)]
    pub lr_decay: LrDecay,
    #[arg(long, default_value_t = AttackConfig::default().seed)]
    pub seed: u64,
    /// Write a checkpoint every this many iterations (0: only at the end).
    #[arg(long, default_value_t = AttackConfig::default().checkpoint_every)]
    pub checkpoint_every: usize,
    /// Power of the mean over images of their losses (overlap rule): 1 is the mean, p > 1
    /// weighs the views the texture fails on more ([`loss::proposals_loss_per_image`],
    /// docs/attack.md).
    #[arg(long, default_value_t = AttackConfig::default().image_power)]
    pub image_power: f32,
    /// The target class's term in every proposal: `bce` (−log σ(z), which stops pulling once
    /// the source model is sure) or `logit` (−z, which does not: the targeted-transfer loss of
    /// Zhao et al. 2021). The other classes are suppressed by their BCE either way (--method cac
    /// only; docs/attack.md).
    #[arg(long, value_parser = crate::cli::values::choice::<TargetLoss>(), default_value_t = AttackConfig::default().target_loss)]
    pub target_loss: TargetLoss,
    /// Share of the training views drawn within 30° of the front or the back (free viewpoints;
    /// default: azimuth uniform, a share of 1/3; the evaluation's views stay uniform;
    /// [`cac_render::environment::azimuth_with_front_back_share`]).
    #[arg(long)]
    pub front_back_share: Option<f32>,
    /// Levels of the atlas's multi-scale parameterisation: 1 optimises texel by texel; K adds
    /// K-1 coarser levels (each half the side of the last) whose sum is the atlas ([`pyramid`]).
    #[arg(long, default_value_t = AttackConfig::default().scales)]
    pub scales: usize,
    /// Train through this printer (a profile, docs/formats.md "Printer profile"): every view
    /// renders what the printer makes. An FDM profile makes the atlas a choice among its
    /// filaments per region ([`filaments`]); the texture written is the one printed.
    #[arg(long)]
    pub printer: Option<std::path::PathBuf>,
    /// Train through these input defences (an adaptive attack; docs/eval.md "Defences"): each
    /// training view goes through one of them, drawn per view, in front of every source model;
    /// gradients pass exactly (blur, resize-pad), through the mask held fixed (lgs) or straight
    /// through (the others).
    #[arg(long = "defence", value_delimiter = ',')]
    pub defences: Vec<String>,
    /// 2D methods: side of the trained patch in texels.
    #[arg(long, default_value_t = AttackConfig::default().patch_res)]
    pub patch_res: usize,
    /// 2D methods: copies of the patch across the atlas side when it is put on the object.
    #[arg(long, default_value_t = AttackConfig::default().patch_tiles)]
    pub patch_tiles: usize,
}

impl From<AttackFlags> for AttackConfig {
    fn from(f: AttackFlags) -> Self {
        AttackConfig {
            method: f.method,
            models: f.models,
            target: f.target,
            hide: f.hide,
            hide_classes: f.hide_classes,
            proposals: f.proposals,
            top_n: f.top_n,
            overlap_iou: f.overlap_iou,
            batch: f.batch,
            iterations: f.iterations,
            lr: f.lr,
            lr_decay: f.lr_decay,
            seed: f.seed,
            checkpoint_every: f.checkpoint_every,
            image_power: f.image_power,
            target_loss: f.target_loss,
            front_back_share: f.front_back_share,
            scales: f.scales,
            printer: f.printer,
            defences: f.defences,
            patch_res: f.patch_res,
            patch_tiles: f.patch_tiles,
            ..AttackConfig::default()
        }
    }
}
