//! `cac bench attack --methods`: CAC, the four attack baselines and the three simple textures in one
//! harness: each attack trained for the same iterations (batch 2, n = 300, the demo's scene), then
//! every texture scored on the same street-level views by NanoDet (white-box) and CenterNet
//! (transfer). Prints a table and writes a CSV. A benchmark, not a test.

use super::timer::Stopwatch;
use crate::cli::{device, train};
use anyhow::Result;
use cac::attack::baselines::atlas::{paint, paintable_texels};
use cac::attack::{AttackConfig, Method, Trainer};
use cac::config;
use cac::environment::{street_views, Brightness};
use cac::eval::{self, Protocol};
use cac::render::Renderer;
use cac::report::Table;
use cac::scene::textures::{self, Kind};
use std::path::Path;

pub fn run(iterations: usize, views_per_level: usize, csv: &Path) -> Result<()> {
    let cfg = config::SceneConfig::training();
    let res = cfg.render.atlas_res;
    let config::Stage {
        renderer: r,
        env,
        original,
    } = cfg.stage()?;
    let eval_r = Renderer::new(r.scene.clone(), config::eval_render(&cfg.render))?;
    let dets = train::load_detectors(&["nanodet".into(), "centernet".into()])?;
    let all: Vec<&dyn cac::detect::Detector> = dets.iter().map(|d| d.as_ref()).collect();
    let mut views = street_views(views_per_level, 1.5, Brightness::Bright);
    views.extend(street_views(views_per_level, 1.5, Brightness::Dark));
    let proto = Protocol {
        target: Some(0),
        ..Default::default()
    };
    let mask = paintable_texels(&r.scene, res);
    let mut rows = header(views.len(), iterations);
    let mut report = |name: &str, secs: f64, atlas: &cac::scene::Texture| -> Result<()> {
        let out = eval::evaluate(
            &eval_r,
            &env,
            &views,
            atlas,
            &all,
            &proto,
            &device::inference(),
        )?;
        let (n, c) = (
            eval::summarise(&out.scores[0]),
            eval::summarise(&out.scores[1]),
        );
        println!(
            "{name:<13} {secs:>8.0} {:>12.3} {:>15.3} {:>14.3} {:>17.3}",
            n.p_at_05, n.targeted_success, c.p_at_05, c.targeted_success
        );
        rows.row([
            name.to_string(),
            format!("{secs:.1}"),
            format!("{:.4}", n.p_at_05),
            format!("{:.4}", n.targeted_success),
            format!("{:.4}", c.p_at_05),
            format!("{:.4}", c.targeted_success),
        ]);
        Ok(())
    };
    report("original", 0.0, &original)?;
    for kind in [Kind::Natural, Kind::Naive, Kind::Random] {
        // Simple textures go on the paintable texels only, like every attack's atlas.
        let a = paint(&original, &textures::generate(kind, res, 0)?, &mask);
        report(&format!("{kind:?}").to_lowercase(), 0.0, &a)?;
    }
    for method in Method::ALL {
        let ac = AttackConfig {
            method,
            iterations,
            batch: 2,
            checkpoint_every: 0,
            ..Default::default()
        };
        let mut tr = Trainer::new(ac, &r, &env, vec![all[0]], device::training(), &original)?;
        let t = Stopwatch::start();
        while tr.state.iteration < iterations {
            tr.step()?;
        }
        report(method.name(), t.secs(), &tr.atlas())?;
    }
    cac::io::write_atomic(csv, rows.csv().as_bytes())?;
    println!("wrote {}", csv.display());
    Ok(())
}

/// Prints the table's heading; returns the CSV table.
fn header(views: usize, iterations: usize) -> Table {
    println!("{views} views (416², 4 spp); P@0.5 = car/truck at IoU >= 0.5, conf >= 0.3; {iterations} iterations, batch 2, n = 300, target person");
    println!(
        "{:<13} {:>8} {:>12} {:>15} {:>14} {:>17}",
        "texture",
        "train_s",
        "nanodet P@.5",
        "nanodet person",
        "centernet P@.5",
        "centernet person"
    );
    Table::new([
        "texture",
        "train_s",
        "nanodet_p05",
        "nanodet_person",
        "centernet_p05",
        "centernet_person",
    ])
}
