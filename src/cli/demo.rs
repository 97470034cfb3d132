//! `cac demo`: the main job on the embedded defaults. A short dense-proposals attack on the
//! default vehicle against NanoDet (target "person"), trained on the evaluation protocol's own
//! distribution (scaled down: 320² renders), then scored as `cac eval` scores: before/after P@0.5
//! and "person" success on protocol views (FV and RV, bright and dark, distance ratio 1.5–6) drawn
//! with a seed the training never saw, with CenterNet as an unseen (transfer) model. The view
//! sheets draw each detector's boxes and labels.

use super::{device, train};
use anyhow::Result;
use cac::attack::{run::RunDir, AttackConfig, Trainer};
use cac::config::{SceneConfig, Stage};
use cac::detect::Detector;
use cac::environment::{Environment, ViewpointSet};
use cac::eval::compare::{before_after, write_sheets, BeforeAfter};
use cac::eval::run::{all_views, evaluate_texture_in, view_groups, TextureResult, ViewPlan};
use cac::eval::Protocol;
use cac::render::{RenderSettings, Renderer};
use cac::scene::Texture;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    /// Seed of the training run.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Attack iterations (batch 2).
    #[arg(long, default_value_t = 600)]
    pub iterations: usize,
    /// Protocol views per brightness level and viewpoint set (4 groups: FV/RV × bright/dark).
    #[arg(long, default_value_t = 16)]
    pub views: usize,
    /// Seed of the protocol views (not the training seed: the texture never saw these views).
    #[arg(long, default_value_t = 2026)]
    pub view_seed: u64,
}

pub fn run(a: Args) -> Result<()> {
    let start = Instant::now();
    let cfg = SceneConfig::training();
    let Stage {
        renderer,
        env,
        original,
    } = cfg.stage()?;
    // Scored as `cac eval` renders by default: 512², 4 samples per pixel.
    let eval_renderer = Renderer::new(
        renderer.scene.clone(),
        RenderSettings {
            width: 512,
            height: 512,
            samples: 4,
            ..cfg.render.clone()
        },
    )?;
    println!("loading detectors (fetched once into the cache on first use) ...");
    let dets = train::load_detectors(&["nanodet".into(), "centernet".into()])?;
    let all: Vec<&dyn Detector> = dets.iter().map(|d| d.as_ref()).collect();
    let attack = attack_config(&a);
    let proto = Protocol::from_labels("car,truck", Some(&attack.target))?;
    let plan = ViewPlan {
        views_per_level: a.views,
        seed: a.view_seed,
        ..Default::default()
    };
    let groups = view_groups(&env, &plan);
    let views = all_views(&groups);
    let dev = device::inference();
    let score = |name: &str, atlas: &Texture| {
        evaluate_texture_in(
            &eval_renderer,
            &env,
            &groups,
            &views,
            name,
            atlas,
            &all,
            &proto,
            2,
            &dev,
            &mut || {},
        )
    };
    println!(
        "scoring the original texture on {} protocol views ...",
        4 * a.views
    );
    let before = score("original", &original)?;

    let (learned, iterations) = train(&a, &cfg, &attack, &renderer, &env, all[0], &original)?;
    println!("scoring the learned texture on the same views ...");
    let after = score("learned", &learned)?;

    let rows = print_results(&a, &cfg, &before, &after);
    let (sheets, sheet_views) = write_sheets(
        &a.out,
        (&original, &before),
        (&learned, &after),
        &["nanodet", "centernet"],
    )?;
    let summary = serde_json::json!({
        "protocol": proto,
        "views": plan,
        "scene": cfg,
        "attack": attack,
        "iterations": iterations,
        "results": rows,
        "sheets": sheets,
        "sheet_views": sheet_views,
        "seconds": start.elapsed().as_secs_f64(),
    });
    write_summary(&a.out, &summary, start)
}

/// Writes summary.json and says what was written.
fn write_summary(out: &std::path::Path, summary: &serde_json::Value, start: Instant) -> Result<()> {
    cac::io::write_atomic(
        &out.join("summary.json"),
        serde_json::to_string_pretty(summary)?.as_bytes(),
    )?;
    println!(
        "\nwrote {} (atlases, before/after view sheets with each detector's boxes, summary.json, \
         run/) in {:.0} s",
        out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The demo's attack: NanoDet, target "person", batch 2, checkpoints every 50 iterations.
fn attack_config(a: &Args) -> AttackConfig {
    AttackConfig {
        models: vec!["nanodet".into()],
        iterations: a.iterations,
        seed: a.seed,
        batch: 2,
        checkpoint_every: 50,
        viewpoints: ViewpointSet::Free,
        ..Default::default()
    }
}

/// Trains (or resumes) the demo's run in OUT/run; returns the learned atlas and the iteration
/// reached.
fn train(
    a: &Args,
    cfg: &SceneConfig,
    attack: &AttackConfig,
    renderer: &Renderer,
    env: &Environment,
    source: &dyn Detector,
    original: &Texture,
) -> Result<(Texture, usize)> {
    let run = RunDir::open_or_create(&a.out.join("run"), cfg.clone(), attack.clone())?;
    let tr = Trainer::new(
        attack.clone(),
        renderer,
        env,
        vec![source],
        device::training(),
        original,
    )?;
    let mut tr = run.resume(tr)?;
    if tr.state.iteration > 0 {
        println!(
            "resuming the demo's run at iteration {}",
            tr.state.iteration
        );
    }
    println!(
        "training {} iterations against nanodet (target \"person\", proposals on the object, \
         batch 2, protocol distances) ...",
        a.iterations
    );
    run.train(&mut tr, true)?;
    Ok((tr.atlas(), tr.state.iteration))
}

/// Prints the before/after table; returns its rows for summary.json.
fn print_results(
    a: &Args,
    cfg: &SceneConfig,
    before: &TextureResult,
    after: &TextureResult,
) -> Vec<BeforeAfter> {
    println!(
        "\n{} protocol views (cac eval's: FV and RV x bright and dark, {} each; distance ratio \
         {:?}, elevation {:?} deg; view seed {}, training seed {}); 512², 4 spp.\nhit = car/truck \
         with IoU >= 0.5 and confidence >= 0.3; person = a person box on the vehicle (IoU >= 0.5, \
         confidence >= 0.3).",
        4 * a.views,
        a.views,
        cfg.environment.distance_ratio,
        cfg.environment.elevation_deg,
        a.view_seed,
        a.seed,
    );
    println!(
        "{:<22} {:>4} {:>12} {:>12} {:>7} {:>14} {:>14}",
        "model", "set", "P@0.5 before", "P@0.5 after", "drop", "person before", "person after"
    );
    let models = [("nanodet", "white-box"), ("centernet", "transfer")];
    let rows = before_after(("original", before), ("learned", after), &models);
    for r in &rows {
        println!(
            "{:<22} {:>4} {:>12.3} {:>12.3} {:>7.3} {:>14.3} {:>14.3}",
            format!("{} ({})", r.model, r.role),
            r.set,
            r.p_at_05_before,
            r.p_at_05_after,
            r.drop,
            r.targeted_before,
            r.targeted_after
        );
    }
    rows
}
