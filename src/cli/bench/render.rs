//! `cac bench render`: BVH build time and primary-ray throughput (1 and 2 threads, beside Embree
//! when it is installed) and the anti-aliasing error against time, measured by
//! `cac::render::bench` and `cac::environment::bench`. Prints tables and writes CSV.

use anyhow::{Context, Result};
use cac::environment::bench as aa_bench;
use cac::render::bench;
use std::path::PathBuf;
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder for the CSV files.
    #[arg(long, default_value = "bench-out")]
    pub out: PathBuf,
    /// Image side for the ray-throughput runs.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Timed repetitions (the best is reported).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Python interpreter for the Embree comparison.
    #[arg(long, default_value = "python3")]
    pub python: String,
}

pub fn run(a: Args) -> Result<()> {
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    println!(
        "{:<11} {:>9} {:>9} {:>7} {:>10} {:>11} {:>13} {:>12}",
        "scene",
        "triangles",
        "build ms",
        "threads",
        "Mrays/s",
        "embree Mr/s",
        "cac / embree",
        "G-buffer ms"
    );
    let scenes = bench::rays(a.size, a.repeats, &a.python)?;
    for s in &scenes {
        print_scene(s);
    }
    let rays_csv = a.out.join("render_rays.csv");
    cac::io::write_atomic(&rays_csv, bench::rays_table(&scenes).csv().as_bytes())?;
    let aa = aa_bench::anti_aliasing(a.repeats)?;
    println!(
        "\nanti-aliasing, 256x256 jeep, against 64 samples per pixel:\n{:>8} {:>12} {:>10}",
        "samples", "ms/frame", "PSNR dB"
    );
    for (spp, secs, psnr) in &aa {
        println!("{:>8} {:>12.1} {:>10.2}", spp, secs * 1e3, psnr);
    }
    let aa_csv = a.out.join("render_aa.csv");
    cac::io::write_atomic(&aa_csv, aa_bench::aa_table(&aa).csv().as_bytes())?;
    println!("\nwrote {} and {}", rays_csv.display(), aa_csv.display());
    Ok(())
}

/// One scene's rows and its note on Embree.
fn print_scene(s: &bench::RayScene) {
    for r in &s.runs {
        let mrays = r.mrays_per_s();
        let er = s.embree.map(|(_, r, _)| format!("{:.2}", r / 1e6));
        let ratio = s
            .embree
            .map(|(_, r, _)| format!("{:.2}", mrays * 1e6 / r))
            .unwrap_or_else(|| "n/a".into());
        println!(
            "{:<11} {:>9} {:>9.2} {:>7} {:>10.2} {:>11} {:>13} {:>12.1}",
            s.name,
            s.triangles,
            s.build_secs * 1e3,
            r.threads,
            mrays,
            er.as_deref().unwrap_or("n/a"),
            ratio,
            r.gbuffer_secs * 1e3
        );
    }
    match s.embree {
        None => println!(
            "  (Embree comparison skipped: `pip install trimesh embreex numpy` to enable it)"
        ),
        Some((_, _, eh)) if eh != s.hits => {
            println!(
                "  note: Embree hit {eh} rays, cac {} (edge rays may differ)",
                s.hits
            )
        }
        Some(_) => {}
    }
}
