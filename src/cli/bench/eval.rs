//! `cac bench eval`: images scored per second, end to end (render + detect + score), for each
//! detector alone and for all of them sharing one render, on the protocol's FV views of the
//! default pickup. Prints a table and writes CSV. A benchmark, not a test: it asserts nothing.

use super::timer::Stopwatch;
use crate::cli::{device, train};
use anyhow::{bail, Result};
use burn::tensor::Tensor;
use cac::config::{SceneConfig, Stage};
use cac::detect::Detector;
use cac::environment::{self, Brightness, Condition, Environment, ViewpointSet};
use cac::eval::{score_image, Protocol};
use cac::render::{self, Renderer};
use cac::report::Table;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Timed images per row (after one warm-up image).
    #[arg(long, default_value_t = 8)]
    pub images: usize,
    /// Detectors, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::detect::ModelSpec, default_value = "centernet,nanodet")]
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
    let Stage {
        renderer: r,
        env,
        original: atlas,
    } = cfg.stage()?;
    let dets = train::load_detectors(&a.models)?;
    let dev = device::inference();
    let p = Protocol::default();
    let conds = env.sample_n(a.images + 1, ViewpointSet::Free, Brightness::Bright, 7);
    let a_t = render::atlas_tensor(&atlas, &dev);
    let mut t = Table::new([
        "detectors",
        "size",
        "spp",
        "images",
        "render_ms",
        "detect_ms",
        "score_ms",
        "total_ms",
        "images_per_s",
    ]);
    let mut rows: Vec<Vec<usize>> = (0..dets.len()).map(|k| vec![k]).collect();
    if dets.len() > 1 {
        rows.push((0..dets.len()).collect());
    }
    for which in rows {
        let (mut tr, mut td, mut ts, mut n) = (0.0, 0.0, 0.0, 0);
        let chosen: Vec<&dyn Detector> = which.iter().map(|&k| dets[k].as_ref()).collect();
        for (i, c) in conds.iter().enumerate() {
            let (render_s, detect_s, score_s) = time_image(&r, &env, c, a_t.clone(), &chosen, &p)?;
            if i == 0 {
                continue; // warm-up
            }
            tr += render_s;
            td += detect_s;
            ts += score_s;
            n += 1;
        }
        let names: Vec<&str> = which.iter().map(|&k| dets[k].name()).collect();
        let total = tr + td + ts;
        let ms = |s: f64| format!("{:.1}", 1e3 * s / n as f64);
        t.row([
            names.join("+"),
            format!("{}", a.size),
            format!("{}", a.samples),
            n.to_string(),
            ms(tr),
            ms(td),
            ms(ts),
            ms(total),
            format!("{:.2}", n as f64 / total),
        ]);
    }
    println!(
        "end-to-end evaluation throughput ({}, FV bright views, {}x{}, {} spp):\n",
        a.object, a.size, a.size, a.samples
    );
    print!("{}", t.markdown());
    cac::io::write_atomic(&a.csv, t.csv().as_bytes())?;
    println!("\nwrote {}", a.csv.display());
    Ok(())
}

/// Seconds to form one image of `c`, to detect with `dets`, and to score the detections.
fn time_image(
    r: &Renderer,
    env: &Environment,
    c: &Condition,
    atlas: Tensor<4>,
    dets: &[&dyn Detector],
    p: &Protocol,
) -> Result<(f64, f64, f64)> {
    let t0 = Stopwatch::start();
    let (img, plans) = environment::form(r, env, std::slice::from_ref(c), atlas)?;
    let gt = plans[0].object_box.unwrap_or([0.0; 4]);
    let _ = img.clone().slice([0..1, 0..1, 0..1, 0..1]).into_data();
    let render_s = t0.secs();
    let t1 = Stopwatch::start();
    let mut found = vec![];
    for d in dets {
        found.push(d.detect(img.clone())?.remove(0));
    }
    let detect_s = t1.secs();
    let t2 = Stopwatch::start();
    let hits = found.iter().filter(|f| score_image(f, &gt, p).hit).count();
    std::hint::black_box(hits);
    Ok((render_s, detect_s, t2.secs()))
}
