//! `cac bench render`: BVH build time and primary-ray throughput (1 and 2 threads, beside Embree
//! when it is installed) and the anti-aliasing error against time, measured by
//! `cac::bench::render` and `cac::bench::anti_aliasing`. Prints tables and writes CSV.

use anyhow::{Context, Result};
use cac::bench::anti_aliasing as aa_bench;
use cac::bench::render as bench;
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
    let scenes = bench::rays(a.size, a.repeats, &a.python)?;
    let rays = bench::rays_table(&scenes);
    print!("{}", rays.markdown());
    for s in &scenes {
        match s.embree {
            None => println!(
                "{}: Embree comparison skipped (`pip install trimesh embreex numpy` enables it)",
                s.name
            ),
            Some((_, _, eh)) if eh != s.hits => println!(
                "{}: Embree hit {eh} rays, cac {} (edge rays may differ)",
                s.name, s.hits
            ),
            Some(_) => {}
        }
    }
    let rays_csv = a.out.join("render_rays.csv");
    cac::io::write_atomic(&rays_csv, rays.csv().as_bytes())?;
    let aa = aa_bench::aa_table(&aa_bench::anti_aliasing(a.repeats)?);
    println!("\nanti-aliasing, 256x256 jeep, against 64 samples per pixel:");
    print!("{}", aa.markdown());
    let aa_csv = a.out.join("render_aa.csv");
    cac::io::write_atomic(&aa_csv, aa.csv().as_bytes())?;
    println!("\nwrote {} and {}", rays_csv.display(), aa_csv.display());
    Ok(())
}
