//! The ultralytics family as users export it, through cac: `tools/onnx/make_family.py` builds
//! each model from its yaml with seeded random weights (YOLOv3u … YOLO26n, RT-DETR-l, the
//! segmentation and pose variants) and YOLOv8n with each export option (opset 12/18, dynamic,
//! simplify off, half, 384×640, nms=True, int8 by onnxruntime's quantizer; YOLOv10n / YOLO26n
//! with nms=False), with onnxruntime's output on a seeded input. Every row is either matched to
//! onnxruntime (output0 within max(1e-4, 2 × onnxruntime's own float noise) of its largest
//! magnitude) and trainable (a finite, non-zero input gradient of the class logits cac's head
//! reads), or refused with a message that says what to do, as the row expects. The conformance
//! table is printed and written to `$CARGO_TARGET_TMPDIR/onnx-family/conformance.md`
//! (docs/detectors.md shows one run).

mod onnx_fixtures;
mod support;

use burn::tensor::{Tensor, TensorData};
use cac::detect::onnx::OnnxDetector;
use cac::detect::Detector;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Deserialize)]
struct T {
    shape: Vec<usize>,
    data: Vec<f64>,
}

#[derive(Deserialize)]
struct Row {
    name: String,
    file: String,
    task: String,
    noise: f64,
    input: Vec<usize>,
}

#[derive(Deserialize)]
struct Family {
    rows: Vec<Row>,
    versions: BTreeMap<String, String>,
}

fn read(path: &Path) -> BTreeMap<String, T> {
    serde_json::from_slice(
        &std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    )
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The family's exports, built once per script version; None (a skip outside CI, a failure
/// under it) without torch and ultralytics.
fn family() -> Option<PathBuf> {
    if !support::require(
        "python3",
        &["-c", "import onnx, onnxruntime, torch, ultralytics"],
        "python3 with onnx, onnxruntime, torch and ultralytics (pip install, as .ci/run does)",
    ) {
        return None;
    }
    let scripts = ["make_family.py", "make_models.py", "ort_run.py"];
    Some(onnx_fixtures::built_once("onnx-family", &scripts, |dir| {
        onnx_fixtures::python("make_family.py", &[dir.as_os_str()])
    }))
}

/// What a row must come to: it runs (with a config, where its refusal said to write one), or
/// it is refused with a message holding every one of these phrases.
enum Expect {
    Runs,
    RunsWithConfig(&'static str, &'static [&'static str]),
    Refused(&'static [&'static str]),
}

fn expect(row: &str) -> Expect {
    const NOT_A_DETECTOR: &[&str] = &["not a detection model", "export the detection variant"];
    match row {
        "yolov8n-seg" | "yolov8n-pose" => Expect::Refused(NOT_A_DETECTOR),
        "yolov8n nms=True" => {
            Expect::Refused(&["NMS or top-k selection inside", "`nms` left at its default"])
        }
        "yolov8n int8" => Expect::Refused(&["quantized", "the float model"]),
        "yolov8n dynamic" => {
            Expect::RunsWithConfig("input_size = [320, 320]\n", &["dynamic size", "input_size"])
        }
        _ => Expect::Runs,
    }
}

/// Sorted scores of a top-k / NMS selection `[1, 300, 6]` (the order of equal scores is the
/// engine's), else the values as they are.
fn comparable(shape: &[usize], data: Vec<f64>) -> Vec<f64> {
    if shape.len() == 3 && shape[1..] == [300, 6] {
        let mut s: Vec<f64> = data.chunks(6).map(|r| r[4]).collect();
        s.sort_by(|a, b| b.total_cmp(a));
        return s;
    }
    data
}

/// Runs a row: output0 against onnxruntime (relative error, bound) and the input gradient's
/// norm. An error is cac's refusal.
fn run_row(dir: &Path, row: &Row, config: Option<&Path>) -> anyhow::Result<(f64, f64, f64)> {
    let train = support::training();
    let path = dir.join(&row.file);
    let det = OnnxDetector::load(&path, config, &train)?;
    let stem = path.with_extension("");
    let input = &read(&stem.with_extension("input.json"))["images"];
    let want = &read(&stem.with_extension("expected.json"))["output0"];
    let [b, c, h, w] = <[usize; 4]>::try_from(row.input.as_slice()).unwrap();
    assert_eq!(input.shape, row.input);
    let x0: Vec<f32> = input.data.iter().map(|&v| v as f32).collect();
    let x = Tensor::<4>::from_data(TensorData::new(x0, [b, c, h, w]), &train);
    let got = det
        .graph()
        .run_images("images", x.clone().detach(), &["output0"])?;
    let h0 = got[0].host()?;
    anyhow::ensure!(
        h0.shape() == want.shape.as_slice(),
        "output0 shape {:?}, onnxruntime {:?}",
        h0.shape(),
        want.shape
    );
    let ours = comparable(h0.shape(), h0.floats().iter().map(|&v| v as f64).collect());
    let theirs = comparable(&want.shape, want.data.clone());
    let scale = theirs.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-6);
    let err = ours
        .iter()
        .zip(&theirs)
        .map(|(a, b)| {
            if a.is_finite() {
                (a - b).abs() / scale
            } else {
                f64::INFINITY
            }
        })
        .fold(0.0, f64::max);
    let bound = 1e-4f64.max(2.0 * row.noise);
    // Trainable: the class-0 logits of the candidates cac reads, back to the input.
    let x = x.require_grad();
    let loss = det.candidates(x.clone())?.logits.narrow(2, 0, 1).mean();
    let grads = loss.backward();
    let g: Vec<f32> = x
        .grad(&grads)
        .unwrap()
        .to_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap();
    anyhow::ensure!(
        g.iter().all(|v| v.is_finite()),
        "a non-finite input gradient"
    );
    let norm = g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    Ok((err, bound, norm))
}

#[test]
fn every_export_of_the_family_is_matched_and_trainable_or_refused_saying_what_to_do() {
    let Some(dir) = family() else { return };
    let fam: Family =
        serde_json::from_slice(&std::fs::read(dir.join("family.json")).unwrap()).unwrap();
    assert!(fam.rows.len() >= 23, "{} rows", fam.rows.len());
    let versions: Vec<String> = fam
        .versions
        .iter()
        .map(|(k, v)| format!("{k} {v}"))
        .collect();
    let mut table = format!(
        "ultralytics exports built from yaml with seeded random weights ({}); cac against \
         onnxruntime on a seeded input\n\n| export | task | cac | output0 vs onnxruntime | bound | input gradient |\n|---|---|---|---|---|---|\n",
        versions.join(", ")
    );
    let mut failures = Vec::new();
    for row in &fam.rows {
        let first = run_row(&dir, row, None);
        let line = match (expect(&row.name), first) {
            (Expect::Runs, Ok((err, bound, norm))) if err <= bound && norm > 0.0 => {
                format!("runs | {err:.1e} | {bound:.1e} | {norm:.2e}")
            }
            (Expect::Refused(words), Err(e)) => {
                let msg = format!("{e:#}");
                if !words.iter().all(|w| msg.contains(w)) || !msg.contains(&row.file) {
                    failures.push(format!(
                        "{}: refused, but not saying {words:?}: {msg}",
                        row.name
                    ));
                }
                let said = msg
                    .split(": ")
                    .nth(1)
                    .unwrap_or(&msg)
                    .split(". ")
                    .next()
                    .unwrap_or("");
                format!("refused: {} | | |", said.replace('|', "/"))
            }
            (Expect::RunsWithConfig(config, words), Err(e)) => {
                let msg = format!("{e:#}");
                if !words.iter().all(|w| msg.contains(w)) {
                    failures.push(format!(
                        "{}: refused, but not saying {words:?}: {msg}",
                        row.name
                    ));
                }
                // Not `MODEL.toml` beside the file: that one is read without being named, and
                // a rerun on the cached family would then load the row with no refusal.
                let cfg = dir.join(format!("{}.given.toml", row.file.trim_end_matches(".onnx")));
                std::fs::write(&cfg, config).unwrap();
                match run_row(&dir, row, Some(&cfg)) {
                    Ok((err, bound, norm)) if err <= bound && norm > 0.0 => format!(
                        "runs with `{}` in a config, as its refusal says | {err:.1e} | {bound:.1e} | {norm:.2e}",
                        config.trim()
                    ),
                    other => {
                        failures.push(format!("{} with {config:?}: {:?}", row.name, other.map_err(|e| format!("{e:#}"))));
                        "FAILED with its config | | |".into()
                    }
                }
            }
            (_, other) => {
                failures.push(format!(
                    "{}: {:?}",
                    row.name,
                    other.map_err(|e| format!("{e:#}"))
                ));
                "FAILED | | |".into()
            }
        };
        writeln!(table, "| {} | {} | {line} |", row.name, row.task).unwrap();
    }
    eprintln!("{table}");
    std::fs::write(dir.join("conformance.md"), &table).unwrap();
    assert!(failures.is_empty(), "{}\n\n{table}", failures.join("\n"));
}
