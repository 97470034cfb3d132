//! The evaluation's and the studies' flags, mapped onto `cac-eval`'s plain settings.

use cac::attack::baselines::Method;
use cac::attack::loss::{ProposalRule, TargetLoss};
use cac::environment::ViewpointSet;
use cac::eval::realism::{RealismJob, ViewSet, Which};
use cac::eval::slurm::Batch;
use cac::study::demo::DemoJob;
use cac::study::methods::MethodsJob;
use cac::study::topn::TopnJob;
use cac::study::Source;
use std::path::PathBuf;

/// `Batch`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct BatchFlags {
    /// Slurm partition (default: the cluster's default).
    #[arg(long)]
    pub partition: Option<String>,
    /// Wall-time limit per task (sbatch --time, e.g. 2:00:00).
    #[arg(long)]
    pub time: Option<String>,
    /// CPUs per task (sbatch --cpus-per-task; also the task's thread count).
    #[arg(long, default_value_t = Batch::default().cpus_per_task)]
    pub cpus_per_task: usize,
    /// Memory per task (sbatch --mem, e.g. 4G).
    #[arg(long)]
    pub mem: Option<String>,
    /// Further #SBATCH option, verbatim (repeatable), e.g. --sbatch-arg=--account=lab.
    #[arg(long = "sbatch-arg", allow_hyphen_values = true)]
    pub extra: Vec<String>,
}

impl From<BatchFlags> for cac::eval::slurm::Batch {
    fn from(f: BatchFlags) -> Self {
        Batch {
            partition: f.partition,
            time: f.time,
            cpus_per_task: f.cpus_per_task,
            mem: f.mem,
            extra: f.extra,
        }
    }
}

/// `RealismJob`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct RealismFlags {
    /// Built-in object names or mesh files (OBJ/glTF/GLB).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "pickup,jeep,../shared/meshes/CesiumMilkTruck/CesiumMilkTruck.glb"
    )]
    pub meshes: Vec<String>,
    /// Viewpoint sets.
    #[arg(value_parser = crate::cli::values::choice::<ViewSet>(), long, value_delimiter = ',', default_value = "street,free,hemisphere")]
    pub sets: Vec<ViewSet>,
    /// Views per set and brightness level.
    #[arg(long, default_value_t = RealismJob::default().views)]
    pub views: usize,
    /// Textures: original, natural, naive, random (simple textures on the paintable texels), or
    /// image files (PNG/JPEG atlases).
    #[arg(long, value_delimiter = ',', default_value = "original")]
    pub textures: Vec<String>,
    /// Renderers.
    #[arg(value_parser = crate::cli::values::choice::<Which>(), long, value_delimiter = ',', default_value = "cac")]
    pub renderers: Vec<Which>,
    /// Apply the sampled photometric transforms (lighten/darken, print error, noise) too.
    #[arg(long)]
    pub photometric: bool,
    /// Light the scene with these HDR environments instead of the bright and dark levels (one
    /// row per environment), in both renderers (cac's image-based lighting, Cycles' world):
    /// Blender's own (city, courtyard, forest, interior, night, studio, sunrise, sunset) or
    /// equirectangular image files.
    #[arg(long, value_delimiter = ',')]
    pub hdri: Vec<String>,
    /// Strength of the HDR environments (1: as photographed).
    #[arg(long, default_value_t = RealismJob::default().hdri_strength)]
    pub hdri_strength: f32,
    /// Turn of the HDR environments about the vertical axis, degrees.
    #[arg(long, default_value_t = RealismJob::default().hdri_rotation)]
    pub hdri_rotation: f32,
    /// Seed of the sampled viewpoint sets.
    #[arg(long, default_value_t = RealismJob::default().seed)]
    pub seed: u64,
    /// Save every rendered view under this folder.
    #[arg(long)]
    pub save: Option<PathBuf>,
    /// Render every texture as this printer makes it (a printer profile; both renderers take the
    /// same as-printed atlas).
    #[arg(long)]
    pub printer: Option<PathBuf>,
}

impl From<RealismFlags> for cac::eval::realism::RealismJob {
    fn from(f: RealismFlags) -> Self {
        RealismJob {
            meshes: f.meshes,
            sets: f.sets,
            views: f.views,
            textures: f.textures,
            renderers: f.renderers,
            photometric: f.photometric,
            hdri: f.hdri,
            hdri_strength: f.hdri_strength,
            hdri_rotation: f.hdri_rotation,
            seed: f.seed,
            save: f.save,
            printer: f.printer,
            ..RealismJob::default()
        }
    }
}

/// `DemoJob`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct DemoFlags {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    /// Seed of the training run.
    #[arg(long, default_value_t = DemoJob::default().seed)]
    pub seed: u64,
    /// Attack iterations (default: as many as fit --budget on this machine; run.json and
    /// summary.json record them, and `--iterations N` repeats a run bit for bit).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Wall time the whole demo is fitted to when --iterations is not given: the training gets
    /// what is left after the original texture is scored and the second scoring is foreseen.
    #[arg(long, value_parser = crate::cli::values::duration, default_value = "3m")]
    pub budget: f64,
    /// Views rendered per iteration. One view per step buys the most quality per second in a
    /// short run (docs/attack.md, the knob table: half the time per iteration).
    #[arg(long, default_value_t = DemoJob::default().batch)]
    pub batch: usize,
    /// The target class's term in every proposal: `bce` or `logit` (as `cac train --target-loss`).
    #[arg(long, value_parser = crate::cli::values::choice::<TargetLoss>(), default_value_t = DemoJob::default().target_loss)]
    pub target_loss: TargetLoss,
    /// Protocol views per brightness level and viewpoint set (4 groups: FV/RV × bright/dark).
    #[arg(long, default_value_t = DemoJob::default().views)]
    pub views: usize,
    /// Seed of the protocol views (not the training seed: the texture never saw these views).
    #[arg(long, default_value_t = DemoJob::default().view_seed)]
    pub view_seed: u64,
    /// Photographed HDR environments (Blender's by name, e.g. `city,interior`, or .exr/.hdr
    /// files): every training and protocol view is lit by one of them, drawn per view with a
    /// random turn, and shows it behind the vehicle (image-based lighting). Default: the
    /// procedural sun, sky and ground.
    #[arg(long, value_delimiter = ',')]
    pub hdri: Vec<String>,
}

impl From<DemoFlags> for cac::study::demo::DemoJob {
    fn from(f: DemoFlags) -> Self {
        DemoJob {
            out: f.out,
            seed: f.seed,
            iterations: f.iterations,
            budget_s: f.budget,
            batch: f.batch,
            target_loss: f.target_loss,
            views: f.views,
            view_seed: f.view_seed,
            hdri: f.hdri,
        }
    }
}

/// `Source`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct SourceFlags {
    /// Which candidates are fixed: `overlap` (on the object, the n best) or `topn` (the paper's
    /// literal rule: the top n after NMS over the whole image).
    #[arg(long, value_parser = crate::cli::values::choice::<ProposalRule>(), default_value_t = Source::default().proposals)]
    pub proposals: ProposalRule,
    /// Source detectors the attacks train against, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::values::MODEL_SPECS, default_value = "nanodet")]
    pub models: Vec<String>,
    /// COCO class the proposals are pushed towards.
    #[arg(long, default_value = "person")]
    pub target: String,
    #[arg(long, default_value_t = Source::default().batch)]
    pub batch: usize,
}

impl From<SourceFlags> for cac::study::Source {
    fn from(f: SourceFlags) -> Self {
        Source {
            proposals: f.proposals,
            models: f.models,
            target: f.target,
            batch: f.batch,
        }
    }
}

/// `TopnJob`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct TopnFlags {
    /// Values of n, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,4,16,64")]
    pub n: Vec<usize>,
    /// What the attacks train against and for.
    #[command(flatten)]
    pub source: SourceFlags,
    /// Detectors the textures are evaluated on (those not among --models measure transfer).
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::values::MODEL_SPECS, default_value = "centernet,nanodet")]
    pub eval_models: Vec<String>,
    /// Training iterations per run.
    #[arg(long, default_value_t = TopnJob::default().iterations)]
    pub iterations: usize,
    /// Evaluation views per brightness level and set.
    #[arg(long, default_value_t = TopnJob::default().views)]
    pub views: usize,
    /// Evaluation viewpoint sets (fv, rv); a repeated set counts once.
    #[arg(long, value_parser = crate::cli::values::choice::<ViewpointSet>(), value_delimiter = ',', default_value = "fv")]
    pub sets: Vec<ViewpointSet>,
    /// Evaluation image side (default: the scene's).
    #[arg(long = "size")]
    pub eval_size: Option<usize>,
    /// Seed of the training runs and of the evaluation views.
    #[arg(long, default_value_t = TopnJob::default().seed)]
    pub seed: u64,
    /// Output folder: one run per n, eval/, topn.png, topn.csv, topn.md and topn.html.
    #[arg(long, default_value = "study-topn")]
    pub out: PathBuf,
}

impl From<TopnFlags> for cac::study::topn::TopnJob {
    fn from(f: TopnFlags) -> Self {
        TopnJob {
            n: f.n,
            source: f.source.into(),
            eval_models: f.eval_models,
            iterations: f.iterations,
            views: f.views,
            sets: f.sets,
            eval_size: f.eval_size,
            seed: f.seed,
            out: f.out,
            ..TopnJob::default()
        }
    }
}

/// `MethodsJob`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct MethodsFlags {
    /// Attacks, comma-separated (cac, advpat, shapeshifter, upc, camou).
    #[arg(
        long,
        value_parser = crate::cli::values::choice::<Method>(),
        value_delimiter = ',',
        default_value = "cac,advpat,shapeshifter,upc,camou"
    )]
    pub methods: Vec<Method>,
    /// Also train CAC in hide mode suppressing these classes: `all`, or COCO labels joined by
    /// `+` (e.g. car+bus+truck). Repeat for several rows.
    #[arg(long)]
    pub hide: Vec<String>,
    /// What the attacks train against and for.
    #[command(flatten)]
    pub source: SourceFlags,
    /// Detectors the textures are judged by (those not among --models measure transfer).
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::values::MODEL_SPECS, default_value = "nanodet,centernet")]
    pub eval_models: Vec<String>,
    /// Training iterations per method (the same budget for all).
    #[arg(long, default_value_t = MethodsJob::default().iterations)]
    pub iterations: usize,
    /// Textures evaluated beside the learned ones (see `cac eval --texture`).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "original,natural,naive,random"
    )]
    pub textures: Vec<String>,
    /// Evaluation views per brightness level and set.
    #[arg(long, default_value_t = MethodsJob::default().views)]
    pub views: usize,
    /// Evaluation viewpoint sets (fv, rv); a repeated set counts once.
    #[arg(long, value_parser = crate::cli::values::choice::<ViewpointSet>(), value_delimiter = ',', default_value = "fv,rv")]
    pub sets: Vec<ViewpointSet>,
    /// Seed of the training runs.
    #[arg(long, default_value_t = MethodsJob::default().seed)]
    pub seed: u64,
    /// Seed of the evaluation views (and of the simple textures).
    #[arg(long, default_value_t = MethodsJob::default().eval_seed)]
    pub eval_seed: u64,
    /// Output folder: one run per method, eval/, methods.md and methods.csv.
    #[arg(long, default_value = "study-methods")]
    pub out: PathBuf,
}

impl From<MethodsFlags> for cac::study::methods::MethodsJob {
    fn from(f: MethodsFlags) -> Self {
        MethodsJob {
            methods: f.methods,
            hide: f.hide,
            source: f.source.into(),
            eval_models: f.eval_models,
            iterations: f.iterations,
            textures: f.textures,
            views: f.views,
            sets: f.sets,
            seed: f.seed,
            eval_seed: f.eval_seed,
            out: f.out,
            ..MethodsJob::default()
        }
    }
}
