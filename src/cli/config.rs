//! `cac config`: print the default scene config, or check a file.

use anyhow::Result;
use cac::config::SceneConfig;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A config file to check; without it, the defaults are printed.
    #[arg(long)]
    pub check: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    match a.check {
        Some(p) => {
            SceneConfig::from_file(&p)?;
            println!("{}: ok", p.display());
        }
        None => print!("{}", SceneConfig::default_toml()),
    }
    Ok(())
}
