//! `cac demo`: the main job on the embedded defaults. Until the attack lands, it renders the
//! default vehicle under sampled environment conditions and writes a contact sheet.

use super::device;
use super::render::render_conditions;
use anyhow::Result;
use cac::config::SceneConfig;
use cac::environment::{Brightness, Environment, ViewpointSet};
use cac::render::Renderer;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

pub fn run(a: Args) -> Result<()> {
    let cfg = SceneConfig::default();
    let scene = cfg.object.load()?;
    let atlas = scene.initial_atlas(cfg.render.atlas_res);
    let renderer = Renderer::new(scene, cfg.render.clone())?;
    let env = Environment::new(cfg.environment.clone())?;
    let dev = device::inference();
    for (b, name) in [(Brightness::Bright, "bright"), (Brightness::Dark, "dark")] {
        let conds = env.sample_n(9, ViewpointSet::Free, b, a.seed);
        let imgs = render_conditions(&renderer, &env, &conds, &atlas, &dev)?;
        let p = a.out.join(format!("views_{name}.png"));
        cac::io::save_png_atomic(&p, &cac::render::contact_sheet(&imgs))?;
        println!("wrote {}", p.display());
    }
    Ok(())
}
