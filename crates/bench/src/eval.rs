//! The evaluation benchmark's measurements (`cac bench eval`): images scored per second, end to
//! end (render + detect + score), for each detector alone and for all of them sharing one render,
//! on free-viewpoint bright views of a stage (the first view is a warm-up). Timed with the one
//! timer (`report::timer`); one [`Table`] row per detector set.

use anyhow::Result;
use burn::tensor::{Device, Tensor};
use cac_core::report::timer::Stopwatch;
use cac_core::report::Table;
use cac_detect::Detector;
use cac_eval::{score_image, Protocol};
use cac_render::config::Stage;
use cac_render::environment::{self, Brightness, Condition, Environment, ViewpointSet};
use cac_render::{self as render, Renderer};

/// Times `images` views (after one warm-up view) of `stage` with each detector of `dets` alone
/// and, with more than one, all together; `size` and `samples` label the rows.
pub fn throughput(
    stage: &Stage,
    dets: &[&dyn Detector],
    images: usize,
    (size, samples): (usize, usize),
    dev: &Device,
) -> Result<Table> {
    let Stage {
        renderer: r,
        env,
        original: atlas,
    } = stage;
    let p = Protocol::default();
    let conds = env.sample_n(images + 1, ViewpointSet::Free, Brightness::Bright, 7);
    let a_t = render::atlas_tensor(atlas, dev);
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
        "peak_mb",
    ]);
    let mut rows: Vec<Vec<usize>> = (0..dets.len()).map(|k| vec![k]).collect();
    if dets.len() > 1 {
        rows.push((0..dets.len()).collect());
    }
    for which in rows {
        let (mut tr, mut td, mut ts, mut n) = (0.0, 0.0, 0.0, 0);
        let chosen: Vec<&dyn Detector> = which.iter().map(|&k| dets[k]).collect();
        cac_core::memory::reset_peak_rss();
        for (i, c) in conds.iter().enumerate() {
            let (render_s, detect_s, score_s) = time_image(r, env, c, a_t.clone(), &chosen, &p)?;
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
            format!("{size}"),
            format!("{samples}"),
            n.to_string(),
            ms(tr),
            ms(td),
            ms(ts),
            ms(total),
            format!("{:.2}", n as f64 / total),
            format!("{:.0}", cac_core::memory::peak_rss_mb()),
        ]);
    }
    Ok(t)
}

/// Seconds to form one image of `c`, to detect with `dets`, and to score the detections.
pub(crate) fn time_image(
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
