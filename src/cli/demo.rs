//! `cac demo`: the main job on the embedded defaults. A short dense-proposals attack on the
//! default vehicle against NanoDet (target "person"), then before/after P@0.5 and targeted success
//! on street-level views, with CenterNet as an unseen (transfer) model.

use super::{device, train};
use anyhow::Result;
use cac::attack::{AttackConfig, Trainer};
use cac::config::SceneConfig;
use cac::environment::{Brightness, Environment, ViewpointSet};
use cac::eval::{self, Protocol};
use cac::render::{RenderSettings, Renderer};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Attack iterations (batch 2).
    #[arg(long, default_value_t = 240)]
    pub iterations: usize,
    /// Street-level evaluation views per brightness level.
    #[arg(long, default_value_t = 12)]
    pub views: usize,
}

/// The demo's scene: the built-in pickup, street-level training views (the distribution the
/// evaluation views come from), the paper's photometric transforms.
pub fn demo_scene() -> SceneConfig {
    let mut cfg = SceneConfig::default();
    cfg.render = RenderSettings {
        width: 320,
        height: 320,
        samples: 1,
        vfov_deg: 45.0,
        atlas_res: 256,
    };
    cfg.environment.distance_ratio = [1.2, 2.2];
    cfg.environment.elevation_deg = [0.0, 25.0];
    cfg
}

pub fn run(a: Args) -> Result<()> {
    let start = Instant::now();
    let cfg = demo_scene();
    let scene = cfg.object.load()?;
    let original = scene.initial_atlas(cfg.render.atlas_res);
    let renderer = Renderer::new(scene, cfg.render.clone())?;
    let eval_renderer = Renderer::new(
        renderer.scene.clone(),
        RenderSettings {
            width: 416,
            height: 416,
            samples: 4,
            ..cfg.render.clone()
        },
    )?;
    let env = Environment::new(cfg.environment.clone())?;
    println!("loading detectors (fetched once into the cache on first use) ...");
    let dets = train::load_detectors(&["nanodet".into(), "centernet".into()])?;
    let all: Vec<&dyn cac::detect::Detector> = dets.iter().map(|d| d.as_ref()).collect();
    let attack = AttackConfig {
        models: vec!["nanodet".into()],
        iterations: a.iterations,
        seed: a.seed,
        batch: 2,
        top_n: 300,
        checkpoint_every: 50,
        viewpoints: ViewpointSet::Free,
        ..Default::default()
    };
    let target = attack.goal()?;
    let proto = Protocol {
        target: match target {
            cac::attack::loss::Goal::Targeted(t) => Some(t),
            _ => None,
        },
        ..Default::default()
    };
    let mut views = eval::street_views(a.views, 1.5, Brightness::Bright);
    views.extend(eval::street_views(a.views, 1.5, Brightness::Dark));
    let dev = device::inference();

    let before = eval::evaluate(&eval_renderer, &env, &views, &original, &all, &proto, &dev)?;
    println!(
        "training {} iterations against nanodet (target \"person\", n = 300, batch 2) ...",
        a.iterations
    );
    let mut tr = Trainer::new(
        attack,
        &renderer,
        &env,
        vec![all[0]],
        device::training(),
        &original,
    )?;
    let run_dir = a.out.join("run");
    if run_dir.join("run.json").exists() {
        tr = tr.resume(&run_dir)?;
        println!(
            "resuming the demo's run at iteration {}",
            tr.state.iteration
        );
    }
    train::train_loop(&mut tr, &run_dir, &cfg, true)?;
    let learned = tr.atlas();
    let after = eval::evaluate(&eval_renderer, &env, &views, &learned, &all, &proto, &dev)?;

    println!("\n{} street-level views (elevation 5-15 deg, distance ratio 1.5, bright and dark); hit = car/truck, IoU >= 0.5, confidence >= 0.3", views.len());
    println!(
        "{:<22} {:>12} {:>12} {:>9} {:>14} {:>14}",
        "model", "P@0.5 before", "P@0.5 after", "drop", "person before", "person after"
    );
    for (m, name) in ["nanodet (white-box)", "centernet (transfer)"]
        .iter()
        .enumerate()
    {
        let (b, f) = (
            eval::summarise(&before.scores[m]),
            eval::summarise(&after.scores[m]),
        );
        println!(
            "{:<22} {:>12.3} {:>12.3} {:>9.3} {:>14.3} {:>14.3}",
            name,
            b.p_at_05,
            f.p_at_05,
            b.p_at_05 - f.p_at_05,
            b.targeted_success,
            f.targeted_success
        );
    }
    std::fs::create_dir_all(&a.out)?;
    cac::io::save_png_atomic(&a.out.join("atlas_original.png"), &original.to_rgb8())?;
    cac::io::save_png_atomic(&a.out.join("atlas_learned.png"), &learned.to_rgb8())?;
    cac::io::save_png_atomic(
        &a.out.join("views_original.png"),
        &cac::render::contact_sheet(&before.images),
    )?;
    cac::io::save_png_atomic(
        &a.out.join("views_learned.png"),
        &cac::render::contact_sheet(&after.images),
    )?;
    let summary = serde_json::json!({
        "protocol": proto,
        "views": views.len(),
        "iterations": tr.state.iteration,
        "models": ["nanodet", "centernet"],
        "before": before.scores.iter().map(|s| eval::summarise(s)).collect::<Vec<_>>(),
        "after": after.scores.iter().map(|s| eval::summarise(s)).collect::<Vec<_>>(),
        "seconds": start.elapsed().as_secs_f64(),
    });
    cac::io::write_atomic(
        &a.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    println!(
        "\nwrote {} (atlases, before/after view sheets, summary.json, run/) in {:.0} s",
        a.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
