//! onnxruntime as the forward engine of users' ONNX detectors (`detect::onnx::runtime`), in a
//! test binary of its own: enabling it is process-wide, and `onnx_conformance` must go on
//! judging cac's executor against onnxruntime with the runtime off.
//!
//! Checked: with the runtime enabled, each detector export's candidates from onnxruntime equal
//! those of cac's executor within the model's float noise on a seeded, letterboxed batch of two
//! (a file exported for batch 1 runs image by image), and so do the detections; the logits read
//! from onnxruntime's probabilities against the executor's; a file whose head is cut out before
//! a selection inside it, or whose input is float16, stays on the executor; gradients never
//! leave the executor; a file onnxruntime refuses, or that lacks the named input or output, is
//! refused naming it; a missing or
//! broken library is refused naming the file, through the library and the command line; the
//! command line's detections agree with the runtime on and off.

mod onnx_fixtures;
mod support;

use burn::tensor::{Tensor, TensorData};
use cac::detect::onnx::{runtime, Engine, OnnxDetector};
use cac::detect::{Detection, Detector};
use onnx_fixtures::{fixtures, has_ultralytics, manifest};
use std::path::Path;

/// Opens python3's onnxruntime library for this process (false: skipped outside CI).
fn enable() -> bool {
    let Some(lib) = runtime::find_in_python("python3") else {
        support::missing(
            "the shared library of python3's onnxruntime package",
            "pip install onnxruntime, as .ci/run does",
        );
        return false;
    };
    runtime::enable(lib.to_str().unwrap()).unwrap();
    true
}

/// A seeded `[b, 3, h, w]` batch in [0, 1] with some structure (smooth gradients plus noise), so
/// that random-weight networks give spread-out scores.
fn batch(b: usize, h: usize, w: usize, seed: u64, dev: &burn::tensor::Device) -> Tensor<4> {
    let mut s = seed;
    let v: Vec<f32> = (0..b * 3 * h * w)
        .map(|i| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let noise = (s >> 40) as f32 / (1u64 << 24) as f32;
            let (x, y) = ((i % w) as f32 / w as f32, ((i / w) % h) as f32 / h as f32);
            0.5 * noise + 0.25 * (x + y)
        })
        .collect();
    Tensor::from_data(TensorData::new(v, [b, 3, h, w]), dev)
}

fn values<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
    cac::detect::to_vec(t).unwrap()
}

/// Every detection of `a` has one of the same class in `b` with its corners within `px` and its
/// score within `tol`, unless its score is within `tol` of the threshold (float noise may drop it
/// there). Corners, not IoU: a box clipped to the image's edge may have no area.
fn covered(
    a: &[Detection],
    b: &[Detection],
    threshold: f32,
    tol: f32,
    px: f32,
) -> Result<(), String> {
    for d in a {
        let near_threshold = (d.score - threshold).abs() <= tol;
        let found = b.iter().any(|e| {
            e.class_id == d.class_id
                && d.bbox.iter().zip(&e.bbox).all(|(p, q)| (p - q).abs() <= px)
                && (e.score - d.score).abs() <= tol
        });
        if !found && !near_threshold {
            return Err(format!(
                "{} {:.5} {:?} has no match",
                d.label, d.score, d.bbox
            ));
        }
    }
    Ok(())
}

#[test]
fn onnxruntime_candidates_and_detections_equal_the_executors() {
    let Some(dir) = fixtures() else { return };
    if !has_ultralytics(dir) || !enable() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("low.toml");
    let threshold = 0.05;
    std::fs::write(
        &cfg,
        format!("score_threshold = {threshold}\niou_threshold = 0.45\n"),
    )
    .unwrap();
    let mut checked = 0;
    let mut detections = 0;
    for e in manifest(dir).models.iter().filter(|e| e.kind == "detector") {
        let det = OnnxDetector::load(&dir.join(&e.file), Some(&cfg), &support::device()).unwrap();
        assert_eq!(det.engine(), Engine::Runtime, "{}", e.name);
        // Two images of another shape than the network's: letterboxed, and run one by one where
        // the file is exported for a batch of one.
        let x = batch(2, 200, 300, 7 + checked as u64, &support::device());
        let a = det.candidates_with(x.clone(), Engine::Executor).unwrap();
        let b = det.candidates_with(x.clone(), Engine::Runtime).unwrap();
        assert_eq!(a.scores.dims(), b.scores.dims(), "{}", e.name);
        // Boxes within four times the model's own float noise (onnxruntime's output moving with
        // its graph optimisations or two ulps of input; at least 1e-4) of the largest box value;
        // scores, in [0, 1], within four times that noise absolutely.
        let (ba, bb) = (values(&a.boxes), values(&b.boxes));
        let (sa, sb) = (values(&a.scores), values(&b.scores));
        let scale = ba.iter().fold(1.0f32, |m, v| m.max(v.abs()));
        let noise = 4.0 * (e.noise as f32).max(1e-4);
        let (bound, score_bound) = (noise * scale, noise);
        let worst = |p: &[f32], q: &[f32]| {
            p.iter()
                .zip(q)
                .fold(0.0f32, |m, (u, v)| m.max((u - v).abs()))
        };
        eprintln!(
            "{}: boxes {:.2e} (bound {bound:.2e}), scores {:.2e} (bound {score_bound:.2e}) apart",
            e.name,
            worst(&ba, &bb),
            worst(&sa, &sb)
        );
        assert!(
            worst(&ba, &bb) <= bound && worst(&sa, &sb) <= score_bound,
            "{}: boxes {} and scores {} apart",
            e.name,
            worst(&ba, &bb),
            worst(&sa, &sb)
        );
        // The logits read from onnxruntime's probabilities against the executor's (the tapped
        // sigmoid inputs, or its own reading of the probabilities) where the score is not
        // saturated: within the scores' bound over the sigmoid's slope there.
        let (la, lb) = (values(&a.logits), values(&b.logits));
        let mut compared_logits = 0;
        for ((&u, &v), &p) in la.iter().zip(&lb).zip(&sa) {
            let slope = p * (1.0 - p);
            if u.abs() <= 6.0 {
                assert!(
                    (u - v).abs() <= score_bound / slope + 1e-4,
                    "{}: logit {u} on the executor, {v} from onnxruntime (score {p})",
                    e.name
                );
                compared_logits += 1;
            }
        }
        assert!(compared_logits > 0, "{}: no unsaturated logit", e.name);
        let da = det.detect_with(x.clone(), Engine::Executor).unwrap();
        let db = det.detect(x).unwrap();
        let (tol, px) = (score_bound, bound.max(1e-2));
        for (i, (p, q)) in da.iter().zip(&db).enumerate() {
            // Where the random network saturates (scores of exactly 1.0), rank ties make NMS's
            // choice depend on the last rounding: counted, not required (as in onnx_conformance).
            let saturated = p.iter().chain(q).any(|d| d.score >= 1.0 - 1e-6);
            let both =
                covered(p, q, threshold, tol, px).and_then(|_| covered(q, p, threshold, tol, px));
            eprintln!(
                "{} image {i}: {} / {} detections (executor / onnxruntime){}{}",
                e.name,
                p.len(),
                q.len(),
                if saturated { ", saturated" } else { "" },
                match &both {
                    Ok(_) => String::new(),
                    Err(m) => format!(": {m}"),
                }
            );
            if !saturated {
                both.unwrap_or_else(|m| panic!("{} image {i}: {m}", e.name));
                detections += p.len();
            }
        }
        checked += 1;
    }
    assert!(checked >= 3, "only {checked} detector exports");
    assert!(detections > 0, "no unsaturated detections to compare");
}

#[test]
fn heads_cut_before_a_selection_and_gradients_stay_on_the_executor() {
    let Some(dir) = fixtures() else { return };
    if !has_ultralytics(dir) || !enable() {
        return;
    }
    let cut: Vec<_> = manifest(dir)
        .models
        .into_iter()
        .filter(|e| e.kind == "selecting" && e.selects == "topk")
        .collect();
    assert!(!cut.is_empty(), "no export selecting by top-k");
    for e in &cut {
        let det = OnnxDetector::load(&dir.join(&e.file), None, &support::device()).unwrap();
        assert_eq!(det.engine(), Engine::Executor, "{}", e.name);
        let x = batch(1, 160, 160, 3, &support::device());
        det.detect(x).unwrap();
    }
    // The attack's path: candidates of a tracked image, on the executor, with a gradient.
    let file = dir.join("yolov8n.onnx");
    let det = OnnxDetector::load(&file, None, &support::training()).unwrap();
    assert_eq!(det.engine(), Engine::Runtime);
    let x = batch(1, 160, 160, 5, &support::training()).require_grad();
    let c = det.candidates(x.clone()).unwrap();
    let g = c.logits.max_dim(2).sum().backward();
    let grad = values(&x.grad(&g).expect("a gradient to the image"));
    assert!(grad.iter().all(|v| v.is_finite()) && grad.iter().any(|v| *v != 0.0));
}

#[test]
fn a_missing_or_broken_library_is_refused_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("libonnxruntime.so.9");
    let e = format!(
        "{:#}",
        runtime::enable(missing.to_str().unwrap()).unwrap_err()
    );
    assert!(e.contains(missing.to_str().unwrap()), "{e}");
    let broken = tmp.path().join("libonnxruntime.so");
    std::fs::write(&broken, b"not a shared library").unwrap();
    let e = format!(
        "{:#}",
        runtime::enable(broken.to_str().unwrap()).unwrap_err()
    );
    assert!(e.contains(broken.to_str().unwrap()), "{e}");
    // Through the command line (a process of its own, where nothing was opened before): exit
    // code 2 before any work, naming the variable and the file, for each.
    for (lib, why) in [(&missing, "no such"), (&broken, "cannot load")] {
        let out = support::cac_command()
            .env("CAC_ONNXRUNTIME", lib)
            .args(["config"])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(
            err.contains("CAC_ONNXRUNTIME")
                && err.contains(lib.to_str().unwrap())
                && err.contains(why),
            "{err}"
        );
    }
    // `--help` answers whatever the variable holds.
    let out = support::cac_command()
        .env("CAC_ONNXRUNTIME", &missing)
        .arg("--help")
        .output()
        .unwrap();
    assert!(out.status.success());
}

#[test]
fn the_command_line_detects_alike_with_the_runtime_on_and_off() {
    let Some(dir) = fixtures() else { return };
    if !has_ultralytics(dir) {
        return;
    }
    let Some(shared) = support::shared() else {
        return;
    };
    let img = shared.join("reference/images/astronaut.png");
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("low.toml");
    std::fs::write(
        &cfg,
        "score_threshold = 0.05
",
    )
    .unwrap();
    let spec = format!(
        "onnx:{}:{}",
        dir.join("yolov6n.onnx").display(),
        cfg.display()
    );
    let run = |lib: Option<&str>| -> Vec<Detection> {
        let mut c = support::cac_command();
        c.env_remove("CAC_ONNXRUNTIME");
        if let Some(l) = lib {
            c.env("CAC_ONNXRUNTIME", l);
        }
        let out = c
            .args(["detect", "--json", "--model", &spec])
            .arg(&img)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                let b: Vec<f32> = v["box"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap() as f32)
                    .collect();
                Detection {
                    class_id: v["class_id"].as_u64().unwrap() as usize,
                    label: "",
                    score: v["score"].as_f64().unwrap() as f32,
                    bbox: [b[0], b[1], b[2], b[3]],
                }
            })
            .collect()
    };
    if runtime::find_in_python("python3").is_none() {
        support::missing("python3's onnxruntime library", "pip install onnxruntime");
        return;
    }
    let off = run(None);
    let on = run(Some("auto"));
    assert!(!off.is_empty(), "no detections to compare");
    // YOLOv6n does not saturate on this photo (as in the test above): every detection matched
    // both ways, in class, corners (0.5 px: the random network's float noise, as bounded
    // above) and score (1e-3), but near the threshold.
    assert!(off.iter().chain(&on).all(|d| d.score < 1.0 - 1e-6));
    covered(&off, &on, 0.05, 1e-3, 0.5)
        .and_then(|_| covered(&on, &off, 0.05, 1e-3, 0.5))
        .unwrap_or_else(|m| panic!("{m}\noff {off:?}\non {on:?}"));
}

#[test]
fn a_file_with_an_fp16_input_stays_on_the_executor() {
    let Some(dir) = fixtures() else { return };
    if !enable() {
        return;
    }
    // The anchor-based fixture behind a float16 graph input (a Cast to float32 first), as an
    // fp16 export's input is: onnxruntime would want f16 data; cac's executor runs it in f32.
    let tmp = tempfile::tempdir().unwrap();
    let half = tmp.path().join("half_input.onnx");
    let script = "import onnx, sys\n\
        from onnx import helper, TensorProto\n\
        m = onnx.load(sys.argv[1])\n\
        i = m.graph.input[0]\n\
        name = i.name\n\
        i.name = name + '_f16'\n\
        i.type.tensor_type.elem_type = TensorProto.FLOAT16\n\
        m.graph.node.insert(0, helper.make_node('Cast', [i.name], [name], to=TensorProto.FLOAT))\n\
        onnx.checker.check_model(m)\n\
        onnx.save(m, sys.argv[2])\n";
    let st = std::process::Command::new("python3")
        .args(["-c", script])
        .arg(dir.join("yolov5_anchor.onnx"))
        .arg(&half)
        .status()
        .unwrap();
    assert!(st.success());
    let low = tmp.path().join("low.toml");
    std::fs::write(&low, "score_threshold = 0.05\n").unwrap();
    let det = OnnxDetector::load(&half, Some(&low), &support::device()).unwrap();
    assert_eq!(det.engine(), Engine::Executor);
    let plain = dir.join("yolov5_anchor.onnx");
    let plain = OnnxDetector::load(&plain, Some(&low), &support::device()).unwrap();
    assert_eq!(plain.engine(), Engine::Runtime);
    // The same detections as the f32 file on the executor (the Cast is exact on f32 data).
    let x = batch(1, 160, 160, 11, &support::device());
    let (a, b) = (
        det.detect(x.clone()).unwrap(),
        plain.detect_with(x, Engine::Executor).unwrap(),
    );
    assert!(!a[0].is_empty(), "no detections to compare");
    assert_eq!(a[0].len(), b[0].len());
    covered(&a[0], &b[0], 0.05, 1e-6, 1e-4).unwrap();
}

#[test]
fn a_file_onnxruntime_refuses_is_named_and_a_missing_head_output_too() {
    let Some(dir) = fixtures() else { return };
    if !enable() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let junk = tmp.path().join("junk.onnx");
    std::fs::write(&junk, b"not a protobuf").unwrap();
    let file = dir.join("yolov5_anchor.onnx");
    let cases: [(&Path, &str, &str, &str); 3] = [
        (&junk, "images", "output0", "refuses"),
        (&file, "images", "no_such_output", "no_such_output"),
        (&file, "no_such_input", "output0", "no_such_input"),
    ];
    for (path, input, output, why) in cases {
        let e = runtime::Session::open(path, input, &[output])
            .err()
            .unwrap();
        let e = format!("{e:#}");
        assert!(e.contains(path.to_str().unwrap()) && e.contains(why), "{e}");
    }
}
