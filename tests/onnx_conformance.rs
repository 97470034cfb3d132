//! ONNX detectors (src/detect/onnx) against onnxruntime, on models the tests build themselves:
//! `tools/onnx/make_models.py` writes 111 single-op graphs (opsets 11–21, `onnx.helper`), a
//! hand-built anchor-based YOLOv5/v3-style detector, and ultralytics' YOLOv8n, YOLOv5su and
//! YOLOv6n built from their yaml with seeded random weights and exported; onnxruntime's outputs
//! on seeded inputs come with them, and `tools/onnx/ort_run.py` runs onnxruntime on inputs cac
//! makes.
//!
//! Checked: every op case and every detector's raw output within 1e-4 of the output's largest
//! magnitude; the detectors' final detections on reference images equal those decoded from
//! onnxruntime's output by an independent decoder here; the input gradient through the tapped
//! logits against central differences; black, white and saturated-noise images stay finite;
//! bad files are refused naming the file, node and op; the CLI (`cac models inspect`, `cac
//! detect`, `cac train`, `cac eval`) takes `onnx:MODEL.onnx`.

mod onnx_fixtures;
mod support;

use onnx_fixtures::{fixtures, has_ultralytics, manifest, Entry};

use burn::tensor::{Tensor, TensorData};
use cac::detect::onnx::{self, Dev, Host, OnnxDetector, Val};
use cac::detect::{Detection, Detector};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

#[derive(Deserialize, Clone)]
struct T {
    shape: Vec<usize>,
    data: Vec<f64>,
    #[serde(default)]
    dtype: Option<String>,
}

fn read(path: &Path) -> BTreeMap<String, T> {
    serde_json::from_slice(
        &std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    )
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn write(path: &Path, name: &str, shape: &[usize], data: &[f32]) {
    let v = serde_json::json!({ name: { "shape": shape, "data": data } });
    std::fs::write(path, serde_json::to_vec(&v).unwrap()).unwrap();
}

/// The fixtures with the torch-built models (ultralytics, torchvision) and the shared folder of
/// reference photos; None (a skip outside CI, a failure under it) when one is missing.
fn exports_and_shared() -> Option<(&'static Path, PathBuf)> {
    let dir = fixtures()?;
    let shared = support::shared()?;
    has_ultralytics(dir).then_some((dir, shared))
}

/// A small scene config for CLI runs (the pickup at 96², one sample, a 32² atlas), written in
/// `dir`; returns its path.
fn small_scene(dir: &Path) -> PathBuf {
    let scene = dir.join("small.toml");
    std::fs::write(
        &scene,
        "[object]\nmesh = \"pickup\"\n[render]\nwidth = 96\nheight = 96\nsamples = 1\n\
         atlas_res = 32\n[environment]\ndistance_ratio = [1.5, 2.0]\n",
    )
    .unwrap();
    scene
}

/// A deterministic `[1, 3, h, w]` image in [0, 1] where no photo is needed.
fn pattern(h: usize, w: usize, dev: &burn::tensor::Device) -> Tensor<4> {
    let v: Vec<f32> = (0..3 * h * w)
        .map(|i| ((i * 37) % 101) as f32 / 100.0)
        .collect();
    Tensor::from_data(TensorData::new(v, [1, 3, h, w]), dev)
}

/// A reference photo from ../shared as an image and as a `[1, 3, H, W]` tensor.
fn photo(shared: &Path, name: &str) -> (image::RgbImage, Tensor<4>) {
    let rgb = cac::io::load_rgb(&shared.join("reference/images").join(name)).unwrap();
    let x = cac::detect::preprocess::image_to_tensor(&rgb, &support::device());
    (rgb, x)
}

/// `got` against onnxruntime's `want`: same shape, every value within 1e-4 of the largest
/// magnitude of `want` (integers exactly). Returns the error relative to that magnitude.
fn compare(what: &str, got: &Val, want: &T) -> Result<f64, String> {
    compare_within(what, got, want, 1e-4)
}

/// [`compare`] with the relative bound `rel`.
fn compare_within(what: &str, got: &Val, want: &T, rel: f64) -> Result<f64, String> {
    let h = got.host().map_err(|e| format!("{what}: {e}"))?;
    if h.shape() != want.shape.as_slice() {
        return Err(format!(
            "{what}: shape {:?}, onnxruntime {:?}",
            h.shape(),
            want.shape
        ));
    }
    let g = h.floats();
    let scale = want
        .data
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(1e-6);
    let int = want.dtype.as_deref().is_some_and(|d| d.starts_with("int"));
    let mut worst = 0.0f64;
    for (i, (&a, &b)) in g.iter().zip(&want.data).enumerate() {
        let e = (a as f64 - b).abs();
        if !(a as f64).is_finite() || (int && e != 0.0) || e > rel * scale {
            return Err(format!(
                "{what}: element {i} is {a}, onnxruntime {b} (largest magnitude {scale})"
            ));
        }
        worst = worst.max(e / scale);
    }
    Ok(worst)
}

fn feed(t: &T) -> Val {
    let dev = support::device();
    if t.dtype.as_deref().is_some_and(|d| d.starts_with("int")) {
        let v: Vec<i64> = t.data.iter().map(|&x| x as i64).collect();
        return Val::H(Host::I(
            ndarray::ArrayD::from_shape_vec(ndarray::IxDyn(&t.shape), v).unwrap(),
        ));
    }
    let v: Vec<f32> = t.data.iter().map(|&x| x as f32).collect();
    let n = v.len();
    Val::D(
        Dev::new(
            Tensor::<1>::from_data(TensorData::new(v, [n]), &dev),
            t.shape.clone(),
        )
        .unwrap(),
    )
}

fn run_case(dir: &Path, e: &Entry) -> Result<f64, String> {
    run_case_within(dir, e, 1e-4)
}

/// [`run_case`] with every output held to `rel` of its largest magnitude.
fn run_case_within(dir: &Path, e: &Entry, rel: f64) -> Result<f64, String> {
    let path = dir.join(&e.file);
    let stem = path.with_extension("");
    let g = onnx::load_graph(&path, &support::device()).map_err(|x| format!("{x:#}"))?;
    let inputs = read(&stem.with_extension("input.json"));
    let want = read(&stem.with_extension("expected.json"));
    let feeds: Vec<(String, Val)> = inputs.iter().map(|(k, t)| (k.clone(), feed(t))).collect();
    let refs: Vec<(&str, Val)> = feeds.iter().map(|(k, v)| (k.as_str(), v.clone())).collect();
    let outs: Vec<&str> = e.outputs.iter().map(|s| s.as_str()).collect();
    let got = g.run(&refs, &outs).map_err(|x| format!("{x:#}"))?;
    let mut worst = 0.0f64;
    for (name, v) in e.outputs.iter().zip(&got) {
        worst = worst.max(compare_within(
            &format!("{} output {name}", e.name),
            v,
            &want[name],
            rel,
        )?);
    }
    Ok(worst)
}

#[test]
fn every_op_case_matches_onnxruntime() {
    let Some(dir) = fixtures() else { return };
    let m = manifest(dir);
    let cases: Vec<&Entry> = m.models.iter().filter(|e| e.kind == "op").collect();
    assert!(cases.len() >= 110, "{} op cases", cases.len());
    let mut failures = Vec::new();
    let mut worst = (0.0f64, "");
    let mut opsets = std::collections::BTreeSet::new();
    for e in &cases {
        opsets.insert(e.opset);
        match run_case(dir, e) {
            Ok(w) if w > worst.0 => worst = (w, &e.name),
            Ok(_) => {}
            Err(x) => failures.push(format!("{} (opset {}): {x}", e.name, e.opset)),
        }
    }
    eprintln!(
        "{} op cases, opsets {opsets:?}, largest error {:.2e} of the output's magnitude ({})",
        cases.len(),
        worst.0,
        worst.1
    );
    assert!(
        failures.is_empty(),
        "{} cases differ:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn yolo_exports_match_onnxruntime_on_their_seeded_input() {
    let Some(dir) = fixtures() else { return };
    has_ultralytics(dir);
    // Held to 1e-4 of the largest magnitude, or twice the model's own float noise where that
    // is larger (the random YOLOv6n moves onnxruntime's output by ~2e-4).
    let exports = manifest(dir).models;
    let exports: Vec<&Entry> = exports
        .iter()
        .filter(|e| e.kind == "detector" || e.kind == "export")
        .collect();
    assert!(
        !dir.join("yolov8n.onnx").is_file() || exports.iter().any(|e| e.name == "yolov6n"),
        "the ultralytics exports lack YOLOv6n (ConvTranspose)"
    );
    for e in exports {
        let bound = 1e-4f64.max(2.0 * e.noise);
        let w = run_case_within(dir, e, bound).unwrap_or_else(|x| panic!("{x}"));
        let noise = match e.noise {
            0.0 => String::new(),
            n => format!(" (bound {bound:.1e}: float noise moves onnxruntime's by {n:.2e})"),
        };
        eprintln!(
            "{} (opset {}): largest error {w:.2e} of the output's magnitude{noise}",
            e.name, e.opset
        );
    }
}

/// Detections decoded from a raw `[1, A, N]` (anchor-free) or `[1, N, 85]` (anchor) output,
/// independently of cac's head: undo the letterbox, threshold, per-class greedy NMS.
fn decode(
    raw: &T,
    anchor_free: bool,
    xyxy: bool,
    geo: ([f32; 2], [f32; 2]),
    (w, h): (f32, f32),
    thr: f32,
    iou: f32,
) -> Vec<(usize, f32, [f32; 4])> {
    let s = &raw.shape;
    let (n, k) = if anchor_free {
        (s[2], s[1])
    } else {
        (s[1], s[2])
    };
    let at = |i: usize, j: usize| -> f32 {
        (if anchor_free {
            raw.data[j * n + i]
        } else {
            raw.data[i * k + j]
        }) as f32
    };
    let mut cand = Vec::new();
    for i in 0..n {
        let (a0, a1, a2, a3) = (at(i, 0), at(i, 1), at(i, 2), at(i, 3));
        let [x1, y1, x2, y2] = if xyxy {
            [a0, a1, a2, a3]
        } else {
            [a0 - a2 / 2.0, a1 - a3 / 2.0, a0 + a2 / 2.0, a1 + a3 / 2.0]
        };
        let b = [
            (x1 - geo.1[0]) / geo.0[0],
            (y1 - geo.1[1]) / geo.0[1],
            (x2 - geo.1[0]) / geo.0[0],
            (y2 - geo.1[1]) / geo.0[1],
        ];
        let first = if anchor_free { 4 } else { 5 };
        for c in first..k {
            let score = if anchor_free {
                at(i, c)
            } else {
                at(i, 4) * at(i, c)
            };
            if score > thr {
                cand.push((c - first, score, b));
            }
        }
    }
    cand.sort_by(|a, b| b.1.total_cmp(&a.1));
    let area = |b: &[f32; 4]| (b[2] - b[0]).max(0.0) * (b[3] - b[1]).max(0.0);
    let mut keep: Vec<(usize, f32, [f32; 4])> = Vec::new();
    for c in cand {
        let clash = keep.iter().any(|k| {
            let ix = (k.2[2].min(c.2[2]) - k.2[0].max(c.2[0])).max(0.0);
            let iy = (k.2[3].min(c.2[3]) - k.2[1].max(c.2[1])).max(0.0);
            let inter = ix * iy;
            k.0 == c.0 && inter / (area(&k.2) + area(&c.2) - inter) > iou
        });
        if !clash && keep.len() < 100 {
            keep.push(c);
        }
    }
    // Kept boxes clipped to the image, as ultralytics' `scale_boxes` clips them.
    for k in &mut keep {
        let b = &mut k.2;
        *b = [
            b[0].clamp(0.0, w),
            b[1].clamp(0.0, h),
            b[2].clamp(0.0, w),
            b[3].clamp(0.0, h),
        ];
    }
    keep
}

#[test]
fn yolo_detections_on_reference_images_match_onnxruntime() {
    let Some((dir, shared)) = exports_and_shared() else {
        return;
    };
    let dev = support::device();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("test.toml");
    std::fs::write(&cfg, "score_threshold = 0.3\niou_threshold = 0.45\n").unwrap();
    let mut compared = 0;
    for e in manifest(dir).models.iter().filter(|e| e.kind == "detector") {
        let det = OnnxDetector::load(&dir.join(&e.file), Some(&cfg), &dev).unwrap();
        let anchor_free = e.name != "yolov5_anchor";
        // onnxruntime's output on each photo, and how far float noise alone moves it: its fused
        // graph against the graph as written, and its output when the input moves by about two
        // ulps (seeded ±2^-22 relative). These random-weight networks amplify float noise by an
        // amount that varies with the photo and the CPU's kernels (AVX2 or AVX-512 summation
        // orders): a few box outputs move by up to ~5e-4 of the largest. cac is held to twice the
        // model's largest noise over the photos (at least 1e-4) at every element, and to 1e-4
        // at all but one element in a thousand: a wrong op moves far more than that.
        let mut oracle = Vec::new();
        for img in ["astronaut.png", "horse.png", "motorcycle_left.png"] {
            let (rgb, x) = photo(&shared, img);
            let (net, geo) = det.network_input(x.clone()).unwrap();
            let input = tmp.path().join("in.json");
            let output = tmp.path().join("out.json");
            let data: Vec<f32> = net
                .to_data()
                .convert::<f32>()
                .try_into_vec::<f32>()
                .unwrap();
            write(&input, "images", &net.dims(), &data);
            let ort = |inp: &Path, out: &Path, extra: &[&str]| {
                let st = Command::new("python3")
                    .arg(support::root().join("tools/onnx/ort_run.py"))
                    .args([dir.join(&e.file).as_path(), inp, out])
                    .args(extra)
                    .status()
                    .unwrap();
                assert!(st.success(), "ort_run.py on {}", e.name);
                read(out)
            };
            let want = ort(&input, &output, &[]);
            let moved = |other: &BTreeMap<String, T>| {
                let (a, b) = (&want["output0"].data, &other["output0"].data);
                let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                a.iter()
                    .zip(b)
                    .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()))
                    / scale
            };
            let plain = ort(&input, &tmp.path().join("plain.json"), &["--no-optimize"]);
            let mut rng = 0x9e37_79b9u64;
            let jittered: Vec<f32> = data
                .iter()
                .map(|&v| {
                    rng = rng
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let sign = if rng >> 63 == 1 { 1.0 } else { -1.0 };
                    v * (1.0 + sign * (2.0f32).powi(-22))
                })
                .collect();
            let jin = tmp.path().join("jitter.json");
            write(&jin, "images", &net.dims(), &jittered);
            let jitter = ort(&jin, &tmp.path().join("jout.json"), &[]);
            let spread = moved(&plain).max(moved(&jitter));
            oracle.push((img, rgb, x, net, geo, want, spread));
        }
        let model_spread = oracle.iter().map(|o| o.6).fold(0.0f64, f64::max);
        for (img, rgb, x, net, geo, want, spread) in oracle {
            let got = det.graph().run_images("images", net, &["output0"]).unwrap();
            let got = &got;
            let rel = compare_within(
                &format!("{} on {img}", e.name),
                &got[0],
                &want["output0"],
                1e-4f64.max(2.0 * model_spread),
            )
            .unwrap();
            let scale = want["output0"]
                .data
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            let mine = got[0].host().unwrap().floats();
            let over = mine
                .iter()
                .zip(&want["output0"].data)
                .filter(|(a, b)| (**a as f64 - **b).abs() > 1e-4 * scale)
                .count();
            assert!(
                over * 1000 <= mine.len(),
                "{} on {img}: {over} of {} outputs differ from onnxruntime's by more than 1e-4 of the largest",
                e.name,
                mine.len()
            );
            eprintln!(
                "{} on {img}: raw output within {rel:.2e} ({over} of {} beyond 1e-4; float noise moves onnxruntime's by {spread:.2e})",
                e.name,
                mine.len()
            );
            let mine = det.detect(x).unwrap().remove(0);
            let (w, h) = (rgb.width() as f32, rgb.height() as f32);
            let same = |a: &Detection, b: &(usize, f32, [f32; 4])| {
                a.class_id == b.0
                    && (a.score - b.1).abs() < 1e-3
                    && a.bbox
                        .iter()
                        .zip(b.2)
                        .all(|(p, q)| (p - q).abs() < 1e-3 * w.max(h))
            };
            let geo = (geo.scale, geo.pad);
            // The head: cac's detections are those an independent decoder finds in cac's raw output.
            let ours = T {
                shape: got[0].shape().to_vec(),
                data: got[0]
                    .host()
                    .unwrap()
                    .floats()
                    .iter()
                    .map(|&v| v as f64)
                    .collect(),
                dtype: None,
            };
            assert!(
                mine.iter().all(|d| {
                    let b = d.bbox;
                    b[0] >= 0.0 && b[1] >= 0.0 && b[2] <= w && b[3] <= h
                }),
                "{} on {img}: a box outside the {w}x{h} image: {mine:?}",
                e.name
            );
            let decoded = decode(&ours, anchor_free, false, geo, (w, h), 0.3, 0.45);
            assert_eq!(mine.len(), decoded.len(), "{} on {img}", e.name);
            for (d, t) in mine.iter().zip(&decoded) {
                assert!(same(d, t), "{} on {img}: cac {d:?}, decoder {t:?}", e.name);
            }
            // The whole: against detections decoded from onnxruntime's output. Where the random
            // network saturates (scores of exactly 1.0 by the dozen), rank ties and the cap of
            // 100 make the selection depend on the last rounding: counted, not required.
            let theirs = decode(&want["output0"], anchor_free, false, geo, (w, h), 0.3, 0.45);
            let matched = mine
                .iter()
                .filter(|d| theirs.iter().any(|t| same(d, t)))
                .count();
            let saturated = theirs.iter().filter(|t| t.1 >= 1.0).count();
            eprintln!(
                "{} on {img}: {} detections, {matched} equal to onnxruntime's {} ({saturated} of them at score 1.0)",
                e.name,
                mine.len(),
                theirs.len()
            );
            if saturated == 0 {
                assert_eq!(
                    matched,
                    mine.len(),
                    "{} on {img}: cac {mine:?}\nonnxruntime {theirs:?}",
                    e.name
                );
                assert_eq!(theirs.len(), mine.len(), "{} on {img}", e.name);
            }
            compared += mine.len();
        }
    }
    assert!(compared > 0, "no detection was compared");
}

#[test]
fn torchvision_ssdlite_dense_export_matches_onnxruntime() {
    let Some((dir, shared)) = exports_and_shared() else {
        return;
    };
    let dev = support::device();
    let model = dir.join("ssdlite.onnx");
    // The TOML written beside it: stretch, torchvision's mean/std, probabilities, xyxy, names.
    let det = OnnxDetector::load(&model, None, &dev).unwrap();
    assert_eq!(det.config().resize, "stretch");
    assert_eq!(det.config().scores, "probabilities");
    assert_eq!(det.classes().len(), 90);
    assert_eq!(det.classes()[..3], ["person", "bicycle", "car"]);
    let (_, x) = photo(&shared, "horse.png");
    let (net, _) = det.network_input(x.clone()).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let (input, output) = (tmp.path().join("in.json"), tmp.path().join("out.json"));
    let data: Vec<f32> = net
        .to_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap();
    write(&input, "images", &net.dims(), &data);
    let st = Command::new("python3")
        .arg(support::root().join("tools/onnx/ort_run.py"))
        .args([model.as_path(), &input, &output])
        .status()
        .unwrap();
    assert!(st.success());
    let want = read(&output);
    let got = det.graph().run_images("images", net, &["output"]).unwrap();
    let rel = compare("ssdlite on horse.png", &got[0], &want["output"]).unwrap();
    // (Its random head gives every class the same 1/91 on photos, so detections would only test
    // ties; the fixture's --check found each of torchvision's own detections, on a random image,
    // as a row of this dense output.)
    eprintln!("ssdlite on horse.png: raw output within {rel:.2e} of the largest magnitude");
    let c = det.candidates(x).unwrap();
    assert_eq!(c.scores.dims(), [1, 3234, 90]);
}

#[test]
fn split_head_reads_boxes_and_scores_from_two_outputs() {
    let Some(dir) = fixtures() else { return };
    let dev = support::device();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("split.toml");
    std::fs::write(
        &cfg,
        "output = \"scores\"\nboxes = \"boxes\"\nbox_format = \"xyxy\"\nresize = \"stretch\"\n",
    )
    .unwrap();
    let model = dir.join("split_head.onnx");
    let det = OnnxDetector::load(&model, Some(&cfg), &dev).unwrap();
    let input = read(&dir.join("split_head.input.json"));
    let want = read(&dir.join("split_head.expected.json"));
    let x: Vec<f32> = input["images"].data.iter().map(|&v| v as f32).collect();
    let x = Tensor::<4>::from_data(TensorData::new(x, [1, 3, 64, 64]), &dev);
    let c = det.candidates(x.clone()).unwrap();
    let host =
        |t: Tensor<3>| -> Vec<f32> { t.to_data().convert::<f32>().try_into_vec::<f32>().unwrap() };
    let (boxes, scores, logits) = (host(c.boxes), host(c.scores), host(c.logits));
    let close = |a: &[f32], b: &[f64], tol: f64| {
        a.len() == b.len() && a.iter().zip(b).all(|(p, q)| (*p as f64 - q).abs() <= tol)
    };
    assert!(close(&boxes, &want["boxes"].data, 1e-3), "boxes differ");
    assert!(close(&scores, &want["scores"].data, 1e-6), "scores differ");
    // The tapped logits are the sigmoid's input: log(p / (1 - p)) of onnxruntime's p.
    let lo: Vec<f64> = want["scores"]
        .data
        .iter()
        .map(|p| (p / (1.0 - p)).ln())
        .collect();
    assert!(close(&logits, &lo, 1e-3), "logits differ");
    // And the config refuses a split head without its boxes.
    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, "head = \"split\"\n").unwrap();
    let e = format!(
        "{:#}",
        OnnxDetector::load(&model, Some(&bad), &dev).err().unwrap()
    );
    assert!(e.contains("bad.toml") && e.contains("boxes"), "{e}");
    det.detect(x).unwrap();
}

#[test]
fn grad_cam_reaches_an_onnx_graph_and_its_gradient_matches_central_differences() {
    use cac::eval::gradcam;
    let Some((dir, shared)) = exports_and_shared() else {
        return;
    };
    let dev = support::device();
    let det = OnnxDetector::load(&dir.join("yolov8n.onnx"), None, &dev).unwrap();
    let (_, x) = photo(&shared, "horse.png");
    let layers = gradcam::layers(&det, x.clone()).unwrap();
    let io = det
        .cam_io(x.clone())
        .unwrap()
        .expect("YOLOv8n exposes its graph");
    // The default layer is the neck's last concatenation on the finest grid (40² at 320²).
    let default = layers
        .iter()
        .find(|l| l.name == io.default_layer)
        .expect("listed");
    assert_eq!(
        (default.op.as_str(), default.shape[2]),
        ("Concat", 40),
        "{default:?}"
    );
    let act = gradcam::activation(&io, &io.default_layer).unwrap();
    let class = 17; // horse
    let (score, g) = gradcam::class_score(&io, &io.default_layer, &act, class, true).unwrap();
    let g = g.unwrap();
    assert!(score.is_finite() && g.iter().any(|v| *v != 0.0));
    let mut rng = 3u64;
    let mut next = || {
        rng = rng
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((rng >> 33) as f32) / (1u64 << 31) as f32 - 0.5
    };
    let scale = act.values.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let h = 1e-3 * scale;
    let at = |v: &[f32], t: f32| -> f64 {
        let mut a = act.clone();
        a.values.iter_mut().zip(v).for_each(|(x, d)| *x += t * d);
        gradcam::class_score(&io, &io.default_layer, &a, class, false)
            .unwrap()
            .0 as f64
    };
    let mut verdict = None;
    for _ in 0..4 {
        let v: Vec<f32> = (0..act.values.len()).map(|_| next()).collect();
        let (lo, mid, hi) = (at(&v, -h), at(&v, 0.0), at(&v, h));
        let (left, right) = ((mid - lo) / h as f64, (hi - mid) / h as f64);
        if (left - right).abs() > 2e-2 * left.abs().max(right.abs()) {
            continue; // the maximum changed candidate inside the step
        }
        let analytic: f64 = g.iter().zip(&v).map(|(a, b)| *a as f64 * *b as f64).sum();
        let numeric = (hi - lo) / (2.0 * h as f64);
        verdict = Some((analytic, numeric));
        break;
    }
    let (analytic, numeric) = verdict.expect("a smooth direction");
    eprintln!("Grad-CAM on YOLOv8n: d score along a random direction {analytic:.5e}, central differences {numeric:.5e}");
    assert!((analytic - numeric).abs() <= 2e-2 * analytic.abs().max(numeric.abs()));
    let cam = gradcam::grad_cam(&det, x, class, None).unwrap();
    assert_eq!(cam.grid, (40, 40));
    assert!(cam.map.iter().all(|v| (0.0..=1.0).contains(v)));
}

/// Grad-CAM on a YOLOv5-repository head (its sigmoid over `[1, 3, h, w, 5 + C]`, rank 5): the
/// class score is the class's logit, read after box and objectness; a softmax head (SSDlite) is
/// refused saying why.
#[test]
fn grad_cam_reads_a_rank_5_yolov5_head_and_names_why_a_softmax_head_has_none() {
    use cac::eval::gradcam;
    let Some(dir) = fixtures() else { return };
    let dev = support::device();
    let det = OnnxDetector::load(&dir.join("yolov5_anchor.onnx"), None, &dev).unwrap();
    let n = det.classes().len();
    let x = pattern(64, 64, &dev);
    let io = det.cam_io(x.clone()).unwrap().expect("a graph");
    assert!(!io.logits.is_empty());
    for (name, axis, first) in &io.logits {
        assert_eq!(
            (*first, *axis),
            (5, 3),
            "{name}: classes after box and objectness"
        );
    }
    // The class score is the largest logit of the class: from the raw graph values.
    let act = gradcam::activation(&io, &io.default_layer).unwrap();
    let class = n - 1;
    let (score, _) = gradcam::class_score(&io, &io.default_layer, &act, class, false).unwrap();
    let outs: Vec<&str> = io.logits.iter().map(|(n, ..)| n.as_str()).collect();
    let feeds: Vec<(&str, Tensor<4>)> = io
        .feeds
        .iter()
        .map(|(k, t)| (k.as_str(), t.clone()))
        .collect();
    let mut want = f32::NEG_INFINITY;
    for (t, shape) in io.graph.run_cam(&feeds, None, &outs).unwrap() {
        let v = t
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap();
        let c = *shape.last().unwrap();
        assert_eq!(c, 5 + n);
        want = v.chunks(c).map(|row| row[5 + class]).fold(want, f32::max);
    }
    assert_eq!(score, want);
    assert!(gradcam::class_score(&io, &io.default_layer, &act, n, false).is_err());
    let cam = gradcam::grad_cam(&det, x, class, None).unwrap();
    assert!(cam.map.iter().all(|v| (0.0..=1.0).contains(v)));

    if let Some((dir, _)) = exports_and_shared() {
        let ssd = OnnxDetector::load(&dir.join("ssdlite.onnx"), None, &dev).unwrap();
        let x = Tensor::<4>::zeros([1, 3, 64, 64], &dev);
        let e = format!("{:#}", ssd.cam_io(x).err().expect("refused"));
        assert!(e.contains("ssdlite.onnx") && e.contains("softmax"), "{e}");
    }
}

/// Files that select their boxes inside with top-k (RT-DETR-l; YOLOv10n and YOLO26n exported with
/// `nms=False`) run up to the dense head before the selection. Checked against onnxruntime: the
/// candidates put through the exporter's own top-k (the best 300 of every row × class score)
/// are its output0 — the same scores in order, and, where a score stands apart from its
/// neighbours, the same class and box. Checked against PyTorch: the mean class-0 logit over the
/// rows and its input gradient. An `nms=True` export is refused saying what to export instead.
#[test]
fn files_that_select_inside_run_up_to_their_dense_head() {
    let Some(dir) = fixtures() else { return };
    if !has_ultralytics(dir) {
        return;
    }
    let entries: Vec<Entry> = manifest(dir)
        .models
        .into_iter()
        .filter(|e| e.kind == "selecting")
        .collect();
    let names: Vec<&str> = entries.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(
        names,
        ["rtdetr_l", "yolov10n_e2e", "yolo26n_e2e", "yolov8n_nms"],
        "the selecting exports"
    );
    let train = support::training();
    for e in &entries {
        let path = dir.join(&e.file);
        if e.selects == "nms" {
            let err = format!(
                "{:#}",
                OnnxDetector::load(&path, None, &train).err().unwrap()
            );
            assert!(
                err.contains(&e.file)
                    && err.contains("NMS or top-k selection inside")
                    && err.contains("`nms` left at its default"),
                "{err}"
            );
            continue;
        }
        let det = OnnxDetector::load(&path, None, &train).unwrap();
        let input = &read(&dir.join(format!("{}.input.json", e.name)))["images"];
        let want = &read(&dir.join(format!("{}.expected.json", e.name)))["output0"];
        assert_eq!(want.shape, [1, 300, 6], "{}", e.name);
        let x0: Vec<f32> = input.data.iter().map(|&v| v as f32).collect();
        let x =
            Tensor::<4>::from_data(TensorData::new(x0, [1, 3, 320, 320]), &train).require_grad();
        let c = det.candidates(x.clone()).unwrap();
        let [_, n, k] = c.scores.dims();
        let scores = cac::detect::to_vec(&c.scores).unwrap();
        let boxes = cac::detect::to_vec(&c.boxes).unwrap();
        // cac's own float noise: the boxes again with the input moved by two ulps (seeded signs).
        // A random-weight network amplifies rounding, by how much depends on the CPU's kernels
        // (8.3e-3 px on an AVX2 EPYC, 1.3e-2 on an AVX-512 Xeon for YOLOv10n's boxes). Only
        // where a row is one anchor (the end-to-end YOLOs): RT-DETR's rows are queries its
        // encoder selects, which the jitter reorders, so its bound stays 1e-2 px.
        let rtdetr = e.name.starts_with("rtdetr");
        let moved: Vec<f32> = match rtdetr {
            true => boxes.clone(),
            false => {
                use rand::{Rng, SeedableRng};
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4321);
                let x = input.data.iter().map(|&v| {
                    let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                    (v * (1.0 + sign * 2f64.powi(-22))) as f32
                });
                let x = TensorData::new(x.collect::<Vec<f32>>(), [1, 3, 320, 320]);
                let c = det.candidates(Tensor::<4>::from_data(x, &train)).unwrap();
                cac::detect::to_vec(&c.boxes).unwrap()
            }
        };
        // The exporter's selection: the best 300 (row, class) scores.
        let mut order: Vec<usize> = (0..n * k).collect();
        order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
        let (mut worst_score, mut worst_box, mut compared) = (0.0f64, 0.0f64, 0);
        let mut own_noise = 0.0f64;
        for (i, &flat) in order.iter().take(300).enumerate() {
            let row = &want.data[i * 6..(i + 1) * 6];
            let s = scores[flat] as f64;
            worst_score = worst_score.max((s - row[4]).abs());
            // Apart by more than twice the score bound: the same row in both rankings.
            let apart = |j: usize| (want.data[j * 6 + 4] - row[4]).abs() > 2e-4;
            if !(i == 0 || apart(i - 1)) || !(i == 299 || apart(i + 1)) {
                continue;
            }
            let (q, class) = (flat / k, flat % k);
            assert_eq!(
                class as f64, row[5],
                "{}: class of selected row {i}",
                e.name
            );
            // onnxruntime's box as cac states it: x1, y1, x2, y2 in input pixels.
            let theirs: [f64; 4] = if rtdetr {
                let (cx, cy, w, h) = (
                    row[0] * 320.0,
                    row[1] * 320.0,
                    row[2] * 320.0,
                    row[3] * 320.0,
                );
                [cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0]
            } else {
                [row[0], row[1], row[2], row[3]]
            };
            for (j, t) in theirs.iter().enumerate() {
                worst_box = worst_box.max((boxes[q * 4 + j] as f64 - t).abs());
                own_noise =
                    own_noise.max((boxes[q * 4 + j] as f64 - moved[q * 4 + j] as f64).abs());
            }
            compared += 1;
        }
        let box_bound = (1e-2f64).max(2.0 * own_noise);
        eprintln!(
            "{}: top-300 scores within {worst_score:.2e} of onnxruntime's, {compared} boxes within {worst_box:.2e} px (bound {box_bound:.2e}: cac's own two-ulp spread {own_noise:.2e})",
            e.name
        );
        assert!(worst_score <= 1e-4, "{}: scores {worst_score}", e.name);
        assert!(
            compared >= 10,
            "{}: only {compared} rows stand apart",
            e.name
        );
        assert!(worst_box <= box_bound, "{}: boxes {worst_box} px", e.name);
        // PyTorch's loss and input gradient.
        let torch = read(&dir.join(format!("{}.grad.json", e.name)));
        let loss = c.logits.narrow(2, 0, 1).mean();
        let ours = loss.clone().into_scalar::<f32>() as f64;
        let theirs = torch["loss"].data[0];
        assert!(
            (ours - theirs).abs() <= 1e-4 * theirs.abs().max(1.0),
            "{}: loss {ours} vs PyTorch {theirs}",
            e.name
        );
        let grads = loss.backward();
        let g: Vec<f32> = x
            .grad(&grads)
            .unwrap()
            .to_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap();
        let t = &torch["images"].data;
        let dot: f64 = g.iter().zip(t).map(|(a, b)| *a as f64 * b).sum();
        let (na, nb) = (
            g.iter().map(|a| (*a as f64).powi(2)).sum::<f64>().sqrt(),
            t.iter().map(|b| b * b).sum::<f64>().sqrt(),
        );
        let diff = g
            .iter()
            .zip(t)
            .map(|(a, b)| (*a as f64 - b).powi(2))
            .sum::<f64>()
            .sqrt()
            / nb;
        // Held to max(1e-3, 2 x PyTorch's own spread when the input moves by two ulps).
        let noise = torch["noise"].data[0];
        let bound = (2.0 * noise).max(1e-3);
        eprintln!(
            "{}: loss {ours:.6} (PyTorch {theirs:.6}), input gradient relative error {diff:.2e} \
             (bound {bound:.2e}; PyTorch's own spread {noise:.2e}), cosine {:.6}",
            e.name,
            dot / (na * nb)
        );
        assert!(
            diff <= bound,
            "{}: input gradient relative error {diff} > {bound}",
            e.name
        );
    }
    // Each trains through the command line: the overlap rule over the queries / one-to-one rows.
    let tmp = tempfile::tempdir().unwrap();
    let scene = small_scene(tmp.path());
    for stem in ["rtdetr_l", "yolov10n_e2e"] {
        let run = tmp.path().join(stem);
        let spec = format!("onnx:{}", dir.join(format!("{stem}.onnx")).display());
        support::cac_ok(&[
            "train",
            "--config",
            scene.to_str().unwrap(),
            "--models",
            &spec,
            "--iterations",
            "2",
            "--batch",
            "1",
            "--out",
            run.to_str().unwrap(),
        ]);
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(run.join("run.json")).unwrap()).unwrap();
        assert_eq!(json["finished"], true, "{stem}: {json}");
    }
}

#[test]
fn input_gradient_through_the_tapped_logits_matches_central_differences() {
    let Some(dir) = fixtures() else { return };
    let train = support::training();
    // The small model: smooth (SiLU, no pooling), so central differences are a fair oracle. (On
    // the random-weight YOLOv8n, whose max-pools switch within any useful step, the central
    // difference itself moves by 2x between steps 3e-4 and 1e-2: not an oracle.)
    {
        let file = "yolov5_anchor.onnx";
        let path = dir.join(file);
        let det = OnnxDetector::load(&path, None, &train).unwrap();
        let (h, w) = (96, 128);
        let mut rng = 7u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((rng >> 33) as f32) / (1u64 << 31) as f32
        };
        let x0: Vec<f32> = (0..3 * h * w).map(|_| 0.2 + 0.6 * next()).collect();
        let v: Vec<f32> = (0..3 * h * w).map(|_| next() - 0.5).collect();
        let img =
            |d: &[f32]| Tensor::<4>::from_data(TensorData::new(d.to_vec(), [1, 3, h, w]), &train);
        // Loss: the person logits (a targeted term), the car scores, and the boxes.
        let loss = |x: Tensor<4>| {
            let c = det.candidates(x).unwrap();
            c.logits.narrow(2, 0, 1).mean()
                + c.scores.narrow(2, 2, 1).sum().mul_scalar(0.1)
                + c.boxes.mean().mul_scalar(1e-3)
        };
        let x = img(&x0).require_grad();
        let l = loss(x.clone());
        let grads = l.backward();
        let g: Vec<f32> = x
            .grad(&grads)
            .unwrap()
            .to_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap();
        let analytic: f64 = g
            .iter()
            .zip(&v)
            .map(|(a, b)| (*a as f64) * (*b as f64))
            .sum();
        let hstep = 1e-2f32;
        let at = |s: f32| -> f64 {
            let d: Vec<f32> = x0.iter().zip(&v).map(|(a, b)| a + s * b).collect();
            loss(img(&d)).into_scalar::<f32>() as f64
        };
        let numeric = (at(hstep) - at(-hstep)) / (2.0 * hstep as f64);
        let rel = (analytic - numeric).abs() / numeric.abs().max(analytic.abs()).max(1e-6);
        eprintln!("{file}: directional derivative {analytic:.6e}, central differences {numeric:.6e} (rel {rel:.2e})");
        assert!(
            rel < 2e-2,
            "{file}: analytic {analytic} vs numeric {numeric}"
        );
        assert!(g.iter().all(|v| v.is_finite()));
    }
}

/// Each differentiable op case: the input gradient of a random projection of the output
/// against central differences.
#[test]
fn op_gradients_match_central_differences() {
    let Some(dir) = fixtures() else { return };
    let train = support::training();
    let mut checked = Vec::new();
    let mut failures = Vec::new();
    for e in manifest(dir).models.iter().filter(|e| e.kind == "op") {
        let path = dir.join(&e.file);
        let stem = path.with_extension("");
        let inputs = read(&stem.with_extension("input.json"));
        let want = read(&stem.with_extension("expected.json"));
        // One float input, float outputs only.
        if inputs.len() != 1 || want.values().any(|t| t.dtype.is_some()) {
            continue;
        }
        let (name, x0) = inputs.iter().next().unwrap();
        if x0.dtype.is_some() {
            continue;
        }
        let g = onnx::load_graph(&path, &train).unwrap();
        let n = x0.data.len();
        let x0: Vec<f32> = x0.data.iter().map(|&v| v as f32).collect();
        let mut rng = 11u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((rng >> 33) as f32) / (1u64 << 31) as f32 - 0.5
        };
        let outs: Vec<&str> = e.outputs.iter().map(|s| s.as_str()).collect();
        let weights: Vec<Vec<f32>> = outs
            .iter()
            .map(|o| (0..want[*o].data.len()).map(|_| next()).collect())
            .collect();
        let shape = inputs.values().next().unwrap().shape.clone();
        let loss = |x: Tensor<1>| -> Option<Tensor<1>> {
            let val = Val::D(Dev::new(x, shape.clone()).unwrap());
            let got = g.run(&[(name.as_str(), val)], &outs).ok()?;
            let mut total: Option<Tensor<1>> = None;
            for (o, w) in got.iter().zip(&weights) {
                let Val::D(d) = o else { return None };
                let flat: Tensor<1> = d.t.clone().reshape([w.len()]);
                let wt = Tensor::<1>::from_data(TensorData::new(w.clone(), [w.len()]), &train);
                let term = (flat * wt).sum();
                total = Some(match total {
                    Some(t) => t + term,
                    None => term,
                });
            }
            total
        };
        let x = Tensor::<1>::from_data(TensorData::new(x0.clone(), [n]), &train).require_grad();
        let Some(l) = loss(x.clone()) else { continue };
        let grads = l.backward();
        let Some(gx) = x.grad(&grads) else { continue };
        let gv: Vec<f32> = gx.to_data().convert::<f32>().try_into_vec::<f32>().unwrap();
        let h = 1e-3f32;
        let at = |v: &[f32], s: f32| -> f64 {
            let d: Vec<f32> = x0.iter().zip(v).map(|(a, b)| a + s * b).collect();
            loss(Tensor::<1>::from_data(TensorData::new(d, [n]), &train))
                .unwrap()
                .into_scalar::<f32>() as f64
        };
        let close = |a: f64, b: f64| (a - b).abs() <= 2e-2 * a.abs().max(b.abs()) + 2e-3;
        // A kink (max-pool switch, ReLU, clip) inside the step shows as one-sided differences
        // that disagree: such a direction is redrawn (at most four times).
        let mut verdict = None;
        for _ in 0..4 {
            let v: Vec<f32> = (0..n).map(|_| next()).collect();
            let (lo, mid, hi) = (at(&v, -h), at(&v, 0.0), at(&v, h));
            let (left, right) = ((mid - lo) / h as f64, (hi - mid) / h as f64);
            if !close(left, right) {
                continue;
            }
            let analytic: f64 = gv.iter().zip(&v).map(|(a, b)| *a as f64 * *b as f64).sum();
            let numeric = (hi - lo) / (2.0 * h as f64);
            verdict = Some((close(analytic, numeric), analytic, numeric));
            break;
        }
        match verdict {
            Some((true, ..)) => {}
            Some((false, analytic, numeric)) => failures.push(format!(
                "{}: analytic {analytic:.5}, central differences {numeric:.5}",
                e.name
            )),
            None => failures.push(format!("{}: a kink within every step", e.name)),
        }
        checked.push(e.name.clone());
    }
    eprintln!("{} op cases checked: {}", checked.len(), checked.join(" "));
    assert!(
        checked.len() >= 95,
        "only {} cases were differentiable",
        checked.len()
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn black_white_and_saturated_noise_stay_finite() {
    let Some(dir) = fixtures() else { return };
    let dev = support::device();
    for file in ["yolov5_anchor.onnx", "yolov8n.onnx", "yolov5su.onnx"] {
        let path = dir.join(file);
        if !path.is_file() {
            has_ultralytics(dir);
            continue;
        }
        let det = OnnxDetector::load(&path, None, &dev).unwrap();
        let n = 3 * 64 * 80;
        let noise: Vec<f32> = (0..n)
            .map(|i| ((i * 2654435761) >> 7) as f32 % 2.0)
            .map(|v| v.floor())
            .collect();
        for (what, data) in [
            ("black", vec![0.0; n]),
            ("white", vec![1.0; n]),
            ("noise", noise),
        ] {
            let x = Tensor::<4>::from_data(TensorData::new(data, [1, 3, 64, 80]), &dev);
            let c = det.candidates(x.clone()).unwrap();
            for (name, t) in [
                ("boxes", c.boxes),
                ("scores", c.scores),
                ("logits", c.logits),
            ] {
                let v: Vec<f32> = t.to_data().convert::<f32>().try_into_vec::<f32>().unwrap();
                assert!(
                    v.iter().all(|x| x.is_finite()),
                    "{file} on {what}: {name} not finite"
                );
            }
            det.detect(x).unwrap();
        }
    }
}

/// Encodes a one-node model with `op` (opset `opset`) and an input of shape `dims`.
fn tiny_model(path: &Path, op: &str, opset: i64, dims: &[Option<i64>]) {
    tiny_chain(path, &[op], opset, dims)
}

/// Encodes a chain of nodes `ops` (the first named "the_node", then "node1", ...; each reads
/// the previous one's output) with an input of shape `dims`.
fn tiny_chain(path: &Path, ops: &[&str], opset: i64, dims: &[Option<i64>]) {
    tiny_chain_meta(path, ops, opset, dims, &[])
}

/// [`tiny_chain`] with metadata `meta` (key, value).
fn tiny_chain_meta(
    path: &Path,
    ops: &[&str],
    opset: i64,
    dims: &[Option<i64>],
    meta: &[(&str, &str)],
) {
    use cac::detect::onnx::proto::*;
    use prost::Message;
    let dim = |d: &Option<i64>| Dimension {
        dim_value: *d,
        dim_param: if d.is_none() { Some("h".into()) } else { None },
    };
    let io = |name: &str| ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            tensor_type: Some(TypeProtoTensor {
                elem_type: 1,
                shape: Some(TensorShapeProto {
                    dim: dims.iter().map(dim).collect(),
                }),
            }),
        }),
    };
    let m = ModelProto {
        ir_version: 8,
        opset_import: vec![OperatorSetIdProto {
            domain: String::new(),
            version: opset,
        }],
        graph: Some(GraphProto {
            node: ops
                .iter()
                .enumerate()
                .map(|(k, op)| NodeProto {
                    input: vec![if k == 0 {
                        "images".into()
                    } else {
                        format!("v{}", k - 1)
                    }],
                    output: vec![if k + 1 == ops.len() {
                        "output0".into()
                    } else {
                        format!("v{k}")
                    }],
                    name: if k == 0 {
                        "the_node".into()
                    } else {
                        format!("node{k}")
                    },
                    op_type: op.to_string(),
                    ..Default::default()
                })
                .collect(),
            name: "g".into(),
            input: vec![io("images")],
            output: vec![io("output0")],
            ..Default::default()
        }),
        metadata_props: meta
            .iter()
            .map(|(k, v)| StringStringEntryProto {
                key: k.to_string(),
                value: v.to_string(),
            })
            .collect(),
        ..Default::default()
    };
    std::fs::write(path, m.encode_to_vec()).unwrap();
}

#[test]
fn bad_files_are_refused_naming_the_file_node_and_op() {
    let dev = support::device();
    let tmp = tempfile::tempdir().unwrap();
    let err = |p: &Path| {
        format!(
            "{:#}",
            OnnxDetector::load(p, None, &dev).err().expect("refused")
        )
    };
    let garbage = tmp.path().join("garbage.onnx");
    std::fs::write(&garbage, b"\xff\xff\xff\xffnot protobuf").unwrap();
    let e = err(&garbage);
    assert!(
        e.contains("garbage.onnx") && e.contains("not an ONNX model"),
        "{e}"
    );

    let unsupported = tmp.path().join("einsum.onnx");
    tiny_model(
        &unsupported,
        "Einsum",
        17,
        &[Some(1), Some(3), Some(32), Some(32)],
    );
    let e = err(&unsupported);
    assert!(
        e.contains("einsum.onnx") && e.contains("the_node") && e.contains("Einsum"),
        "{e}"
    );

    // Every unsupported op type at once, and NMS / top-k inside told how to export instead.
    let several = tmp.path().join("several.onnx");
    tiny_chain(
        &several,
        &["Einsum", "Relu", "TopK", "Einsum", "NonZero"],
        17,
        &[Some(1), Some(3), Some(32), Some(32)],
    );
    let e = err(&several);
    assert!(
        e.contains("several.onnx")
            && e.contains("2 op types")
            && e.contains("Einsum (2 nodes, first \"the_node\")")
            && e.contains("NonZero (node \"node4\")")
            && e.contains("NMS or top-k selection inside"),
        "{e}"
    );
    assert!(!err(&unsupported).contains("NMS"), "Einsum alone is no NMS");
    // Top-k with the gathers that pick its rows, every op of them supported: still refused as
    // selection inside (an end-to-end head's `[1, 300, 6]` would read as one class).
    let e2e = tmp.path().join("e2e.onnx");
    tiny_chain(
        &e2e,
        &["Relu", "TopK", "GatherElements"],
        17,
        &[Some(1), Some(3), Some(32), Some(32)],
    );
    let e = err(&e2e);
    assert!(
        e.contains("e2e.onnx")
            && e.contains("selects boxes inside")
            && e.contains("TopK (node \"node1\")")
            && e.contains("GatherElements (node \"node2\")")
            && e.contains("dense head"),
        "{e}"
    );
    // An ultralytics segmentation export: refused as not a detector, before its ops are listed.
    let seg = tmp.path().join("seg.onnx");
    tiny_chain_meta(
        &seg,
        &["ConvTranspose"],
        17,
        &[Some(1), Some(3), Some(32), Some(32)],
        &[("task", "segment")],
    );
    let e = err(&seg);
    assert!(
        e.contains("seg.onnx") && e.contains("not a detection model") && e.contains("mask"),
        "{e}"
    );

    let opset = tmp.path().join("opset.onnx");
    tiny_model(
        &opset,
        "Sigmoid",
        30,
        &[Some(1), Some(3), Some(32), Some(32)],
    );
    let e = err(&opset);
    assert!(e.contains("opset.onnx") && e.contains("opset 30"), "{e}");

    let dynamic = tmp.path().join("dynamic.onnx");
    tiny_model(&dynamic, "Sigmoid", 17, &[Some(1), Some(3), None, None]);
    let e = err(&dynamic);
    assert!(
        e.contains("dynamic.onnx") && e.contains("input_size"),
        "{e}"
    );
    // With the size in a config beside it, the same file loads (and has no dense output).
    std::fs::write(dynamic.with_extension("toml"), "input_size = [32, 32]\n").unwrap();
    let e = err(&dynamic);
    assert!(e.contains("dense"), "{e}");
    std::fs::write(
        dynamic.with_extension("toml"),
        "input_size = [32, 32]\nhed = 1\n",
    )
    .unwrap();
    let e = err(&dynamic);
    assert!(e.contains("dynamic.toml") && e.contains("hed"), "{e}");

    // The catalogue refuses a missing file before anything loads.
    let e = cac::detect::check_spec("onnx:/no/such/model.onnx")
        .unwrap_err()
        .to_string();
    assert!(e.contains("/no/such/model.onnx"), "{e}");
}

#[test]
fn the_cli_inspects_detects_trains_and_evaluates_with_an_onnx_model() {
    let Some((dir, shared)) = exports_and_shared() else {
        return;
    };
    let model = dir.join("yolov8n.onnx");
    let spec = format!("onnx:{}", model.display());
    let text = support::cac_ok(&["models", "inspect", model.to_str().unwrap()]);
    assert!(
        text.contains("ai.onnx=18")
            && text.contains("output0 float32 [1, 84, 2100]")
            && text.contains("Conv×64"),
        "{text}"
    );
    assert!(
        text.contains("as a detector: 320x320 input, 80 classes (person"),
        "{text}"
    );
    assert!(!text.contains("(unsupported)"), "{text}");

    // cac detect prints what the library detects.
    let img = shared.join("reference/images/horse.png");
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("low.toml");
    std::fs::write(&cfg, "score_threshold = 0.3\n").unwrap();
    let spec_cfg = format!("{spec}:{}", cfg.display());
    let text = support::cac_ok(&[
        "detect",
        img.to_str().unwrap(),
        "--model",
        &spec_cfg,
        "--json",
    ]);
    let dev = support::device();
    let det = OnnxDetector::load(&model, Some(&cfg), &dev).unwrap();
    let want = det.detect(photo(&shared, "horse.png").1).unwrap().remove(0);
    let lines: Vec<serde_json::Value> = text
        .lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), want.len(), "{text}");
    for (l, d) in lines.iter().zip(&want) {
        assert_eq!(l["label"], d.label);
        assert_eq!(l["class_id"], d.class_id);
        let near = |v: &serde_json::Value, x: f32| (v.as_f64().unwrap() - x as f64).abs() < 1e-3;
        assert!(
            near(&l["score"], d.score) && near(&l["box"][2], d.bbox[2]),
            "{l}"
        );
    }

    // A source of cac train and a column of cac eval.
    let run = tmp.path().join("run");
    let scene = small_scene(tmp.path());
    support::cac_ok(&[
        "train",
        "--config",
        scene.to_str().unwrap(),
        "--models",
        &spec,
        "--iterations",
        "2",
        "--batch",
        "1",
        "--out",
        run.to_str().unwrap(),
    ]);
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("run.json")).unwrap()).unwrap();
    assert_eq!(json["finished"], true, "{json}");
    let eval = tmp.path().join("eval");
    support::cac_ok(&[
        "eval",
        "--config",
        scene.to_str().unwrap(),
        "--texture",
        &format!("original,CAC={}", run.display()),
        "--models",
        &format!("{spec},nanodet"),
        "--views",
        "1",
        "--sets",
        "fv",
        "--out",
        eval.to_str().unwrap(),
    ]);
    let csv = std::fs::read_to_string(eval.join("p05_fv.csv")).unwrap();
    assert!(csv.lines().next().unwrap().contains("yolov8n"), "{csv}");
}

/// A user's detector trained on its own classes (`yolov8n_own.onnx`: forklift, dog, pallet in
/// its `names` metadata) through the command line: every place that names a class resolves it
/// against the model's classes, refuses a name the model lacks by listing them, and maps an
/// ensemble's classes by name.
#[test]
fn a_model_with_its_own_classes_is_attacked_and_judged_on_them() {
    let Some((dir, _shared)) = exports_and_shared() else {
        return;
    };
    let model = dir.join("yolov8n_own.onnx");
    let spec = format!("onnx:{}", model.display());
    let text = support::cac_ok(&["models", "inspect", model.to_str().unwrap()]);
    assert!(text.contains("3 classes (forklift, dog, pallet"), "{text}");
    let tmp = tempfile::tempdir().unwrap();
    let scene = small_scene(tmp.path());
    let fails = |args: &[&str]| {
        let out = support::cac(args);
        assert!(!out.status.success(), "{args:?} succeeded");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let train = |out: &Path, models: &str, extra: &[&str]| -> Vec<String> {
        let mut a: Vec<String> = [
            "train",
            "--config",
            scene.to_str().unwrap(),
            "--models",
            models,
            "--iterations",
            "2",
            "--batch",
            "1",
            "--out",
            out.to_str().unwrap(),
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    fn strs(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }

    // The default target, "person", is not one of the model's classes: refused, listing them
    // (before: class 0, "forklift", attacked in silence).
    let args = train(&tmp.path().join("r0"), &spec, &[]);
    let e = fails(&strs(&args));
    assert!(
        e.contains("has no class \"person\"")
            && e.contains("\"forklift\", \"dog\", \"pallet\"")
            && e.contains("--target"),
        "{e}"
    );
    assert!(
        !tmp.path().join("r0").exists(),
        "a refused run leaves no folder behind"
    );
    // Hidden classes likewise.
    let args = train(&tmp.path().join("r1"), &spec, &["--hide"]);
    let e = fails(&strs(&args));
    assert!(
        e.contains("has no class \"car\"") && e.contains("--hide-classes"),
        "{e}"
    );
    // An ensemble with a COCO model: a class the COCO model lacks is refused naming it.
    let args = train(
        &tmp.path().join("r2"),
        &format!("{spec},nanodet"),
        &["--target", "pallet"],
    );
    let e = fails(&strs(&args));
    assert!(e.contains("nanodet has no class \"pallet\""), "{e}");

    // Attacked to one of its own classes, then to a class both models have (mapped by name:
    // "dog" is 1 in the model, 16 in COCO).
    let run = tmp.path().join("run");
    let args = train(&run, &spec, &["--target", "pallet"]);
    support::cac_ok(&strs(&args));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("run.json")).unwrap()).unwrap();
    assert_eq!(json["finished"], true, "{json}");
    assert_eq!(json["attack"]["target"], "pallet", "{json}");
    let both = tmp.path().join("both");
    let args = train(&both, &format!("{spec},nanodet"), &["--target", "dog"]);
    support::cac_ok(&strs(&args));

    // Judged on its classes: the default true classes (car, truck) are refused, named ones run
    // and the report names them.
    let eval = tmp.path().join("eval");
    let eval_args = |true_classes: Option<&str>| -> Vec<String> {
        let mut a: Vec<String> = [
            "eval",
            "--config",
            scene.to_str().unwrap(),
            "--texture",
            &format!("original,CAC={}", run.display()),
            "--models",
            &spec,
            "--views",
            "1",
            "--sets",
            "fv",
            "--target",
            "pallet",
            "--out",
            eval.to_str().unwrap(),
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        if let Some(t) = true_classes {
            a.extend(["--true-classes".to_string(), t.to_string()]);
        }
        a
    };
    let e = fails(&strs(&eval_args(None)));
    assert!(
        e.contains("has no class \"car\"") && e.contains("--true-classes"),
        "{e}"
    );
    support::cac_ok(&strs(&eval_args(Some("forklift,dog"))));
    let report = std::fs::read_to_string(eval.join("report.html")).unwrap();
    assert!(
        report.contains("a true-class (forklift, dog) detection")
            && report.contains("a pallet detection"),
        "the report does not name the model's classes"
    );
    let csv = std::fs::read_to_string(eval.join("p05_fv.csv")).unwrap();
    assert!(csv.lines().next().unwrap().contains("yolov8n_own"), "{csv}");

    // Grad-CAM of one of its classes; a COCO name it lacks is refused.
    let img = tmp.path().join("view.png");
    image::RgbImage::from_pixel(64, 48, image::Rgb([120, 90, 60]))
        .save(&img)
        .unwrap();
    let out = tmp.path().join("cam.png");
    let e = fails(&[
        "explain",
        img.to_str().unwrap(),
        "--model",
        &spec,
        "--class",
        "person",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(e.contains("has no class \"person\""), "{e}");
    support::cac_ok(&[
        "explain",
        img.to_str().unwrap(),
        "--model",
        &spec,
        "--class",
        "pallet",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(out.is_file());
}

/// An fp16 export (ultralytics `half=True`, nodes written out of topological order): loaded
/// (sorted) and run in f32 arithmetic on its f16 weights. The oracle for that is onnxruntime
/// running the same file with its f16 weights and casts widened to f32 (exact on the weights):
/// cac must match it like an f32 model; onnxruntime's own fp16 output differs from it by fp16
/// rounding, and cac from onnxruntime's fp16 output by no more than that rounding (both printed).
#[test]
fn an_fp16_export_loads_out_of_order_and_runs_its_weights_in_f32() {
    let Some((dir, _shared)) = exports_and_shared() else {
        return;
    };
    let dev = support::device();
    let half = dir.join("yolov8n_half.onnx");
    let g = onnx::load_graph(&half, &dev).unwrap();
    let input = read(&dir.join("yolov8n_half.input.json"));
    let out = |f: &str| read(&dir.join(f)).remove("output0").unwrap();
    let (ort16, ort16_plain, widened) = (
        out("yolov8n_half.expected.json"),
        out("yolov8n_half.unoptimised.json"),
        out("yolov8n_half.widened.json"),
    );
    let x = feed(&input["images"]);
    let got = g.run(&[("images", x)], &["output0"]).unwrap().remove(0);
    let rel = |a: &[f64], b: &[f64]| {
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()))
            / scale
    };
    let mine: Vec<f64> = got
        .host()
        .unwrap()
        .floats()
        .iter()
        .map(|&v| v as f64)
        .collect();
    assert!(mine.iter().all(|v| v.is_finite()));
    let cac_16 = rel(&mine, &ort16.data);
    let ort_16 = rel(&ort16.data, &widened.data);
    let spread_16 = rel(&ort16_plain.data, &ort16.data);
    eprintln!(
        "fp16 export: cac vs onnxruntime fp16 {cac_16:.2e}; onnxruntime fp16 vs the widened \
         file {ort_16:.2e}; onnxruntime fp16 against itself (unoptimised) {spread_16:.2e}"
    );
    let cac_wide = compare_within(
        "yolov8n_half against its widened file",
        &got,
        &widened,
        1e-3,
    )
    .unwrap();
    eprintln!("fp16 export: cac vs the widened file {cac_wide:.2e}");
    assert!(
        cac_16 <= 1.5 * ort_16.max(spread_16),
        "cac is further from onnxruntime's fp16 output ({cac_16:.2e}) than fp16 rounding moves it"
    );
    // As a detector with no config: the class sigmoids are tapped through the closing Cast, so
    // the logits are exact (their sigmoids are the scores).
    let det = OnnxDetector::load(&half, None, &dev).unwrap();
    assert_eq!(det.classes().len(), 80);
    let x = pattern(200, 300, &dev);
    let c = det.candidates(x.clone()).unwrap();
    let (l, p) = (
        c.logits
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap(),
        c.scores
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap(),
    );
    assert!(l.iter().all(|v| v.is_finite()));
    let worst = l
        .iter()
        .zip(&p)
        .map(|(l, p)| (1.0 / (1.0 + (-l).exp()) - p).abs())
        .fold(0.0f32, f32::max);
    assert!(
        worst < 1e-5,
        "sigmoid(logit) differs from the score by {worst}"
    );
    det.detect(x).unwrap();
}
