//! `cac render`: one view, or a contact sheet of sampled views.

use super::device;
use anyhow::{bail, Result};
use cac::config::{SceneConfig, Stage};
use cac::environment::{self, Brightness, Condition, ViewpointSet};
use cac::render::Viewpoint;
use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs, Debug)]
pub struct Args {
    /// Scene config (TOML); defaults to the built-in pickup and the paper's environment.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Mesh file (OBJ/glTF/GLB) or built-in name; overrides the config.
    #[arg(long)]
    pub mesh: Option<String>,
    /// Camouflage atlas PNG for the paintable parts (default: the object's own texture).
    #[arg(long)]
    pub texture: Option<PathBuf>,
    #[arg(long, default_value_t = 30.0)]
    pub azimuth: f32,
    #[arg(long, default_value_t = 10.0)]
    pub elevation: f32,
    /// Camera distance in object lengths.
    #[arg(long, default_value_t = 1.6)]
    pub distance: f32,
    #[arg(long)]
    pub width: Option<usize>,
    #[arg(long)]
    pub height: Option<usize>,
    /// Samples per pixel.
    #[arg(long)]
    pub samples: Option<usize>,
    #[arg(long, value_parser = crate::cli::values::choice::<Brightness>(), default_value = "bright")]
    pub brightness: Brightness,
    /// Render N sampled views (the environment distribution) in a grid instead of one view.
    #[arg(long)]
    pub contact_sheet: Option<usize>,
    #[arg(long, value_parser = crate::cli::values::choice::<ViewpointSet>(), default_value = "fv")]
    pub viewpoints: ViewpointSet,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let mut cfg = SceneConfig::from_file_or(a.config.as_deref(), SceneConfig::default)?;
    if let Some(m) = &a.mesh {
        cfg.object.mesh = m.clone();
    }
    if let Some(w) = a.width {
        cfg.render.width = w;
    }
    if let Some(h) = a.height {
        cfg.render.height = h;
    }
    if let Some(s) = a.samples {
        cfg.render.samples = s;
    }
    let Stage {
        renderer,
        env,
        original,
    } = cfg.stage()?;
    let atlas = match &a.texture {
        Some(p) => cac::scene::Texture::from_rgb8(&cac::io::load_rgb(p)?)
            .resized(cfg.render.atlas_res, cfg.render.atlas_res),
        None => original,
    };
    let conds = match a.contact_sheet {
        Some(0) => bail!("--contact-sheet needs at least one view"),
        Some(n) => env.sample_n(n, a.viewpoints, a.brightness, a.seed),
        None => vec![Condition::plain(
            Viewpoint::new(a.azimuth, a.elevation, a.distance),
            a.brightness,
        )],
    };
    let dev = device::inference();
    let images = environment::form_images(&renderer, &env, &conds, &atlas, &dev)?;
    let img = if images.len() == 1 {
        images.into_iter().next().unwrap()
    } else {
        cac::render::contact_sheet(&images)
    };
    cac::io::save_png_atomic(&a.out, &img)?;
    println!(
        "wrote {} ({} view{})",
        a.out.display(),
        conds.len(),
        if conds.len() == 1 { "" } else { "s" }
    );
    Ok(())
}
