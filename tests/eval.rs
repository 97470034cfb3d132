//! Evaluation: Grad-CAM looks at the vehicle and its gradients match finite differences; `cac
//! eval --config` runs other objects (barrel, container) with the stop-sign target, pairs the
//! views across textures, and resumes from its cache.

mod support;

use cac::detect::{self, labels, Detector};
use cac::environment::{Brightness, Condition, EnvConfig, Environment};
use cac::eval::gradcam;
use cac::render::{self, RenderSettings, Renderer, Viewpoint};
use cac::scene::generate;
use rand::{Rng, SeedableRng};
use support::device as inference;

fn nanodet() -> Box<dyn Detector> {
    detect::load("nanodet", support::models(), &inference()).unwrap()
}

/// The pickup from its side at street level: an image NanoDet finds as a vehicle, and its box.
fn side_view() -> (burn::tensor::Tensor<4>, [f32; 4]) {
    let mut s = generate::pickup();
    s.normalise(0.0, None);
    let res = 64;
    let atlas = s.initial_atlas(res);
    let r = Renderer::new(
        s,
        RenderSettings {
            width: 416,
            height: 416,
            samples: 1,
            vfov_deg: 45.0,
            atlas_res: res,
        },
    )
    .unwrap();
    let env = Environment::new(EnvConfig::default()).unwrap();
    let c = Condition::plain(Viewpoint::new(80.0, 10.0, 1.5), Brightness::Bright);
    let plan = cac::environment::plan(&r, &env, &c).unwrap();
    let gt = plan.object_box.unwrap();
    let img = render::composite(&[plan], render::atlas_tensor(&atlas, &inference()));
    (img, gt)
}

#[test]
fn grad_cam_peaks_on_the_vehicle_and_its_gradient_matches_finite_differences() {
    let det = nanodet();
    let (img, gt) = side_view();
    let dets = det.detect(img.clone()).unwrap().remove(0);
    let truck = labels::class_id("truck").unwrap();
    let car = labels::class_id("car").unwrap();
    let found = dets
        .iter()
        .filter(|d| d.class_id == truck || d.class_id == car)
        .max_by(|a, b| a.score.total_cmp(&b.score))
        .expect("NanoDet finds the pickup as a car or truck (else the test is meaningless)");
    let cam = gradcam::grad_cam(det.as_ref(), img.clone(), found.class_id, None).unwrap();
    let (px, py) = cam.peak(416, 416);
    assert!(
        (px as f32) >= gt[0] && (px as f32) < gt[2] && (py as f32) >= gt[1] && (py as f32) < gt[3],
        "Grad-CAM peak ({px}, {py}) outside the vehicle's box {gt:?}"
    );
    assert!(cam.map.iter().all(|v| (0.0..=1.0).contains(v)));
    let inside: f32 = {
        let up = cam.upsampled(416, 416);
        let mut s = [0.0f32; 2];
        for (i, v) in up.iter().enumerate() {
            let (x, y) = ((i % 416) as f32 + 0.5, (i / 416) as f32 + 0.5);
            let k = (x >= gt[0] && x < gt[2] && y >= gt[1] && y < gt[3]) as usize;
            s[k] += v;
        }
        s[1] / (s[0] + s[1])
    };
    let area = (gt[2] - gt[0]) * (gt[3] - gt[1]) / (416.0 * 416.0);
    assert!(
        inside > area,
        "the map is no more on the box ({inside:.2} of its mass) than a uniform map ({area:.2})"
    );

    // The gradient at the layer against central differences of the re-injected forward pass:
    // along the gradient itself (slope = |g|) and along random directions (slope = g·r).
    let io = det.cam_io(img).unwrap().unwrap();
    let layer = io.default_layer.clone();
    let act = gradcam::activation(&io, &layer).unwrap();
    let (s0, g) = gradcam::class_score(&io, &layer, &act, found.class_id, true).unwrap();
    let g = g.unwrap();
    assert!(
        (s0 - cam.score).abs() < 1e-4,
        "same score: {s0} vs {}",
        cam.score
    );
    // Re-injecting the layer's own activation reproduces the plain forward pass.
    let logits = det.candidates(side_view().0).unwrap().logits;
    let [_, n, c] = logits.dims();
    assert_eq!(c, 80);
    let plain = logits
        .narrow(2, found.class_id, 1)
        .reshape([n])
        .max()
        .into_scalar::<f32>();
    assert!(
        (plain - s0).abs() < 1e-3 * plain.abs().max(1.0),
        "injected forward {s0} != plain forward {plain}"
    );
    let norm = g.iter().map(|v| v * v).sum::<f32>().sqrt();
    assert!(norm > 0.0, "no gradient");
    let slope = |dir: &[f32], eps: f32| {
        let shifted = |sign: f32| {
            let mut a = act.clone();
            a.values
                .iter_mut()
                .zip(dir)
                .for_each(|(x, d)| *x += sign * eps * d);
            gradcam::class_score(&io, &layer, &a, found.class_id, false)
                .unwrap()
                .0
        };
        (shifted(1.0) - shifted(-1.0)) / (2.0 * eps)
    };
    let unit: Vec<f32> = g.iter().map(|v| v / norm).collect();
    let fd = slope(&unit, 0.05);
    assert!(
        (fd - norm).abs() < 0.1 * norm,
        "slope along the gradient {fd} != |g| {norm}"
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    for _ in 0..2 {
        // A random direction tilted towards the gradient so its slope is well above noise.
        let r: Vec<f32> = unit
            .iter()
            .map(|u| 0.5 * u + rng.random_range(-1.0f32..1.0) / (g.len() as f32).sqrt())
            .collect();
        let rn = r.iter().map(|v| v * v).sum::<f32>().sqrt();
        let r: Vec<f32> = r.iter().map(|v| v / rn).collect();
        let want: f32 = g.iter().zip(&r).map(|(a, b)| a * b).sum();
        let fd = slope(&r, 0.05);
        assert!(
            (fd - want).abs() < 0.1 * want.abs() + 1e-3,
            "slope along a random direction {fd} != g·r {want}"
        );
    }
}

#[test]
fn eval_config_runs_barrel_and_container_with_the_stop_sign_target_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    for (object, sets, groups) in [("barrel", "fv,rv", 4), ("container", "fv", 2)] {
        let cfg = dir.path().join(format!("{object}.toml"));
        std::fs::write(
            &cfg,
            format!(
                "[object]\nmesh = \"{object}\"\n[render]\nwidth = 128\nheight = 128\nsamples = 1\n\
                 atlas_res = 64\n[environment]\ndistance_ratio = [1.5, 3.0]\n"
            ),
        )
        .unwrap();
        let out = dir.path().join(object);
        let args = [
            "eval",
            "--config",
            cfg.to_str().unwrap(),
            "--views",
            "1",
            "--sets",
            sets,
            "--texture",
            "original,random",
            "--models",
            "nanodet",
            "--true-classes",
            "none",
            "--target",
            "stop sign",
            "--out",
            out.to_str().unwrap(),
        ];
        support::cac_ok(&args);
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
        assert_eq!(json["info"]["object"], object);
        assert_eq!(json["info"]["protocol"]["target"], 11, "stop sign");
        let records = json["records"].as_array().unwrap();
        let skipped: u64 = json["info"]["skipped"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .sum();
        assert_eq!(records.len() as u64 + skipped, 2 * groups, "{object}");
        // Paired views: both textures are seen from the same viewpoints.
        let view = |t: &str| -> Vec<String> {
            records
                .iter()
                .filter(|r| r["texture"] == t)
                .map(|r| {
                    format!(
                        "{}/{}/{}",
                        r["azimuth_deg"], r["elevation_deg"], r["distance_ratio"]
                    )
                })
                .collect()
        };
        assert_eq!(view("Original"), view("Random"));
        // No true class: nothing is a hit, so P@0.5 is 0 everywhere.
        assert!(records.iter().all(|r| r["hit"] == false));
        let md = std::fs::read_to_string(out.join("report.md")).unwrap();
        assert!(
            md.contains("stop sign") && md.contains("Targeted success, FV"),
            "{md}"
        );
        let csv = std::fs::read_to_string(out.join("p05_fv.csv")).unwrap();
        assert!(
            csv.starts_with("Texture,nanodet L_b,nanodet L_d,nanodet Avg (Drop)\n"),
            "{csv}"
        );
        let html = std::fs::read_to_string(out.join("report.html")).unwrap();
        assert!(html.contains("data:image/png;base64,") && !html.contains("src=\"http"));
        // Rerun: both textures come from the cache, with the same records.
        let text = support::cac_ok(&args);
        assert!(
            text.contains("reused from") && text.contains("Original, Random"),
            "{text}"
        );
        let again: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
        assert_eq!(again["records"], json["records"]);
    }
    // Bad input names what is wrong.
    let out = support::cac(&["eval", "--target", "tank", "--views", "1"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("\"tank\""));
}

/// `cac study methods`: one run per method (and per hide class set), then one evaluation; the
/// table's figures are the evaluation's own records, and a rerun reuses the finished runs.
#[test]
fn study_methods_trains_each_method_and_tables_the_protocols_records() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("small.toml");
    std::fs::write(
        &cfg,
        "[object]\nmesh = \"pickup\"\n[render]\nwidth = 128\nheight = 128\nsamples = 1\n\
         atlas_res = 64\n[environment]\ndistance_ratio = [1.5, 3.0]\n",
    )
    .unwrap();
    let out = dir.path().join("methods");
    let args = [
        "study",
        "methods",
        "--config",
        cfg.to_str().unwrap(),
        "--methods",
        "cac,camou",
        "--hide",
        "car+bus+truck",
        "--textures",
        "original",
        "--iterations",
        "2",
        "--batch",
        "1",
        "--views",
        "2",
        "--sets",
        "fv",
        "--eval-models",
        "nanodet",
        "--out",
        out.to_str().unwrap(),
    ];
    support::cac_ok(&args);
    let run: serde_json::Value = serde_json::from_slice(
        &std::fs::read(out.join("cac-hide-car+bus+truck/run.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(run["finished"], true);
    assert_eq!(run["attack"]["hide"], true);
    assert_eq!(run["attack"]["hide_classes"], "car,bus,truck");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("eval/results.json")).unwrap()).unwrap();
    let records = json["records"].as_array().unwrap();
    let csv = std::fs::read_to_string(out.join("methods.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next().unwrap(),
        "texture,train (s),nanodet (white-box) P@0.5 FV,nanodet (white-box) target FV"
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let names: Vec<&str> = rows.iter().map(|r| r[0]).collect();
    assert_eq!(
        names,
        ["Original", "CAC", "CAMOU", "CAC hide (car+bus+truck)"]
    );
    for r in &rows {
        let of = |key: &str| {
            let mine: Vec<_> = records.iter().filter(|x| x["texture"] == r[0]).collect();
            assert!(!mine.is_empty(), "{}", r[0]);
            mine.iter().filter(|x| x[key] == true).count() as f64 / mine.len() as f64
        };
        assert_eq!(r[2], format!("{:.3}", of("hit")), "{csv}");
        assert_eq!(r[3], format!("{:.3}", of("targeted")), "{csv}");
        // Trained rows carry their logged training time; the original none.
        assert_eq!(r[1] == "—", r[0] == "Original", "{csv}");
    }
    let text = support::cac_ok(&args);
    assert!(text.contains("CAMOU: reusing the finished run"), "{text}");
    assert_eq!(
        std::fs::read_to_string(out.join("methods.csv")).unwrap(),
        csv
    );
    // A hide class the source model lacks is refused before anything is trained.
    let bad = support::cac(&[
        "study",
        "methods",
        "--config",
        cfg.to_str().unwrap(),
        "--methods",
        "cac",
        "--hide",
        "tank",
        "--out",
        dir.path().join("bad").to_str().unwrap(),
    ]);
    assert!(!bad.status.success());
    let e = String::from_utf8_lossy(&bad.stderr);
    assert!(e.contains("has no class \"tank\""), "{e}");
    assert!(!dir.path().join("bad").exists());
}

/// The HDRI protocol (`cac eval --hdri`): every view lit by the given environment, the report
/// says so, the figures are not those of the sun-and-ambient protocol on the same views, and an
/// unknown environment is refused naming the choices.
#[test]
fn eval_hdri_protocol_lights_every_view_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (64usize, 32usize);
    let px: Vec<image::Rgb<f32>> = (0..w * h)
        .map(|i| {
            let t = (i / w) as f32 / h as f32;
            image::Rgb(if t < 0.5 {
                [0.9, 0.6, 0.3]
            } else {
                [0.05, 0.04, 0.03]
            })
        })
        .collect();
    let map = dir.path().join("amber.hdr");
    let f = std::io::BufWriter::new(std::fs::File::create(&map).unwrap());
    image::codecs::hdr::HdrEncoder::new(f)
        .encode(&px, w, h)
        .unwrap();
    let cfg = dir.path().join("small.toml");
    std::fs::write(
        &cfg,
        "[render]\nwidth = 128\nheight = 128\nsamples = 1\natlas_res = 64\n",
    )
    .unwrap();
    let run = |hdri: Option<&str>, out: &str| -> serde_json::Value {
        let out = dir.path().join(out);
        let mut args = vec![
            "eval",
            "--config",
            cfg.to_str().unwrap(),
            "--views",
            "2",
            "--sets",
            "fv",
            "--texture",
            "original",
            "--models",
            "nanodet",
            "--out",
            out.to_str().unwrap(),
        ];
        if let Some(h) = hdri {
            args.extend(["--hdri", h]);
        }
        support::cac_ok(&args);
        let md = std::fs::read_to_string(out.join("report.md")).unwrap();
        assert_eq!(
            md.contains("lit by the HDR environments"),
            hdri.is_some(),
            "{md}"
        );
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap()
    };
    let (plain, lit) = (run(None, "plain"), run(Some(map.to_str().unwrap()), "lit"));
    assert!(lit["info"]["light"].as_str().unwrap().contains("amber.hdr"));
    let confs = |j: &serde_json::Value| -> Vec<String> {
        j["records"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r.to_string())
            .collect()
    };
    assert_ne!(
        confs(&plain),
        confs(&lit),
        "the environment changed nothing"
    );
    let o = support::cac(&[
        "eval",
        "--hdri",
        "moonbase",
        "--views",
        "1",
        "--out",
        dir.path().join("x").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("moonbase") && err.contains("interior"),
        "{err}"
    );
}

/// `cac demo` without `--iterations` fits its training to `--budget`: a budget the scoring
/// alone spends leaves the training its floor (10 s), whose fitted iterations run.json and
/// summary.json record alike; the same command again resumes that run to those iterations
/// instead of fitting a new one.
#[test]
fn a_budgeted_demo_records_its_fitted_iterations_and_resumes_them() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let args = [
        "demo",
        "--budget",
        "1s",
        "--views",
        "1",
        "--out",
        out.to_str().unwrap(),
    ];
    let text = support::cac_ok(&args);
    let json = |p: &str| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(out.join(p)).unwrap()).unwrap()
    };
    let (summary, run) = (json("summary.json"), json("run/run.json"));
    assert_eq!(summary["training_budget_seconds"].as_f64(), Some(10.0));
    let fitted = run["attack"]["iterations"].as_u64().unwrap();
    assert!(
        fitted > 2,
        "10 s of training fits more than 2 iterations: {fitted}"
    );
    assert_eq!(summary["attack"]["iterations"].as_u64(), Some(fitted));
    let reached = summary["iterations"].as_u64().unwrap();
    assert!(reached <= fitted && reached > 0, "{reached} of {fitted}");
    assert_eq!(
        summary["attack"]["target_loss"], "logit",
        "the demo's default"
    );
    assert!(
        text.contains(&format!("trained {reached} iterations")),
        "{text}"
    );
    let again = support::cac_ok(&args);
    assert!(again.contains("resuming the demo's run"), "{again}");
    assert_eq!(
        json("run/run.json")["attack"]["iterations"],
        run["attack"]["iterations"]
    );
    // Resumed to its fitted iterations (a run the budget stopped short goes on to them), its
    // training time the run's clock (not this session's, which trained nothing more).
    assert_eq!(json("summary.json")["iterations"].as_u64(), Some(fitted));
    let seconds = |v: &serde_json::Value| v["training_seconds"].as_f64().unwrap();
    assert!(seconds(&summary) > 0.0, "{summary}");
    assert!(seconds(&json("summary.json")) >= seconds(&summary));
    assert!(
        json("summary.json")["training_budget_seconds"].is_null(),
        "not fitted again"
    );
}
