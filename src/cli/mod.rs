//! Subcommand dispatch. Each subcommand lives in its own file.

use anyhow::Result;
use clap::{Parser, Subcommand};

pub mod device;
pub mod export;

/// Learn, fabricate and physically test coated adversarial camouflages.
#[derive(Parser, Debug)]
#[command(name = "cac", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Bake a learned texture into 3MF, OBJ and paste-on sheets.
    Export(export::Args),
    /// Bake error against triangles and seconds for several subdivision limits.
    BenchExport(export::BenchArgs),
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Export(a) => export::run(a),
        Command::BenchExport(a) => export::bench(a),
    }
}
