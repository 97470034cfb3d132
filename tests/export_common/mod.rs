//! Helpers shared by the export integration tests: inputs made at test time, and external tools
//! that must be present under CI (`CI=true`) and are skipped with a message locally (through
//! tests/support's `require`).
#![allow(dead_code)]

#[path = "../support/mod.rs"]
mod support;
pub use support::require;

use cac::export::{self, benchmark, ExportOptions, PrintMesh, Scale};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Writes a synthetic camouflage PNG of `res` texels into `dir`.
pub fn camo_png(dir: &Path, res: usize) -> PathBuf {
    let p = dir.join("camo.png");
    cac::io::save_png_atomic(&p, &benchmark::synthetic_camouflage(res, 5).to_rgb8()).unwrap();
    p
}

/// The print mesh the exporter builds for `mesh` with `texture` at `scale`.
pub fn print_mesh(mesh: &Path, texture: &Path, scale: Scale) -> PrintMesh {
    let opts = ExportOptions::default();
    let scene = export::load_mesh(mesh, &opts.load).unwrap();
    let camo = export::load_texture(texture, &Default::default()).unwrap();
    export::prepare(&scene, &camo, scale).unwrap()
}

/// The third-party truck of the shared folder (`None`, a failure under CI, when it is missing).
pub fn truck() -> Option<PathBuf> {
    support::require_path(
        &support::root().join("../shared/meshes/CesiumMilkTruck/CesiumMilkTruck.glb"),
        "the Cesium milk truck of ../shared (a third-party mesh)",
    )
}

/// lib3mf (Python) present?
pub fn have_lib3mf() -> bool {
    require(
        "python3",
        &["-c", "import lib3mf"],
        "lib3mf (pip install lib3mf)",
    )
}

/// Runs the lib3mf strict-mode checker on a 3MF and returns its JSON summary.
pub fn lib3mf_check(file: &Path) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/check_3mf.py");
    let o = Command::new("python3")
        .arg(script)
        .arg(file)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "lib3mf refused {}: {}",
        file.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

/// PrusaSlicer present?
pub fn have_prusa() -> bool {
    require(
        "prusa-slicer",
        &["--help"],
        "PrusaSlicer CLI (apt-get install prusa-slicer)",
    )
}

/// `prusa-slicer --info FILE`: the `key = value` lines.
pub fn prusa_info(file: &Path) -> std::collections::HashMap<String, String> {
    let o = Command::new("prusa-slicer")
        .arg("--info")
        .arg(file)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "PrusaSlicer failed on {}: {}{}",
        file.display(),
        out,
        String::from_utf8_lossy(&o.stderr)
    );
    out.lines()
        .filter_map(|l| l.split_once(" = "))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect()
}

/// Poppler's pdfinfo present?
pub fn have_pdfinfo() -> bool {
    require(
        "pdfinfo",
        &["-v"],
        "pdfinfo (apt-get install poppler-utils)",
    )
}
