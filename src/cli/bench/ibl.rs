//! `cac bench ibl`: cac's image-based lighting against Cycles rendering the same views with the
//! same HDR environment, per knob (spherical-harmonic order, occlusion rays): error in 8-bit
//! levels on the object and the whole image, against Cycles and against cac's finest setting,
//! and shading time per view. Measured by `cac::bench::ibl`; this prints and writes CSV.

use crate::cli::device;
use anyhow::Result;
use cac::bench::ibl::{self as ibl_bench, IblBenchJob};
use cac::config::SceneConfig;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Built-in object name or mesh file.
    #[arg(long, default_value = "pickup")]
    pub mesh: String,
    /// HDR environments: Blender's (city, courtyard, forest, interior, night, studio, sunrise,
    /// sunset) or equirectangular EXR/HDR files.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "city,interior,night,sunset"
    )]
    pub hdri: Vec<String>,
    /// Free viewpoints per environment (the config's distribution, seeded).
    #[arg(long, default_value_t = 6)]
    pub views: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Image side (pixels).
    #[arg(long, default_value_t = 416)]
    pub size: usize,
    /// Samples per pixel of cac's renderer.
    #[arg(long, default_value_t = 4)]
    pub samples: usize,
    /// Cycles samples per pixel.
    #[arg(long, default_value_t = 64)]
    pub blender_samples: usize,
    /// Scene config whose [render] field of view and [environment] are used.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// CSV output file.
    #[arg(long, default_value = "bench-ibl.csv")]
    pub csv: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let mut cfg = SceneConfig::from_file_or(a.config.as_deref(), SceneConfig::default)?;
    (cfg.render.width, cfg.render.height, cfg.render.samples) = (a.size, a.size, a.samples);
    let mut blender = cac::eval::blender::BlenderSettings {
        samples: a.blender_samples,
        ..Default::default()
    };
    if let Some(exe) = std::env::var_os("CAC_BLENDER") {
        blender.executable = exe.into();
    }
    println!("renderer 2: {}", cac::eval::blender::check(&blender)?);
    let job = IblBenchJob {
        mesh: a.mesh,
        hdri: a.hdri,
        views: a.views,
        seed: a.seed,
        cfg,
        blender,
    };
    println!(
        "{} free views per environment, {}² px, cac {} spp, Cycles {} spp; MAE in 8-bit levels (object: pixels both renderers cover fully)",
        job.views, a.size, a.samples, a.blender_samples
    );
    println!("environment  sh_order  rays  prefilter  shade_ms  object_vs_cycles  image_vs_cycles  object_vs_finest  object_px");
    let t = ibl_bench::run(&job, &device::inference(), &mut |r| {
        println!(
            "{:<12} {:>8} {:>5} {:>10} {:>9} {:>17} {:>16} {:>17} {:>10}",
            r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]
        )
    })?;
    cac::io::write_atomic(&a.csv, t.csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}
