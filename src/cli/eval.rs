//! `cac eval`: the evaluation protocol (FV and RV views, bright and dark, P@0.5, drop, targeted
//! success, breakdowns) for a list of textures and models; writes report.md, report.html, CSV
//! tables, results.json and plots into the output folder, resuming finished textures.

use super::{device, train};
use anyhow::{bail, Result};
use cac::config::SceneConfig;
use cac::environment::ViewpointSet;
use cac::eval::job::{self, EvalJob};
use cac::eval::run::ViewPlan;
use cac::eval::shard::Shard;
use cac::eval::Protocol;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Scene config (TOML): object, render settings, environment (default: built-in defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Object, overriding the config (pickup, jeep, barrel, container or a mesh path).
    #[arg(long)]
    pub object: Option<String>,
    /// Textures as table rows: original, natural, naive, random, or NAME=PATH (atlas image or
    /// run folder). Comma-separated or repeated.
    #[arg(
        long = "texture",
        value_delimiter = ',',
        default_value = "original,natural,random"
    )]
    pub textures: Vec<String>,
    /// Detectors, comma-separated (column groups).
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::values::MODEL_SPECS, default_value = "centernet,nanodet")]
    pub models: Vec<String>,
    /// Views per brightness level in each viewpoint set (the paper: 200).
    #[arg(long, default_value_t = 200)]
    pub views: usize,
    /// Viewpoint sets: fv (free), rv (restricted side views), comma-separated.
    #[arg(long, value_parser = crate::cli::values::choice::<ViewpointSet>(), value_delimiter = ',', default_value = "fv,rv")]
    pub sets: Vec<ViewpointSet>,
    /// Seed of the views (and of the generated natural/naive/random textures).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// True classes (class names, comma-separated, each one of every model's classes; `none`
    /// for objects without one).
    #[arg(long, default_value = "car,truck")]
    pub true_classes: String,
    /// Target class for targeted success, by name (a COCO label such as "person" or "stop
    /// sign" for the built-in detectors, one of its own classes for a user's model).
    #[arg(long)]
    pub target: Option<String>,
    /// Image side in pixels (overrides the config's render width and height).
    #[arg(long)]
    pub size: Option<usize>,
    /// Samples per pixel (overrides the config).
    #[arg(long)]
    pub samples: Option<usize>,
    /// The HDRI protocol: every view lit by one of these photographed environments (drawn per
    /// view, turned at random about the vertical; Blender's city, courtyard, forest, interior,
    /// night, studio, sunrise, sunset, or EXR/HDR files) instead of the sun and ambient
    /// (Cycles under the same maps: `cac bench realism --hdri`). Overrides the config's `hdri`.
    #[arg(long, value_delimiter = ',')]
    pub hdri: Vec<String>,
    /// Example views per group kept for the HTML report.
    #[arg(long, default_value_t = 1)]
    pub examples: usize,
    /// Extra figure for the HTML report, CAPTION=PNG (e.g. "Top-n study=study-topn/topn.png").
    #[arg(long = "figure", value_parser = job::parse_figure)]
    pub figures: Vec<(String, PathBuf)>,
    /// Judge every texture as this printer makes it (a printer profile, docs/formats.md "Printer
    /// profile"): each texel the nearest filament (FDM) or the fitted response; the report says
    /// which printer judged.
    #[arg(long)]
    pub printer: Option<PathBuf>,
    /// Input defences in front of every detector, each a column group beside the detector as
    /// it is: NAME[:PARAM] of jpeg, blur, median, bits, resize-pad, tv, lgs (`+` chains several;
    /// docs/eval.md "Defences"), comma-separated.
    #[arg(long = "defence", value_delimiter = ',')]
    pub defences: Vec<String>,
    /// Output folder (finished textures are reused from its cache/ on a rerun).
    #[arg(long, default_value = "eval-out")]
    pub out: PathBuf,
    /// Evaluate only shard K of N (K = 0 .. N-1): every N-th view of the seeded view list,
    /// written into OUT/cache/ as one file per texture and shard; no report. Rerun to resume.
    #[arg(long, value_name = "K/N", conflicts_with = "merge")]
    pub shard: Option<Shard>,
    /// Write the report from the shards' files (and the cache) only, rendering nothing; refuses a
    /// missing or duplicated shard or shards written with other settings.
    #[arg(long)]
    pub merge: bool,
}

/// The evaluation job the arguments describe.
pub fn job(a: &Args) -> Result<EvalJob> {
    let mut scene = SceneConfig::from_file_or(a.config.as_deref(), SceneConfig::default)?;
    if let Some(o) = &a.object {
        scene.object.mesh = o.clone();
    }
    if let Some(s) = a.size {
        (scene.render.width, scene.render.height) = (s, s);
    }
    if let Some(s) = a.samples {
        scene.render.samples = s;
    }
    if !a.hdri.is_empty() {
        scene.environment.hdri = a.hdri.clone();
        scene.environment.hdri_share = 1.0;
    }
    scene.render.validate()?;
    cac::detect::defence::parse_chains(&a.defences)?;
    if a.views == 0 {
        bail!("--views must be at least 1");
    }
    let job = EvalJob {
        scene,
        textures: a.textures.clone(),
        plan: ViewPlan {
            views_per_level: a.views,
            seed: a.seed,
            sets: ViewpointSet::distinct(&a.sets),
            ..Default::default()
        },
        protocol: Protocol::from_labels(&a.true_classes, a.target.as_deref())?,
        examples_per_group: a.examples,
        figures: a.figures.clone(),
        printer: a.printer.clone(),
        out: a.out.clone(),
    };
    Ok(job)
}

pub fn run(a: Args) -> Result<()> {
    let job = job(&a)?;
    let chains = cac::detect::defence::parse_chains(&a.defences)?;
    let dets = cac::detect::defence::defend(train::load_detectors(&a.models)?, &chains);
    let refs = cac::detect::refs(&dets);
    let pb = ProgressBar::new(0);
    pb.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} images, {per_sec}, ETA {eta}")
            .expect("template"),
    );
    let mut bar = |d: usize, t: usize| {
        pb.set_length(t as u64);
        pb.set_position(d as u64);
    };
    if let Some(shard) = a.shard {
        let o = job::run_shard(&job, shard, &refs, &device::inference(), &mut bar)?;
        pb.finish_and_clear();
        print!("{o}");
        return Ok(());
    }
    let o = if a.merge {
        job::merge(&job, &refs, &device::inference())?
    } else {
        job::run(&job, &refs, &device::inference(), &mut bar)?
    };
    pb.finish_and_clear();
    print!("{o}");
    Ok(())
}
