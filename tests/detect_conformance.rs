//! Conformance of the burn detectors with the TensorFlow.js runtime (the reference runner
//! `../shared/reference/tfjs/detect.mjs`, cpu backend, is the oracle).
//!
//! For every image of `../shared/reference/images`: raw outputs within
//! `max|a-b| / max|b| <= 1e-4` per tensor, and the same final detections (labels, boxes within
//! 0.5 px, scores within 1e-4). The runner is installed (npm install in a copy under the target
//! folder, or `$CAC_TFJS_RUNNER`) and its dumps are cached under `target/tfjs-oracle`, keyed by a
//! SHA-256 of the model and its pinned digests, the settings, the image's bytes and the runner's
//! `detect.mjs` and `package.json`: a changed image or runner is run again. Every run must compare
//! at least one image, and every image it names. Without `../shared` it fails under CI
//! (`CI=true`) and is skipped, loudly, elsewhere.

mod support;

use cac::detect;
use cac::detect::raw::{relative_error, RawDump};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use support::models;

const REL_TOL: f64 = 1e-4;
const BOX_TOL: f64 = 0.5;
const SCORE_TOL: f64 = 1e-4;

fn shared_dir() -> Option<PathBuf> {
    let d = support::root().join("../shared");
    support::require_path(
        &d.join("reference/tfjs/detect.mjs"),
        "the TFJS reference runner of ../shared (detector conformance)",
    )?;
    Some(d)
}

/// `target/` (the folder above `release/deps/<this test>`).
fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    exe.ancestors().nth(3).unwrap().to_path_buf()
}

/// The runner's files that decide its output (hashed into the oracle cache key).
const RUNNER_FILES: [&str; 2] = ["detect.mjs", "package.json"];

/// The installed reference runner folder (installs it on first use, and again when its
/// [`RUNNER_FILES`] differ from those of `../shared`).
fn runner(shared: &Path) -> &'static PathBuf {
    static RUNNER: OnceLock<PathBuf> = OnceLock::new();
    RUNNER.get_or_init(|| {
        let dir = std::env::var_os("CAC_TFJS_RUNNER")
            .map(PathBuf::from)
            .unwrap_or_else(|| target_dir().join("tfjsref"));
        let src = shared.join("reference/tfjs");
        let stale = RUNNER_FILES
            .iter()
            .any(|f| std::fs::read(dir.join(f)).ok() != std::fs::read(src.join(f)).ok());
        if stale || !dir.join("node_modules/@tensorflow/tfjs").exists() {
            std::fs::create_dir_all(&dir).unwrap();
            for e in std::fs::read_dir(&src).unwrap() {
                let p = e.unwrap().path();
                if p.is_file() {
                    std::fs::copy(&p, dir.join(p.file_name().unwrap())).unwrap();
                }
            }
            eprintln!("installing the TFJS reference runner in {}", dir.display());
            let st = Command::new("npm")
                .args(["install", "--no-audit", "--no-fund", "--silent"])
                .current_dir(&dir)
                .status()
                .expect("npm is needed to install the TFJS reference runner");
            assert!(st.success(), "npm install of the reference runner failed");
        }
        dir
    })
}

fn images(shared: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(shared.join("reference/images"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "png" || e == "jpg"))
        .collect();
    v.sort();
    v
}

/// The oracle cache key of one case: a SHA-256 of the model, its pinned file digests, the
/// settings, the image's bytes and the runner's files (hex, 16 digits).
fn oracle_key(shared: &Path, model: &str, norm: &str, decode: &str, image: &Path) -> String {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    let mut field = |bytes: &[u8]| {
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    };
    for s in [model, norm, decode] {
        field(s.as_bytes());
    }
    for (name, digest) in detect::fetch::FILES {
        if name.starts_with(&format!("{model}.")) {
            field(digest.as_bytes());
        }
    }
    field(&std::fs::read(image).unwrap());
    for f in RUNNER_FILES {
        field(&std::fs::read(shared.join("reference/tfjs").join(f)).unwrap());
    }
    h.finalize()[..8]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The oracle's raw dump and detection list for one case (cached under [`oracle_key`]).
fn oracle(
    shared: &Path,
    model: &str,
    norm: &str,
    decode: &str,
    image: &Path,
) -> (PathBuf, PathBuf) {
    let dir = target_dir().join("tfjs-oracle");
    std::fs::create_dir_all(&dir).unwrap();
    let stem = image.file_stem().unwrap().to_string_lossy();
    let key = oracle_key(shared, model, norm, decode, image);
    let base = dir.join(format!("{model}-{norm}-{decode}-{stem}-{key}"));
    let raw = base.with_extension("raw.json");
    let dets = base.with_extension("dets.json");
    if raw.exists() && dets.exists() {
        return (raw, dets);
    }
    let run = runner(shared);
    let tmp_raw = base.with_extension("raw.json.tmp");
    let out = Command::new("node")
        .arg(run.join("detect.mjs"))
        .args([
            model,
            image.to_str().unwrap(),
            "--norm",
            norm,
            "--decode",
            decode,
        ])
        .arg("--raw")
        .arg(&tmp_raw)
        .arg("--models")
        .arg(models())
        .output()
        .expect("node is needed to run the TFJS reference runner");
    assert!(
        out.status.success(),
        "reference runner failed on {}: {}",
        image.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::write(base.with_extension("dets.json.tmp"), &out.stdout).unwrap();
    std::fs::rename(&tmp_raw, &raw).unwrap();
    std::fs::rename(base.with_extension("dets.json.tmp"), &dets).unwrap();
    (raw, dets)
}

#[derive(serde::Deserialize)]
struct RefDetection {
    label: String,
    class_id: usize,
    score: f64,
    #[serde(rename = "box")]
    bbox: [f64; 4],
}

/// Runs one model configuration over all images; panics listing every violation.
fn conformance(model: &str, norm: &str, decode: &str, detector_name: &str, only: Option<&[&str]>) {
    let Some(shared) = shared_dir() else { return };
    let device = support::device();
    let det = detect::load(detector_name, models(), &device).unwrap();
    let mut failures = Vec::new();
    let mut worst: Vec<(String, f64)> = Vec::new();
    let mut compared: Vec<String> = Vec::new();
    for image in images(&shared) {
        let stem = image.file_stem().unwrap().to_string_lossy().to_string();
        if only.is_some_and(|o| !o.contains(&stem.as_str())) {
            continue;
        }
        compared.push(stem.clone());
        let (raw_path, dets_path) = oracle(&shared, model, norm, decode, &image);
        let want = RawDump::read(&raw_path).unwrap();
        let img = cac::io::load_rgb(&image).unwrap();
        let x = detect::preprocess::image_to_tensor(&img, &device);
        let got = det.raw(x.clone()).unwrap();
        let input_err = relative_error(&got.input.values, &want.input.values);
        eprintln!("{model}/{norm}/{decode} {stem}: input rel err {input_err:.2e}");
        if input_err > REL_TOL {
            failures.push(format!("{stem}: input rel err {input_err:.3e}"));
        }
        for (name, w) in &want.outputs {
            let Some(g) = got.outputs.get(name) else {
                failures.push(format!("{stem}: output {name} missing"));
                continue;
            };
            assert_eq!(g.shape, w.shape, "{stem}: {name} shape");
            let e = relative_error(&g.values, &w.values);
            eprintln!("  {name:24} rel err {e:.2e}");
            match worst.iter_mut().find(|(n, _)| n == name) {
                Some(x) => x.1 = x.1.max(e),
                None => worst.push((name.clone(), e)),
            }
            if e > REL_TOL {
                failures.push(format!("{stem}: {name} rel err {e:.3e} > {REL_TOL:e}"));
            }
        }
        let want_dets: Vec<RefDetection> =
            serde_json::from_str(&std::fs::read_to_string(&dets_path).unwrap()).unwrap();
        let got_dets = det.detect(x).unwrap().remove(0);
        if got_dets.len() != want_dets.len() {
            failures.push(format!(
                "{stem}: {} detections, oracle has {}",
                got_dets.len(),
                want_dets.len()
            ));
        }
        for (k, (g, w)) in got_dets.iter().zip(&want_dets).enumerate() {
            let box_err = (0..4)
                .map(|i| (g.bbox[i] as f64 - w.bbox[i]).abs())
                .fold(0.0, f64::max);
            let score_err = (g.score as f64 - w.score).abs();
            if g.label != w.label
                || g.class_id != w.class_id
                || box_err > BOX_TOL
                || score_err > SCORE_TOL
            {
                failures.push(format!(
                    "{stem} #{k}: got {} {:.5} {:?}, oracle {} {:.5} {:?}",
                    g.label, g.score, g.bbox, w.label, w.score, w.bbox
                ));
            }
        }
        eprintln!(
            "  {} detections, oracle {}",
            got_dets.len(),
            want_dets.len()
        );
    }
    eprintln!("WORST {model}/{norm}/{decode}: {worst:?}");
    assert!(
        !compared.is_empty(),
        "{model}/{norm}/{decode}: no image compared in {}",
        shared.join("reference/images").display()
    );
    let absent: Vec<&&str> = only
        .unwrap_or_default()
        .iter()
        .filter(|n| !compared.iter().any(|c| c == *n))
        .collect();
    assert!(
        absent.is_empty(),
        "{model}/{norm}/{decode}: images {absent:?} not found"
    );
    assert!(
        failures.is_empty(),
        "conformance failures:\n{}",
        failures.join("\n")
    );
}

#[test]
fn centernet_matches_tfjs() {
    conformance("centernet", "human", "human", "centernet", None);
}

#[test]
fn nanodet_matches_tfjs() {
    conformance("nanodet", "nanodet", "dfl", "nanodet", None);
}

#[test]
fn nanodet_human_mode_matches_tfjs() {
    conformance(
        "nanodet",
        "human",
        "human",
        "nanodet-human",
        Some(&["astronaut", "motorcycle_left", "chelsea"]),
    );
}

/// The oracle cache key changes with the image's bytes, either runner file, the model and each
/// setting, and only with them.
#[test]
fn oracle_key_changes_with_every_input() {
    let d = tempfile::tempdir().unwrap();
    let runner = d.path().join("reference/tfjs");
    std::fs::create_dir_all(&runner).unwrap();
    let image = d.path().join("a.png");
    let write = |p: &Path, s: &str| std::fs::write(p, s).unwrap();
    write(&runner.join("detect.mjs"), "runner");
    write(&runner.join("package.json"), "{}");
    write(&image, "pixels");
    let key = |m: &str, n: &str, dec: &str| oracle_key(d.path(), m, n, dec, &image);
    let base = key("nanodet", "human", "human");
    assert_eq!(key("nanodet", "human", "human"), base, "deterministic");
    for other in [
        key("centernet", "human", "human"),
        key("nanodet", "nanodet", "human"),
        key("nanodet", "human", "dfl"),
    ] {
        assert_ne!(other, base);
    }
    let mut seen = vec![base];
    for (file, text) in [
        (&image, "other pixels"),
        (&runner.join("detect.mjs"), "new runner"),
        (&runner.join("package.json"), "{\"v\":2}"),
    ] {
        write(file, text);
        let k = key("nanodet", "human", "human");
        assert!(!seen.contains(&k), "{} changed, same key", file.display());
        seen.push(k);
    }
}
