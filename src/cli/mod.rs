//! Subcommand dispatch. Each subcommand lives in its own file.

use anyhow::Result;
use clap::{Parser, Subcommand};

pub mod bench_render;
pub mod config;
pub mod demo;
pub mod device;
pub mod meshes;
pub mod render;

/// Learn, fabricate and physically test coated adversarial camouflages.
#[derive(Parser, Debug)]
#[command(name = "cac", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Run the main job on the embedded defaults.
    Demo(demo::Args),
    /// Render one view, or a contact sheet of sampled views.
    Render(render::Args),
    /// The built-in default objects.
    #[command(subcommand)]
    Meshes(meshes::Cmd),
    /// Benchmarks (print a table, write CSV).
    #[command(subcommand)]
    Bench(BenchCmd),
    /// Print the default scene config (TOML), or check a config file.
    Config(config::Args),
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Demo(a) => demo::run(a),
        Command::Render(a) => render::run(a),
        Command::Meshes(c) => meshes::run(c),
        Command::Config(a) => config::run(a),
        Command::Bench(b) => match b {
            BenchCmd::Render(a) => bench_render::run(a),
        },
    }
}

/// The benchmarks.
#[derive(Subcommand, Debug)]
pub enum BenchCmd {
    /// BVH build, rays/s (1 and 2 threads, against Embree), anti-aliasing error against time.
    Render(bench_render::Args),
}
