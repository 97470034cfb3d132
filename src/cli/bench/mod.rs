//! `cac bench …`: the benchmarks (the subcommands are listed in [`super::BenchCmd`]). Each prints
//! a table and writes CSV through [`cac::report::Table`], timed in the library with the one
//! timer (`cac::report::timer`), never in tests. A benchmark asserts nothing. (`cac bench export` lives in
//! `cli/export.rs`.)

pub mod agreement;
pub mod attack;
pub mod calibration;
pub mod detect;
pub mod eval;
pub mod frcnn;
pub mod ibl;
pub mod kernels;
pub mod realism;
pub mod render;
pub mod video;

use crate::cli::device::{self, Backend};
use cac::bench::detect::BenchDevice;

/// The backends a detector benchmark times side by side: those `--backends` names, else the one
/// `CAC_DEVICE` names, else every CPU backend of this build (Flex, and libtorch in a `tch`
/// build: both paths in one run).
pub fn backends(names: &[String]) -> anyhow::Result<Vec<BenchDevice>> {
    let chosen: Vec<Backend> = match (names.is_empty(), std::env::var_os("CAC_DEVICE")) {
        (false, _) => names
            .iter()
            .map(|n| Backend::parse(n).map_err(|e| anyhow::anyhow!("--backends: {e}")))
            .collect::<anyhow::Result<_>>()?,
        (true, Some(_)) => vec![device::backend()],
        (true, None) => Backend::cpus(),
    };
    Ok(chosen
        .into_iter()
        .map(|b| {
            let inference = b.device();
            BenchDevice {
                name: b.name().to_string(),
                training: burn::tensor::Device::autodiff(inference.clone()),
                inference,
            }
        })
        .collect())
}
