//! The ONNX fixtures the ONNX test binaries share: `tools/onnx/make_models.py`'s single-op
//! graphs and detector exports with onnxruntime's outputs, and torchvision's SSDlite, built once
//! per script version into the target's test folder (test binaries run one after another).
#![allow(dead_code)]

use crate::support;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

#[derive(Deserialize)]
pub struct Entry {
    pub name: String,
    pub file: String,
    pub kind: String,
    pub opset: i64,
    pub outputs: Vec<String>,
    /// How far onnxruntime's own output moves with float rounding (the ultralytics exports).
    #[serde(default)]
    pub noise: f64,
    /// How a file that selects its boxes inside selects them (`topk`, `nms`).
    #[serde(default)]
    pub selects: String,
}

#[derive(Deserialize)]
pub struct Manifest {
    pub models: Vec<Entry>,
}

/// `name` under the target's test folder, (re)built by `build` into that folder whenever the
/// bytes of the `tools/onnx` scripts `scripts` change (a SHA-256 stamp file beside the fixtures).
pub fn built_once(name: &str, scripts: &[&str], build: impl FnOnce(&Path)) -> PathBuf {
    let tools = support::root().join("tools/onnx");
    let mut text = Vec::new();
    for f in scripts {
        text.extend(std::fs::read(tools.join(f)).unwrap());
    }
    use sha2::Digest;
    let stamp = format!("{:x}", sha2::Sha256::digest(&text));
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    if std::fs::read_to_string(dir.join("stamp")).ok().as_deref() != Some(stamp.as_str()) {
        let _ = std::fs::remove_dir_all(&dir);
        build(&dir);
        std::fs::write(dir.join("stamp"), &stamp).unwrap();
    }
    dir
}

/// Runs `python3 tools/onnx/SCRIPT ARGS...`; a failure fails the test with the script's output.
pub fn python(script: &str, args: &[&std::ffi::OsStr]) {
    let out = Command::new("python3")
        .arg(support::root().join("tools/onnx").join(script))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{script} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The fixtures folder, built once per script version (None: skipped outside CI).
pub fn fixtures() -> Option<&'static Path> {
    static F: OnceLock<Option<PathBuf>> = OnceLock::new();
    F.get_or_init(|| {
        if !support::require(
            "python3",
            &["-c", "import onnx, onnxruntime, numpy"],
            "python3 with onnx and onnxruntime (pip install, as .ci/run does)",
        ) {
            return None;
        }
        let scripts = ["make_models.py", "ort_run.py", "export_torchvision.py"];
        Some(built_once("onnx-fixtures", &scripts, |dir| {
            python("make_models.py", &[dir.as_os_str()]);
            // torchvision's SSDlite as its dense pre-NMS export (where torch is installed), its
            // --check: torchvision's own detections are rows of the dense output.
            if dir.join("yolov8n.onnx").is_file() {
                let out = dir.join("ssdlite.onnx");
                python(
                    "export_torchvision.py",
                    &["ssdlite".as_ref(), out.as_os_str(), "--check".as_ref()],
                );
            }
        }))
    })
    .as_deref()
}

pub fn manifest(dir: &Path) -> Manifest {
    serde_json::from_slice(&std::fs::read(dir.join("manifest.json")).unwrap()).unwrap()
}

/// The ultralytics exports must be there under CI.
pub fn has_ultralytics(dir: &Path) -> bool {
    let ok = dir.join("yolov8n.onnx").is_file();
    if !ok {
        support::missing(
            "ultralytics' YOLOv8n export",
            "pip install torch ultralytics onnxslim, as .ci/run does",
        );
    }
    ok
}
