//! Subcommand dispatch. Each subcommand lives in its own file.

use anyhow::Result;
use clap::{Parser, Subcommand};

pub mod bench;
pub mod detect;
pub mod device;
pub mod models;

/// Learn, fabricate and physically test coated adversarial camouflages.
#[derive(Parser, Debug)]
#[command(name = "cac", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Detect COCO objects in images (CenterNet or NanoDet, TFJS models on burn).
    Detect(detect::DetectArgs),
    /// Fetch or locate the detector model files.
    Models {
        #[command(subcommand)]
        cmd: models::ModelsCmd,
    },
    /// Benchmarks (timings are measured here, never in tests).
    Bench {
        #[command(subcommand)]
        cmd: bench::BenchCmd,
    },
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Detect(a) => detect::run(a),
        Command::Models { cmd } => models::run(cmd),
        Command::Bench { cmd } => bench::run(cmd),
    }
}
