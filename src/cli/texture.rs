//! `cac texture`: write one of the simple baseline textures (Natural, Naive, Random) as a PNG.

use anyhow::{bail, Result};
use cac::scene::textures::{self, Kind};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Which texture.
    #[arg(value_parser = crate::cli::values::choice::<Kind>())]
    pub kind: Kind,
    /// Side in texels (2..=8192).
    #[arg(long, default_value_t = 512)]
    pub res: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    if a.out.extension().and_then(|e| e.to_str()) != Some("png") {
        bail!("--out {} must name a .png file", a.out.display());
    }
    let t = textures::generate(a.kind, a.res, a.seed)
        .map_err(|e| anyhow::anyhow!("--res {}: {e}", a.res))?;
    cac::io::save_png_atomic(&a.out, &t.to_rgb8())?;
    println!("wrote {} ({}², seed {})", a.out.display(), a.res, a.seed);
    Ok(())
}
