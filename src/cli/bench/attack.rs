//! `cac bench attack`: (1) iteration time split into render / detector forward (+ proposal
//! selection and loss) / backward / optimiser, batch 1 and 4 at 512×512 on the default scene;
//! (2) white-box P@0.5 and targeted success against training wall time for a few settings of
//! batch size, n and texture resolution (the demo's scene and street-level views). Prints tables
//! and writes CSVs. A benchmark, not a test: it asserts nothing.

use super::timer::{median, Stopwatch};
use crate::cli::{device, train};
use anyhow::Result;
use cac::attack::{loss::Goal, AttackConfig, IterationLog, Trainer};
use cac::config::{self, SceneConfig};
use cac::detect::Detector;
use cac::environment::{street_views, Brightness, Environment};
use cac::eval::{self, Protocol};
use cac::render::Renderer;
use cac::report::Table;
use cac::scene::{Scene, Texture};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Timed iterations per batch size (after one warm-up iteration).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Iterations of each error-against-time run.
    #[arg(long, default_value_t = 120)]
    pub iterations: usize,
    /// Evaluate every this many iterations.
    #[arg(long, default_value_t = 40)]
    pub eval_every: usize,
    /// Street-level views per brightness level.
    #[arg(long, default_value_t = 12)]
    pub views: usize,
    /// Error-against-time settings, comma-separated BATCHxNxTEXTURE_RES.
    #[arg(
        long,
        default_value = "1x300x256,2x300x256,2x50x256,2x300x128,2x300x512"
    )]
    pub settings: String,
    /// Skip the error-against-time part.
    #[arg(long)]
    pub split_only: bool,
    /// CSV prefix: writes PREFIX-split.csv and PREFIX-error.csv.
    #[arg(long, default_value = "bench-attack")]
    pub csv: PathBuf,
}

/// `PREFIX-<what>.csv` beside the `--csv` prefix.
fn csv_path(a: &Args, what: &str) -> PathBuf {
    let prefix = a
        .csv
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("bench-attack");
    a.csv.with_file_name(format!("{prefix}-{what}.csv"))
}

pub fn run(a: Args) -> Result<()> {
    if a.runs == 0 || a.eval_every == 0 || a.views == 0 {
        anyhow::bail!("--runs, --eval-every and --views must be positive");
    }
    let settings = parse_settings(&a.settings)?;
    let dets = train::load_detectors(&["nanodet".into()])?;
    let det = [dets[0].as_ref()];
    let scene = time_split(&a, &det)?;
    if a.split_only {
        return Ok(());
    }
    error_against_time(&a, &det, &scene, settings)
}

/// (1) The iteration time split on the default scene (512², 4 spp, 512² atlas); returns the scene.
fn time_split(a: &Args, det: &[&dyn Detector]) -> Result<Scene> {
    let cfg = SceneConfig::default();
    let config::Stage {
        renderer,
        env,
        original: init,
    } = cfg.stage()?;
    println!("iteration time, nanodet, n = 300, {}x{} renders ({} spp), {}² atlas, CPU (median of {} after 1 warm-up)", cfg.render.width, cfg.render.height, cfg.render.samples, cfg.render.atlas_res, a.runs);
    println!(
        "{:>5} {:>10} {:>11} {:>12} {:>13} {:>9}",
        "batch", "render_ms", "forward_ms", "backward_ms", "optimiser_ms", "total_ms"
    );
    let mut split = Table::new([
        "batch",
        "render_ms",
        "forward_ms",
        "backward_ms",
        "optimiser_ms",
        "total_ms",
    ]);
    for batch in [1usize, 4] {
        let ac = AttackConfig {
            batch,
            iterations: a.runs + 1,
            checkpoint_every: 0,
            ..Default::default()
        };
        let mut tr = Trainer::new(ac, &renderer, &env, det.to_vec(), device::training(), &init)?;
        tr.step()?;
        let logs: Vec<_> = (0..a.runs).map(|_| tr.step()).collect::<Result<_>>()?;
        let m = |f: fn(&IterationLog) -> f64| median(logs.iter().map(f).collect());
        let (r, f, b, o) = (
            m(|l| l.ms_render),
            m(|l| l.ms_forward),
            m(|l| l.ms_backward),
            m(|l| l.ms_optimiser),
        );
        println!(
            "{batch:>5} {r:>10.0} {f:>11.0} {b:>12.0} {o:>13.1} {:>9.0}",
            r + f + b + o
        );
        split.row([
            batch.to_string(),
            format!("{r:.1}"),
            format!("{f:.1}"),
            format!("{b:.1}"),
            format!("{o:.2}"),
            format!("{:.1}", r + f + b + o),
        ]);
    }
    let p = csv_path(a, "split");
    cac::io::write_atomic(&p, split.csv().as_bytes())?;
    println!("wrote {}", p.display());
    Ok(renderer.scene.clone())
}

/// (2) White-box error against training time on the demo's scene and street-level views.
fn error_against_time(
    a: &Args,
    det: &[&dyn Detector],
    scene: &Scene,
    settings: Vec<(usize, usize, usize)>,
) -> Result<()> {
    let dcfg = SceneConfig::training();
    let denv = Environment::new(dcfg.environment.clone())?;
    let mut views = street_views(a.views, 1.5, Brightness::Bright);
    views.extend(street_views(a.views, 1.5, Brightness::Dark));
    let proto = Protocol {
        target: Some(0),
        ..Default::default()
    };
    let inf = device::inference();
    let mut rows = error_header(views.len());
    for (batch, n, res) in settings {
        let mut c = dcfg.clone();
        c.render.atlas_res = res;
        let r = Renderer::new(scene.clone(), c.render.clone())?;
        let eval_r = Renderer::new(scene.clone(), config::eval_render(&c.render))?;
        let score = |atlas: &Texture| -> Result<eval::Summary> {
            let r = eval::evaluate(&eval_r, &denv, &views, atlas, det, &proto, &inf)?;
            Ok(eval::summarise(&r.scores[0]))
        };
        let mut report = |it: usize, secs: f64, s: &eval::Summary| {
            println!(
                "{batch:>5} {n:>5} {res:>7} {it:>10} {secs:>10.1} {:>7.3} {:>14.3}",
                s.p_at_05, s.targeted_success
            );
            rows.row([
                batch.to_string(),
                n.to_string(),
                res.to_string(),
                it.to_string(),
                format!("{secs:.2}"),
                format!("{:.4}", s.p_at_05),
                format!("{:.4}", s.targeted_success),
            ]);
        };
        let original = r.scene.initial_atlas(res);
        let ac = AttackConfig {
            batch,
            top_n: n,
            iterations: a.iterations,
            checkpoint_every: 0,
            ..Default::default()
        };
        if ac.goal()? != Goal::Targeted(0) {
            anyhow::bail!("the default target must be person");
        }
        let mut tr = Trainer::new(ac, &r, &denv, det.to_vec(), device::training(), &original)?;
        let mut secs = 0.0;
        report(0, 0.0, &score(&original)?);
        while tr.state.iteration < a.iterations {
            let t = Stopwatch::start();
            tr.step()?;
            secs += t.secs();
            let it = tr.state.iteration;
            if it % a.eval_every == 0 || it == a.iterations {
                report(it, secs, &score(&tr.atlas())?);
            }
        }
    }
    let p = csv_path(a, "error");
    cac::io::write_atomic(&p, rows.csv().as_bytes())?;
    println!("wrote {}", p.display());
    Ok(())
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

/// `BATCHxNxRES,...` → `(batch, n, res)` triples.
fn parse_settings(s: &str) -> Result<Vec<(usize, usize, usize)>> {
    s.split(',')
        .map(|t| {
            let v: Vec<usize> = t
                .trim()
                .split('x')
                .map(|x| x.parse::<usize>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| anyhow::anyhow!("--settings: {t:?} is not BATCHxNxTEXTURE_RES"))?;
            match v[..] {
                [b, n, r] if b > 0 && n > 0 && (2..=8192).contains(&r) => Ok((b, n, r)),
                _ => anyhow::bail!(
                    "--settings: {t:?} is not BATCHxNxTEXTURE_RES with positive values"
                ),
            }
        })
        .collect()
}
