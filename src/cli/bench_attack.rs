//! `cac bench attack`: (1) iteration time split into render / detector forward (+ proposal
//! selection and loss) / backward / optimiser, batch 1 and 4 at 512×512 on the default scene;
//! (2) white-box P@0.5 and targeted success against training wall time for a few settings of
//! batch size, n and texture resolution (the demo's scene and street-level views). Prints tables
//! and writes CSVs. A benchmark, not a test: it asserts nothing.

use super::{demo, device, train};
use anyhow::Result;
use cac::attack::{loss::Goal, AttackConfig, Trainer};
use cac::config::SceneConfig;
use cac::environment::{Brightness, Environment};
use cac::eval::{self, Protocol};
use cac::render::{RenderSettings, Renderer};
use std::path::PathBuf;
use std::time::Instant;

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
    /// Instead: compare CAC, the baselines and the simple textures (trains each method for
    /// --iterations) and write PREFIX-methods.csv.
    #[arg(long)]
    pub methods: bool,
    /// Skip the error-against-time part.
    #[arg(long)]
    pub split_only: bool,
    /// CSV prefix: writes PREFIX-split.csv and PREFIX-error.csv.
    #[arg(long, default_value = "bench-attack")]
    pub csv: PathBuf,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

pub fn run(a: Args) -> Result<()> {
    if a.runs == 0 || a.eval_every == 0 || a.views == 0 {
        anyhow::bail!("--runs, --eval-every and --views must be positive");
    }
    parse_settings(&a.settings)?;
    if a.methods {
        let p = a.csv.with_file_name(format!(
            "{}-methods.csv",
            a.csv
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or("bench-attack")
        ));
        return super::bench::methods::run(a.iterations, a.views, &p);
    }
    let dets = train::load_detectors(&["nanodet".into()])?;
    let det = [dets[0].as_ref()];
    // (1) Time split on the default scene (512², 4 spp, 512² atlas).
    let cfg = SceneConfig::default();
    let renderer = Renderer::new(cfg.object.load()?, cfg.render.clone())?;
    let env = Environment::new(cfg.environment.clone())?;
    let init = renderer.scene.initial_atlas(cfg.render.atlas_res);
    println!("iteration time, nanodet, n = 300, {}x{} renders ({} spp), {}² atlas, CPU (median of {} after 1 warm-up)", cfg.render.width, cfg.render.height, cfg.render.samples, cfg.render.atlas_res, a.runs);
    println!(
        "{:>5} {:>10} {:>11} {:>12} {:>13} {:>9}",
        "batch", "render_ms", "forward_ms", "backward_ms", "optimiser_ms", "total_ms"
    );
    let mut split =
        vec!["batch,render_ms,forward_ms,backward_ms,optimiser_ms,total_ms".to_string()];
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
        let m = |f: fn(&cac::attack::IterationLog) -> f64| median(logs.iter().map(f).collect());
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
        split.push(format!(
            "{batch},{r:.1},{f:.1},{b:.1},{o:.2},{:.1}",
            r + f + b + o
        ));
    }
    let p = a.csv.with_file_name(format!(
        "{}-split.csv",
        a.csv
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("bench-attack")
    ));
    cac::io::write_atomic(&p, (split.join("\n") + "\n").as_bytes())?;
    println!("wrote {}", p.display());
    if a.split_only {
        return Ok(());
    }
    // (2) Error against time on the demo's scene and views.
    let dcfg = demo::demo_scene();
    let denv = Environment::new(dcfg.environment.clone())?;
    let mut views = eval::street_views(a.views, 1.5, Brightness::Bright);
    views.extend(eval::street_views(a.views, 1.5, Brightness::Dark));
    let proto = Protocol {
        target: Some(0),
        ..Default::default()
    };
    let inf = device::inference();
    let settings = parse_settings(&a.settings)?;
    println!("\nwhite-box error against training time: nanodet, target \"person\", demo scene (320², 1 spp), {} street-level views (416², 4 spp)", views.len());
    println!(
        "{:>5} {:>5} {:>7} {:>10} {:>10} {:>7} {:>14}",
        "batch", "n", "texture", "iterations", "train_s", "P@0.5", "person_success"
    );
    let mut rows =
        vec!["batch,n,texture_res,iterations,train_s,p_at_05,targeted_success".to_string()];
    for (batch, n, res) in settings {
        let mut c = dcfg.clone();
        c.render.atlas_res = res;
        let r = Renderer::new(renderer.scene.clone(), c.render.clone())?;
        let eval_r = Renderer::new(
            renderer.scene.clone(),
            RenderSettings {
                width: 416,
                height: 416,
                samples: 4,
                ..c.render.clone()
            },
        )?;
        let score = |atlas: &cac::scene::Texture| -> Result<eval::Summary> {
            let r = eval::evaluate(&eval_r, &denv, &views, atlas, &det, &proto, &inf)?;
            Ok(eval::summarise(&r.scores[0]))
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
        let s0 = score(&original)?;
        let mut report = |it: usize, secs: f64, s: &eval::Summary| {
            println!(
                "{batch:>5} {n:>5} {res:>7} {it:>10} {secs:>10.1} {:>7.3} {:>14.3}",
                s.p_at_05, s.targeted_success
            );
            rows.push(format!(
                "{batch},{n},{res},{it},{secs:.2},{:.4},{:.4}",
                s.p_at_05, s.targeted_success
            ));
        };
        report(0, 0.0, &s0);
        while tr.state.iteration < a.iterations {
            let t = Instant::now();
            tr.step()?;
            secs += t.elapsed().as_secs_f64();
            let it = tr.state.iteration;
            if it % a.eval_every == 0 || it == a.iterations {
                let s = score(&tr.atlas())?;
                report(it, secs, &s);
            }
        }
    }
    let p = a.csv.with_file_name(format!(
        "{}-error.csv",
        a.csv
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("bench-attack")
    ));
    cac::io::write_atomic(&p, (rows.join("\n") + "\n").as_bytes())?;
    println!("wrote {}", p.display());
    Ok(())
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
