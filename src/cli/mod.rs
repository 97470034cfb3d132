//! Subcommand dispatch. Each subcommand lives in its own file.

use anyhow::Result;
use clap::{Parser, Subcommand};

pub mod device;

/// Learn, fabricate and physically test coated adversarial camouflages.
#[derive(Parser, Debug)]
#[command(name = "cac", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {}
}
