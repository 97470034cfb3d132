//! The attack benchmark's measurements (`cac bench attack`): (1) the iteration time split into
//! render / detector forward (+ proposal selection and loss) / backward / optimiser, batch 1 and
//! 4 at 512×512 on the default scene; (2) white-box P@0.5 and targeted success against training
//! wall time for a few settings of batch size, n and texture resolution (the demo's scene and
//! street-level views, scored with `eval`). Each part prints its rows as they are measured and
//! returns them as a [`Table`] for CSV. Timed with the one timer (`report::timer`).

use anyhow::Result;
use burn::tensor::Device;
use cac_attack::loss::Goal;
use cac_attack::AttackConfig;
use cac_attack::IterationLog;
use cac_attack::Trainer;
use cac_core::report::timer::{median, Stopwatch};
use cac_core::report::Table;
use cac_detect::Detector;
use cac_eval::Protocol;
use cac_render::config::{self, SceneConfig};
use cac_render::environment::{street_views, Brightness, Environment};
use cac_render::Renderer;
use cac_scene::{Scene, Texture};

/// One error-against-time setting: batch size, n, atlas side.
pub type Setting = (usize, usize, usize);

/// (1) The iteration time split on the default scene (512², 4 spp, 512² atlas): the median of
/// `runs` iterations after one warm-up, per batch size; with a `printer` profile, each batch
/// also trained through it (side by side). Returns the table and the scene.
pub fn time_split(
    runs: usize,
    det: &[&dyn Detector],
    device: &Device,
    printer: Option<&std::path::Path>,
) -> Result<(Table, Scene)> {
    let cfg = SceneConfig::default();
    let config::Stage {
        renderer,
        env,
        original: init,
    } = cfg.stage()?;
    println!("iteration time, nanodet, n = 300, {}x{} renders ({} spp), {}² atlas, CPU (median of {} after 1 warm-up)", cfg.render.width, cfg.render.height, cfg.render.samples, cfg.render.atlas_res, runs);
    println!(
        "{:>5} {:>8} {:>10} {:>11} {:>12} {:>13} {:>9} {:>8}",
        "batch",
        "printer",
        "render_ms",
        "forward_ms",
        "backward_ms",
        "optimiser_ms",
        "total_ms",
        "peak_mb"
    );
    let columns = [
        "render_ms",
        "forward_ms",
        "backward_ms",
        "optimiser_ms",
        "total_ms",
        "peak_mb",
    ];
    let mut split = Table::new(["batch", "printer"].into_iter().chain(columns));
    let printers = std::iter::once(None).chain(printer.map(Some));
    let printers: Vec<Option<&std::path::Path>> = printers.collect();
    for (batch, printer) in [1usize, 4]
        .into_iter()
        .flat_map(|b| printers.iter().map(move |p| (b, *p)))
    {
        let ac = AttackConfig {
            batch,
            iterations: runs + 1,
            checkpoint_every: 0,
            printer: printer.map(|p| p.to_path_buf()),
            ..Default::default()
        };
        let training = Device::autodiff(device.clone());
        cac_core::memory::reset_peak_rss();
        let tr = Trainer::new(ac.clone(), &renderer, &env, det.to_vec(), training, &init)?;
        let mut tr = tr.through_printer(&ac)?;
        let pname = if printer.is_some() { "fdm" } else { "none" };
        tr.step()?;
        let logs: Vec<_> = (0..runs).map(|_| tr.step()).collect::<Result<_>>()?;
        let m = |f: fn(&IterationLog) -> f64| median(logs.iter().map(f).collect());
        let (r, f, b, o) = (
            m(|l| l.ms_render),
            m(|l| l.ms_forward),
            m(|l| l.ms_backward),
            m(|l| l.ms_optimiser),
        );
        let total = r + f + b + o;
        let peak = cac_core::memory::peak_rss_mb();
        println!(
            "{batch:>5} {pname:>8} {r:>10.0} {f:>11.0} {b:>12.0} {o:>13.1} {total:>9.0} {peak:>8.0}"
        );
        split.row([
            batch.to_string(),
            pname.to_string(),
            format!("{r:.1}"),
            format!("{f:.1}"),
            format!("{b:.1}"),
            format!("{o:.2}"),
            format!("{total:.1}"),
            format!("{peak:.0}"),
        ]);
    }
    Ok((split, renderer.scene.clone()))
}

/// (2) White-box error against training time on the demo's scene and street-level
/// views per brightness (`per_level`): each setting trains `iterations` iterations, scored before training and
/// every `eval_every` iterations.
pub fn error_against_time(
    (iterations, eval_every, per_level): (usize, usize, usize),
    det: &[&dyn Detector],
    scene: &Scene,
    settings: &[Setting],
    device: &Device,
) -> Result<Table> {
    let dcfg = SceneConfig::training();
    let denv = Environment::new(dcfg.environment.clone())?;
    let mut views = street_views(per_level, 1.5, Brightness::Bright);
    views.extend(street_views(per_level, 1.5, Brightness::Dark));
    let proto = Protocol {
        target: Some(0),
        ..Default::default()
    };
    let mut rows = error_header(views.len());
    for &(batch, n, res) in settings {
        let mut c = dcfg.clone();
        c.render.atlas_res = res;
        let r = Renderer::new(scene.clone(), c.render.clone())?;
        let eval_r = Renderer::new(scene.clone(), config::eval_render(&c.render))?;
        let score = |atlas: &Texture| -> Result<cac_eval::Summary> {
            let r = cac_eval::evaluate(&eval_r, &denv, &views, atlas, det, &proto, device)?;
            Ok(cac_eval::summarise(&r.scores[0]))
        };
        let mut report = |it: usize, secs: f64, s: &cac_eval::Summary| {
            let (p, t) = (s.p_at_05, s.targeted_success);
            println!("{batch:>5} {n:>5} {res:>7} {it:>10} {secs:>10.1} {p:>7.3} {t:>14.3}");
            rows.row([
                batch.to_string(),
                n.to_string(),
                res.to_string(),
                it.to_string(),
                format!("{secs:.2}"),
                format!("{p:.4}"),
                format!("{t:.4}"),
            ]);
        };
        let original = r.scene.initial_atlas(res);
        let ac = AttackConfig {
            batch,
            top_n: n,
            iterations,
            checkpoint_every: 0,
            ..Default::default()
        };
        if det
            .iter()
            .any(|d| ac.goal_for(*d).ok() != Some(Goal::Targeted(0)))
        {
            anyhow::bail!("the default target must be person");
        }
        let training = Device::autodiff(device.clone());
        cac_core::memory::reset_peak_rss();
        let mut tr = Trainer::new(ac, &r, &denv, det.to_vec(), training, &original)?;
        let mut secs = 0.0;
        report(0, 0.0, &score(&original)?);
        while tr.state.iteration < iterations {
            let t = Stopwatch::start();
            tr.step()?;
            secs += t.secs();
            let it = tr.state.iteration;
            if it % eval_every == 0 || it == iterations {
                report(it, secs, &score(&tr.atlas())?);
            }
        }
    }
    Ok(rows)
}

/// Prints the error table's heading for `views` views; returns the CSV table.
fn error_header(views: usize) -> Table {
    println!("\nwhite-box error against training time: nanodet, target \"person\", demo scene (320², 1 spp), {} street-level views (416², 4 spp)", views);
    println!(
        "{:>5} {:>5} {:>7} {:>10} {:>10} {:>7} {:>14}",
        "batch", "n", "texture", "iterations", "train_s", "P@0.5", "person_success"
    );
    Table::new([
        "batch",
        "n",
        "texture_res",
        "iterations",
        "train_s",
        "p_at_05",
        "targeted_success",
    ])
}
