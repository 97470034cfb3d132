//! `cac bench realism`: is the *original* vehicle recognised at all? P@0.5 of each detector for
//! each mesh × texture × renderer × viewpoint set × brightness, printed as a table and written as
//! CSV. Viewpoint sets: `street` (12-ish azimuths, elevation 5–15°, distance ratio 1.5, the
//! demo's evaluation views), `free` (the config's free viewpoint distribution) and `hemisphere`
//! (the same with elevation 0–90°). Photometric transforms are off unless `--photometric`.
//! With `--renderers cac,blender` every view is also re-rendered by Blender (Cycles, CPU) at the
//! same camera and lighting (see docs/blender.md). A benchmark, not a test: it asserts nothing.
//! Measured by `cac::eval::realism`; this prints the rows and writes the CSV files.

use crate::cli::device;
use anyhow::Result;
use cac::config::SceneConfig;
use cac::detect;
use cac::eval::realism::{self, RealismJob, Row, Which};
use cac::eval::{blender, Protocol};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub job: crate::cli::flags::eval::RealismFlags,
    /// Image side (pixels).
    #[arg(long, default_value_t = 416)]
    pub size: usize,
    /// Samples per pixel of cac's renderer.
    #[arg(long, default_value_t = 4)]
    pub samples: usize,
    /// Scene config whose [render] field of view and [environment] are used (default: defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Cycles samples per pixel for the Blender renderer.
    #[arg(long, default_value_t = 32)]
    pub blender_samples: usize,
    /// Cycles' light bounces for the Blender renderer (0: direct light only).
    #[arg(long, default_value_t = 4)]
    pub blender_bounces: usize,
    /// How the Blender renderer forms the image: linear (physical), display (light × colour on
    /// display values, as cac does), cac-surfaces (and cac's surface model and reflected sky)
    /// or cac (and cac's unoccluded ambient).
    #[arg(long, value_parser = crate::cli::values::choice::<blender::Shading>(), default_value = "linear")]
    pub blender_shading: blender::Shading,
    /// Blender's glossy rays see cac's sky rather than the uniform ambient world.
    #[arg(long)]
    pub blender_sky_reflections: bool,
    /// CSV output file.
    #[arg(long, default_value = "bench-realism.csv")]
    pub csv: PathBuf,
    /// Target class (by name, such as "person"): also report each detector's targeted
    /// success (a target-class box with IoU >= 0.5 and confidence >= 0.3).
    #[arg(long)]
    pub target: Option<String>,
    /// Also write one CSV row per view (viewpoint, hit and best confidence per detector).
    #[arg(long)]
    pub per_view: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    let mut job = RealismJob::from(a.job);
    job.cfg = SceneConfig::from_file_or(a.config.as_deref(), SceneConfig::default)?;
    let r = &mut job.cfg.render;
    (r.width, r.height, r.samples) = (a.size, a.size, a.samples);
    let b = &mut job.blender;
    (b.samples, b.bounces, b.shading) = (a.blender_samples, a.blender_bounces, a.blender_shading);
    b.sky_reflections = a.blender_sky_reflections;
    if let Some(exe) = std::env::var_os("CAC_BLENDER") {
        b.executable = exe.into();
    }
    b.work_dir = std::env::var_os("CAC_BLENDER_WORK").map(Into::into);
    job.protocol = Protocol::from_labels("car,truck", a.target.as_deref())?;
    let dev = device::inference();
    let dets = detect::load_all(&["nanodet", "centernet"], None, &dev)?;
    if job.renderers.contains(&Which::Blender) {
        println!("renderer 2: {}", blender::check(&job.blender)?);
    }
    println!(
        "P@0.5 = car/truck at IoU >= 0.5, conf >= 0.3; {}² px, {} spp (cac), {} spp, {} bounces, {:?} shading (Blender); {} views per row; photometric transforms {}",
        a.size, a.samples, a.blender_samples, a.blender_bounces, a.blender_shading, job.views, if job.photometric { "on" } else { "off" }
    );
    // The columns of `print_row`.
    println!("mesh             renderer texture   set        light        nanodet       conf   target centernet       conf   target      s");
    let all = cac::detect::refs(&dets);
    let t = realism::run(&job, &all, &dev, &mut print_row)?;
    cac::io::write_atomic(&a.csv, t.rows.csv().as_bytes())?;
    if let Some(p) = &a.per_view {
        cac::io::write_atomic(p, t.per_view.csv().as_bytes())?;
        println!("wrote {}", p.display());
    }
    println!("wrote {}", a.csv.display());
    if job.renderers.contains(&Which::Cac) && job.renderers.iter().any(|w| *w != Which::Cac) {
        // The renderers against each other on this run's views (pool runs: `cac bench agreement`).
        // A convenience after the measured rows: a failure here must not fail the run.
        let mut views = cac::eval::agreement::Views::default();
        match views
            .add_csv(&t.per_view.csv(), "this run")
            .and_then(|()| views.agreement())
        {
            Ok(ag) => super::agreement::print(&ag, 0.05),
            Err(e) => eprintln!("no agreement table: {e:#}"),
        }
    }
    Ok(())
}

fn print_row(r: &Row) {
    let [short, wname, tname, sname, bname] = &r.key;
    let (n, c, secs) = (&r.nanodet, &r.centernet, r.seconds);
    println!(
        "{short:<16} {wname:<8} {tname:<9} {sname:<10} {bname:<12} {:>8.3} {:>10.3} {:>8.3} {:>8.3} {:>10.3} {:>8.3} {secs:>6.0}",
        n.p_at_05,
        n.mean_best_true_conf,
        n.targeted_success,
        c.p_at_05,
        c.mean_best_true_conf,
        c.targeted_success
    );
}
