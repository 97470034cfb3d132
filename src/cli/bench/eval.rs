//! `cac bench eval`: images scored per second, end to end (render + detect + score), for each
//! detector alone and for all of them sharing one render, on the protocol's FV views of the
//! default pickup. Prints a table and writes CSV. A benchmark, not a test: it asserts nothing.
//! Measured by `cac::bench::eval`.

use crate::cli::{device, train};
use anyhow::{bail, Result};
use cac::config::SceneConfig;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Timed images per row (after one warm-up image).
    #[arg(long, default_value_t = 8)]
    pub images: usize,
    /// Detectors, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::values::MODEL_SPECS, default_value = "centernet,nanodet")]
    pub models: Vec<String>,
    /// Image side in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Samples per pixel.
    #[arg(long, default_value_t = 4)]
    pub samples: usize,
    /// Object (pickup, jeep, barrel, container).
    #[arg(long, default_value = "pickup")]
    pub object: String,
    #[arg(long, default_value = "bench-eval.csv")]
    pub csv: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    if a.images == 0 {
        bail!("--images must be positive");
    }
    let mut cfg = SceneConfig::default();
    cfg.object.mesh = a.object.clone();
    (cfg.render.width, cfg.render.height, cfg.render.samples) = (a.size, a.size, a.samples);
    let stage = cfg.stage()?;
    let dets = train::load_detectors(&a.models)?;
    let refs = cac::detect::refs(&dets);
    let dev = device::inference();
    let t = cac::bench::eval::throughput(&stage, &refs, a.images, (a.size, a.samples), &dev)?;
    println!(
        "end-to-end evaluation throughput ({}, FV bright views, {}x{}, {} spp):\n",
        a.object, a.size, a.size, a.samples
    );
    print!("{}", t.markdown());
    cac::io::write_atomic(&a.csv, t.csv().as_bytes())?;
    println!("\nwrote {}", a.csv.display());
    Ok(())
}
