//! Subcommand dispatch. Each subcommand lives in its own file.

use anyhow::Result;
use clap::{Parser, Subcommand};

pub mod bench;
pub mod camera;
pub mod capture;
pub mod config;
pub mod demo;
pub mod detect;
pub mod device;
pub mod eval;
pub mod explain;
pub mod export;
pub mod flags;
pub mod meshes;
pub mod models;
pub mod print;
pub mod render;
pub mod score;
pub mod score_video;
pub mod slurm;
pub mod study;
pub mod texture;
pub mod train;
pub mod values;

/// Learn, fabricate and physically test coated adversarial camouflages.
#[derive(Parser, Debug)]
#[command(name = "cac", version, about)]
pub struct Cli {
    /// Memory budget (e.g. 4G, 12G): work estimated above it (a texture, a solid, a bake, a
    /// rendered view) is refused before it is allocated, naming the flag that makes it smaller.
    #[arg(long, global = true, default_value_t = cac::memory::MemoryBudget::default())]
    pub max_memory: cac::memory::MemoryBudget,
    #[command(subcommand)]
    pub command: Command,
}

// One command is parsed per run: the variants' sizes do not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Run the main job on the embedded defaults.
    Demo(flags::eval::DemoFlags),
    /// Learn a coated adversarial camouflage (the dense-proposals attack).
    Train(train::Args),
    /// Write a simple baseline texture (natural, naive, random) as a PNG.
    Texture(texture::Args),
    /// Render one view, or a contact sheet of sampled views.
    Render(render::Args),
    /// Detect COCO objects in images (CenterNet or NanoDet, TFJS models on burn).
    Detect(detect::DetectArgs),
    /// Fetch or locate the detector model files.
    Models {
        #[command(subcommand)]
        cmd: models::ModelsCmd,
    },
    /// The built-in default objects.
    #[command(subcommand)]
    Meshes(meshes::Cmd),
    /// Bake a learned texture into 3MF, OBJ and paste-on sheets.
    Export(export::Args),
    /// Print the default scene config (TOML), or check a config file.
    Config(config::Args),
    /// Score a recorded video or image sequence against annotations or a turntable log.
    ScoreVideo(score_video::Args),
    /// Physical test: turn, settle and capture frames into a session folder (or simulate).
    Capture(capture::Args),
    /// Check a V4L2 camera as a session will use it: lock it, capture a few frames, record
    /// what it runs at (camera.json).
    Camera(flags::physical::CameraCheckFlags),
    /// Score a capture session: P@0.5 per distance ratio and angle, JSON/CSV/HTML report.
    Score(score::Args),
    /// Evaluate textures: P@0.5, drop and targeted success in FV/RV, bright/dark views; reports.
    Eval(eval::Args),
    /// Grad-CAM attention map of a detector's class score for an image, as an overlay PNG.
    Explain(explain::Args),
    /// Studies built from training runs and evaluations (the top-n denseness study).
    #[command(subcommand)]
    Study(study::Cmd),
    /// Run an evaluation or a study as a Slurm sweep: job arrays and a dependent merge.
    #[command(subcommand)]
    Slurm(slurm::Cmd),
    /// Printers: write a calibration chart, fit a printer profile from its photograph.
    #[command(subcommand)]
    Print(print::Cmd),
    /// Benchmarks: print a table and write CSV (timings are measured here, never in tests).
    #[command(subcommand)]
    Bench(BenchCmd),
}

/// The benchmarks.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand, Debug)]
pub enum BenchCmd {
    /// BVH build, rays/s (1 and 2 threads, against Embree), anti-aliasing error against time.
    Render(bench::render::Args),
    /// The COCO detectors (burn) against the TFJS wasm runtime.
    Detect(bench::detect::DetectBench),
    /// The detectors' activations (fused kernels) against burn's composites and PyTorch.
    Kernels(bench::kernels::Args),
    /// Bake error against triangles and seconds for several subdivision limits.
    Export(export::BenchArgs),
    /// The attack: iteration time split, and white-box error against wall time.
    Attack(bench::attack::Args),
    /// Offline video scoring: decode frames/s and scored frames/s per detector and codec.
    Video(bench::video::Args),
    /// Evaluation throughput: images scored per second (render + detect + score) per detector.
    Eval(bench::eval::Args),
    /// Is the original vehicle recognised? P@0.5 per mesh, viewpoint set, light and renderer.
    Realism(bench::realism::Args),
    /// Image-based lighting: error against Cycles and time per knob (SH order, occlusion rays).
    Ibl(bench::ibl::Args),
    /// cac's renderer against a second one on the same views, pooled over `realism` runs.
    Agreement(bench::agreement::Args),
    /// Printer calibration on the twin: held-out ΔE2000 and fit time against the patch count.
    Calibration(bench::calibration::Args),
}

/// The stage the memory guard names until the command names its own.
fn stage_name(c: &Command) -> &'static str {
    match c {
        Command::Demo(_) => "demo",
        Command::Train(_) => "training",
        Command::Render(_) => "render",
        Command::Eval(_) => "evaluation",
        Command::Export(_) => "export",
        Command::Bench(_) => "benchmark",
        Command::Study(_) => "study",
        _ => "command",
    }
}

pub fn run(cli: Cli) -> Result<()> {
    cac::memory::stage(stage_name(&cli.command));
    cac::memory::set_process_budget(cli.max_memory);
    match cli.command {
        Command::Demo(a) => demo::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Explain(a) => explain::run(a),
        Command::Study(c) => study::run(c),
        Command::Slurm(c) => slurm::run(c),
        Command::Render(a) => render::run(a),
        Command::Texture(a) => texture::run(a),
        Command::Train(a) => train::run(a),
        Command::Detect(a) => detect::run(a),
        Command::Models { cmd } => models::run(cmd),
        Command::Meshes(c) => meshes::run(c),
        Command::Config(a) => config::run(a),
        Command::Export(a) => export::run(a),
        Command::ScoreVideo(a) => score_video::run(a),
        Command::Capture(a) => capture::run(a),
        Command::Camera(a) => camera::run(a),
        Command::Score(a) => score::run(a),
        Command::Print(c) => print::run(c),
        Command::Bench(BenchCmd::Render(a)) => bench::render::run(a),
        Command::Bench(BenchCmd::Detect(a)) => bench::detect::run(a),
        Command::Bench(BenchCmd::Kernels(a)) => bench::kernels::run(a),
        Command::Bench(BenchCmd::Export(a)) => export::bench(a),
        Command::Bench(BenchCmd::Attack(a)) => bench::attack::run(a),
        Command::Bench(BenchCmd::Video(a)) => bench::video::run(a),
        Command::Bench(BenchCmd::Eval(a)) => bench::eval::run(a),
        Command::Bench(BenchCmd::Realism(a)) => bench::realism::run(a),
        Command::Bench(BenchCmd::Ibl(a)) => bench::ibl::run(a),
        Command::Bench(BenchCmd::Agreement(a)) => bench::agreement::run(a),
        Command::Bench(BenchCmd::Calibration(a)) => bench::calibration::run(a),
    }
}

#[cfg(test)]
mod tests {
    /// clap's own checks of every subcommand's flags (see Cargo.toml: they run in release too).
    #[test]
    fn the_command_line_is_well_formed() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }
}
