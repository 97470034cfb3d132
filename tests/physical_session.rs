//! Capture sessions end to end: the real serial driver against the simulated firmware on a
//! pseudo-terminal, the digital-twin camera, the manifest, resume after a kill, scoring. Every
//! (ratio, angle, repeat) must be captured exactly once, with exactly one completed move per
//! frame in the simulated device's log, under each fault kind and their mix.
#![cfg(unix)]

mod support;

use cac::physical::calib::CameraModel;
use cac::physical::manifest::{self, Entry};
use cac::physical::rig::{Rig, RigConfig};
use cac::physical::session::{self, CaptureOptions, SessionInfo, SessionPlan};
use cac::physical::truth::ground_truth_box;
use cac::physical::twin::{DigitalTwin, Pose};
use cac::sim::rig::{faults_by_name, SimRig};
use cac::sim::{FaultConfig, FaultCounts, MotionKind};
use firmware_protocol::{Axis, DoneEnd};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

const SPEEDUP: f64 = 40.0;

fn calib(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("calib")
        .join(name)
}

/// A small rig file in `dir` (96x72 frames of the repository's calibrated lens).
fn rig_file(dir: &Path, rail: bool, size: [usize; 2], axis: [f64; 2]) -> PathBuf {
    let p = dir.join("rig.toml");
    let text = format!(
        r#"ratios = [1.5, 3.0]
[camera]
intrinsics = "{}"
resolution = [{}, {}]
height_m = 0.10
elevation_deg = 5.0
[turntable]
axis_m = [{}, {}]
settle_ms = 200
speed_deg_s = 180.0
[rail]
present = {rail}
near_m = 0.25
length_m = 1.0
[object]
mesh = "pickup"
length_m = 0.22
"#,
        calib("camera_opencv.yaml").display(),
        size[0],
        size[1],
        axis[0],
        axis[1]
    );
    std::fs::write(&p, text).unwrap();
    p
}

fn plan() -> SessionPlan {
    SessionPlan::new(
        vec![1.5, 3.0],
        SessionPlan::parse_angles("0:360:90").unwrap(),
        2,
    )
    .unwrap()
}

#[test]
fn opencv_and_ros_intrinsics_load_to_the_same_numbers() {
    let a = CameraModel::load(&calib("camera_opencv.yaml")).unwrap();
    let b = CameraModel::load(&calib("camera_ros.yaml")).unwrap();
    assert_eq!((a.width, a.height), (640, 480));
    for (x, y) in [
        (a.fx, b.fx),
        (a.fy, b.fy),
        (a.cx, b.cx),
        (a.cy, b.cy),
        (a.dist[0], b.dist[0]),
        (a.dist[1], b.dist[1]),
        (a.dist[2], b.dist[2]),
        (a.dist[3], b.dist[3]),
        (a.dist[4], b.dist[4]),
    ] {
        assert!((x - y).abs() < 1e-9, "{a:?} vs {b:?}");
    }
    // OpenCV's pixel centres are integers, cac's half-integers.
    assert!((a.cx - 319.41).abs() < 1e-9 && (a.dist[0] + 0.27134).abs() < 1e-12);
    // The example rig loads, and a broken one names the file and the field.
    let (cfg, lens) = RigConfig::load(&calib("rig.toml")).unwrap();
    assert_eq!(lens, a);
    assert!(!cfg.rail.present);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.toml");
    let text = std::fs::read_to_string(calib("rig.toml")).unwrap();
    std::fs::write(&p, text.replace("length_m = 0.22", "")).unwrap();
    let e = format!("{:#}", RigConfig::load(&p).unwrap_err());
    assert!(
        e.contains("bad.toml") && e.contains("object.length_m"),
        "{e}"
    );
    std::fs::write(&p, text.replace("camera_opencv.yaml", "missing.yaml")).unwrap();
    let e = format!("{:#}", RigConfig::load(&p).unwrap_err());
    assert!(
        e.contains("missing.yaml") && e.contains("camera.intrinsics"),
        "{e}"
    );
}

#[test]
fn twin_mask_box_matches_the_projected_box_with_distortion() {
    let dir = tempfile::tempdir().unwrap();
    let rig = Arc::new(Rig::load(&rig_file(dir.path(), true, [160, 120], [0.02, -0.01])).unwrap());
    let atlas = rig.renderer.scene.initial_atlas(64);
    let twin = DigitalTwin::new(rig.clone(), &atlas, Box::new(|| Err("unused".into())), 1);
    let pinhole = rig.clone_without_distortion();
    let mut worst: f32 = 0.0;
    let mut distortion_moves: f32 = 0.0;
    for ratio in [1.2, 1.5, 3.0] {
        let d = rig.horizontal_distance(ratio).unwrap();
        for angle in [0.0, 35.0, 90.0, 160.0, 250.0] {
            let f = twin
                .render(
                    Pose {
                        angle_deg: angle,
                        horizontal_m: d,
                    },
                    0,
                )
                .unwrap();
            let mask = f.mask_box.expect("object in view");
            let gt = ground_truth_box(&rig, angle, d).unwrap().unwrap();
            for i in 0..4 {
                worst = worst.max((mask[i] - gt[i]).abs());
            }
            let pin = ground_truth_box(&pinhole, angle, d).unwrap().unwrap();
            for i in 0..4 {
                distortion_moves = distortion_moves.max((pin[i] - gt[i]).abs());
            }
        }
    }
    println!("twin mask vs projected box: worst {worst:.2} px; distortion moves the box by up to {distortion_moves:.1} px");
    assert!(
        worst <= 1.5,
        "mask box differs from the projection by {worst} px"
    );
    assert!(
        distortion_moves > 4.0,
        "the test views must exercise the distortion"
    );
    // Same seed and frame: the same image; another frame: other noise.
    let pose = Pose {
        angle_deg: 30.0,
        horizontal_m: rig.horizontal_distance(2.0).unwrap(),
    };
    let a = twin.render(pose, 5).unwrap().image;
    assert_eq!(a, twin.render(pose, 5).unwrap().image);
    assert_ne!(a, twin.render(pose, 6).unwrap().image);
}

/// Helper trait: a copy of the rig with a distortion-free lens.
trait NoDistortion {
    fn clone_without_distortion(&self) -> Rig;
}

impl NoDistortion for Rig {
    fn clone_without_distortion(&self) -> Rig {
        let mut lens = self.lens.clone();
        lens.dist = [0.0; 5];
        Rig::new(self.config.clone(), lens).unwrap()
    }
}

struct Outcome {
    entries: Vec<Entry>,
    faults: FaultCounts,
    boots: u32,
    dir: tempfile::TempDir,
}

/// Runs a whole session in-process against the simulated rig and checks it exactly-once.
fn run_session(name: &str, faults: FaultConfig, rail: bool) -> Outcome {
    let seed = faults.seed;
    let dir = tempfile::tempdir().unwrap();
    let rig = Arc::new(Rig::load(&rig_file(dir.path(), rail, [96, 72], [0.0, 0.0])).unwrap());
    let sim = SimRig::spawn(&rig, faults, SPEEDUP).unwrap();
    let mut stage = sim.stage(&rig).unwrap_or_else(|e| panic!("[{name}] {e:#}"));
    let atlas = rig.renderer.scene.initial_atlas(64);
    let mut cam = DigitalTwin::new(rig.clone(), &atlas, sim.pose_source(), seed);
    let out = dir.path().join("session");
    let info = SessionInfo {
        plan: plan(),
        rig: rig.config.clone(),
        lens: rig.lens.clone(),
        texture: None,
        camera: "twin".into(),
        camera_settings: None,
        simulated: true,
    }
    .prepare(&out, false)
    .unwrap();
    let sim = Arc::new(sim);
    let s2 = sim.clone();
    let opts = CaptureOptions {
        settle: Box::new(move || s2.settle(Duration::from_millis(200))),
        progress: false,
    };
    let sum = session::capture(&out, &info, &rig, &mut stage, &mut cam, &opts)
        .unwrap_or_else(|e| panic!("[{name}] capture failed: {e:#}"));
    assert_eq!(sum.captured, 16);
    let entries = manifest::read(&out.join("manifest.jsonl")).unwrap();
    check_exactly_once(name, &entries, &plan(), &out);
    // The twin saw the table at the planned angle and the camera at the planned distance.
    for e in &entries {
        let v: Vec<f64> = e
            .camera
            .split(['=', ' '])
            .filter_map(|t| t.parse().ok())
            .collect();
        assert!((v[0] - e.angle).abs() < 1e-6, "[{name}] {e:?}");
        assert!(
            (v[1] - rig.horizontal_distance(e.ratio).unwrap()).abs() < 1e-4,
            "[{name}] {e:?}"
        );
    }
    // The device log: every frame's move ran exactly once and reached its angle; any other
    // completed turntable move was wiped out by a later reset and commanded again.
    let w = sim.world().lock();
    let dev = w.device();
    assert_eq!(dev.max_starts_per_seq(), 1, "[{name}] a command ran twice");
    let moves: Vec<_> = dev
        .log()
        .iter()
        .filter(|r| r.kind == MotionKind::Move && r.axis == Axis::Turntable)
        .collect();
    let seqs: Vec<u64> = entries
        .iter()
        .map(|e| e.device["move_seq"].as_u64().expect("move_seq"))
        .collect();
    for (e, s) in entries.iter().zip(&seqs) {
        let recs: Vec<_> = moves.iter().filter(|r| u64::from(r.seq) == *s).collect();
        assert_eq!(
            recs.len(),
            1,
            "[{name}] frame {} has {} moves",
            e.frame,
            recs.len()
        );
        let target = (e.angle * 1000.0).round() as i32;
        assert_eq!(recs[0].target, target, "[{name}] {}", e.frame);
        assert_eq!(
            recs[0].end,
            Some((DoneEnd::Reached, target)),
            "[{name}] {}",
            e.frame
        );
    }
    let mut distinct = seqs.clone();
    distinct.sort();
    distinct.dedup();
    assert_eq!(
        distinct.len(),
        seqs.len(),
        "[{name}] two frames share one move"
    );
    let boots = dev.boots();
    for r in &moves {
        if !seqs.contains(&u64::from(r.seq)) {
            assert!(
                r.boot < boots
                    && (r.end.is_none() || r.end.is_some_and(|e| e.0 == DoneEnd::Reached)),
                "[{name}] move {r:?} is neither a frame's nor undone by a reset"
            );
        }
    }
    let extra = moves.len() - seqs.len();
    assert!(
        extra <= 2 * (boots as usize - 1),
        "[{name}] {extra} extra moves for {boots} boots"
    );
    let faults = w.fault_counts();
    println!(
        "[{name}] 16 frames exactly once; injected {faults}; device boots {boots}; {extra} moves redone after resets; driver {:?}",
        stage.turntable().stats()
    );
    drop(w);
    Outcome {
        entries,
        faults,
        boots,
        dir,
    }
}

/// Each planned frame exactly once in the manifest, its file present and decodable.
fn check_exactly_once(name: &str, entries: &[Entry], plan: &SessionPlan, dir: &Path) {
    let mut seen: HashMap<(String, usize), usize> = HashMap::new();
    for e in entries {
        *seen.entry(e.key()).or_default() += 1;
        let img = image::open(dir.join(&e.frame)).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (96, 72));
    }
    let frames = plan.frames();
    assert_eq!(
        entries.len(),
        frames.len(),
        "[{name}] manifest has {} lines",
        entries.len()
    );
    for f in &frames {
        let k = (manifest::key_of(f.ratio, f.angle), f.repeat);
        assert_eq!(
            seen.get(&k),
            Some(&1),
            "[{name}] frame {} captured {:?} times",
            f.file,
            seen.get(&k)
        );
    }
}

#[test]
fn session_clean_without_rail_operator_moves_camera() {
    let o = run_session("clean, no rail", faults_by_name("none", 30).unwrap(), false);
    assert_eq!(o.faults.total(), 0);
    assert_eq!(o.boots, 1);
    assert!(
        o.entries.iter().all(|e| e.device["rail_um"].is_null()),
        "no rail moved"
    );
}

#[test]
fn session_dropped_bytes() {
    let o = run_session("drops", faults_by_name("drops", 31).unwrap(), true);
    assert!(o.faults.dropped > 0, "{}", o.faults);
}

#[test]
fn session_garbled_bytes() {
    let o = run_session("garbles", faults_by_name("garbles", 32).unwrap(), true);
    assert!(o.faults.garbled > 0, "{}", o.faults);
}

#[test]
fn session_delays() {
    let o = run_session("delays", faults_by_name("delays", 33).unwrap(), true);
    assert!(o.faults.delayed > 0, "{}", o.faults);
}

#[test]
fn session_resets_mid_move() {
    let o = run_session("resets", faults_by_name("resets", 34).unwrap(), true);
    assert!(o.faults.resets > 0 && o.boots > 1, "{}", o.faults);
}

#[test]
fn session_disconnects() {
    // More often than the CLI's rate, so that a short session sees several.
    let f = FaultConfig::disconnects(35, 0.15, Duration::from_millis(1500));
    let o = run_session("disconnects", f, true);
    assert!(o.faults.disconnects >= 2, "{}", o.faults);
}

#[test]
fn session_mix_then_scored() {
    let o = run_session("mix", faults_by_name("mix", 36).unwrap(), true);
    assert!(o.faults.total() > 0, "{}", o.faults);
    let dir = o.dir.path().join("session");
    let device = burn::tensor::Device::from(burn::backend::FlexDevice);
    let models = cac::detect::fetch::ensure_models().expect("detector models");
    let det = cac::detect::load("nanodet", &models, &device).unwrap();
    let p = cac::eval::Protocol::default();
    let s = cac::physical::score::score(&dir, &[det.as_ref()], &p, &device, false).unwrap();
    assert_eq!(s.frames.len(), 16);
    let rig = Rig::load(&dir.parent().unwrap().join("rig.toml")).unwrap();
    for f in &s.frames {
        let gt =
            ground_truth_box(&rig, f.angle, rig.horizontal_distance(f.ratio).unwrap()).unwrap();
        assert_eq!(f.gt, gt, "{}", f.frame);
        assert_eq!(f.hit.len(), 1);
    }
    // Two ratios, two repeats each; the mean over repeats is over the angles' hits.
    assert_eq!(s.by_ratio.len(), 2);
    for r in &s.by_ratio {
        assert_eq!(r.per_repeat.len(), 2);
        let hits = s
            .frames
            .iter()
            .filter(|f| f.ratio == r.ratio && f.hit[0])
            .count();
        assert!((r.mean - hits as f64 / 8.0).abs() < 1e-12, "{r:?}");
    }
    assert_eq!(s.by_angle.len(), 4);
    let out = dir.join("score");
    cac::physical::score::write(&out, &s, "test").unwrap();
    support::score_report::check(&out, &s, &o.entries, "test");
    println!(
        "[mix] scored: {:?}",
        s.by_ratio
            .iter()
            .map(|r| (r.ratio, r.mean, r.std))
            .collect::<Vec<_>>()
    );
}

#[test]
fn killed_capture_resumes_each_missing_frame_once() {
    let dir = tempfile::tempdir().unwrap();
    let rig = rig_file(dir.path(), true, [96, 72], [0.0, 0.0]);
    let out = dir.path().join("session");
    let args_n = |resume: bool, repeats: &str| {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_cac"));
        c.args(["capture", "--rig"]).arg(&rig).args([
            "--ratios",
            "1.5,3",
            "--angles",
            "0:360:90",
            "--repeats",
            repeats,
            "--simulate",
            "--faults",
            "mix",
            "--seed",
            "7",
            "--out",
        ]);
        c.arg(&out);
        if resume {
            c.arg("--resume");
        }
        c.stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped());
        c
    };
    let args = |resume: bool| args_n(resume, "2");
    let mut child = args(false).spawn().unwrap();
    let m = out.join("manifest.jsonl");
    let lines = |p: &Path| {
        std::fs::read_to_string(p)
            .map(|t| t.lines().count())
            .unwrap_or(0)
    };
    let t0 = std::time::Instant::now();
    while lines(&m) < 5 && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let before = manifest::read(&m).unwrap();
    assert!(
        (5..16).contains(&before.len()),
        "killed after {} frames",
        before.len()
    );
    // A write torn by the kill: half a line at the end.
    let mut f = std::fs::OpenOptions::new().append(true).open(&m).unwrap();
    std::io::Write::write_all(&mut f, b"{\"frame\":\"frames/r3.00_a090").unwrap();
    drop(f);
    // A different plan is refused.
    let o = args_n(true, "3").output().unwrap();
    assert!(
        !o.status.success() && String::from_utf8_lossy(&o.stderr).contains("plan differs"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // So is a changed rig file.
    let text = std::fs::read_to_string(&rig).unwrap();
    std::fs::write(&rig, text.replace("settle_ms = 200", "settle_ms = 300")).unwrap();
    let o = args(true).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("rig file"));
    std::fs::write(&rig, text).unwrap();
    let o = args(true).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(stdout.contains("partial last line"), "{stdout}");
    assert!(
        stdout.contains(&format!(
            "captured {} frames ({} were already",
            16 - before.len(),
            before.len()
        )),
        "{stdout}"
    );
    let after = manifest::read(&m).unwrap();
    check_exactly_once("kill+resume", &after, &plan(), &out);
    assert_eq!(
        &after[..before.len()],
        &before[..],
        "earlier frames kept as they were"
    );
    // A new session into the same folder is refused.
    let o = args(false).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--resume"));
    println!(
        "[kill+resume] killed after {} frames, resumed {} more",
        before.len(),
        16 - before.len()
    );
}

/// A 64×32 equirectangular room written as Radiance HDR: a warm half and a cool half of the
/// walls (by azimuth), a grey floor below the horizon, no sun.
fn write_room(dir: &Path) -> PathBuf {
    let (w, h) = (64usize, 32usize);
    let px: Vec<image::Rgb<f32>> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            image::Rgb(match (y < h / 2, x < w / 2) {
                (true, true) => [1.6, 0.7, 0.3],
                (true, false) => [0.3, 0.6, 1.5],
                (false, _) => [0.4, 0.4, 0.4],
            })
        })
        .collect();
    let p = dir.join("room.hdr");
    let f = std::io::BufWriter::new(std::fs::File::create(&p).unwrap());
    image::codecs::hdr::HdrEncoder::new(f)
        .encode(&px, w, h)
        .unwrap();
    p
}

/// `rig.toml` in `dir` with a `[twin]` table lit by `room` (noise and blur off, so frames
/// compare exactly), turned by `turn` degrees; `room: None` keeps the lamp and ambient.
fn rig_in_room(dir: &Path, room: Option<&str>, turn: f32) -> PathBuf {
    let p = rig_file(dir, false, [96, 72], [0.0, 0.0]);
    let mut text = std::fs::read_to_string(&p).unwrap();
    text.push_str("[twin]\nread_noise = 0.0\nshot_noise = 0.0\nblur_px = 0.0\n");
    if let Some(room) = room {
        text.push_str(&format!("hdri = {room:?}\nhdri_rotation_deg = {turn}\n"));
    }
    std::fs::write(&p, text).unwrap();
    p
}

/// `[twin] hdri`: the room lights the object and is seen behind it, fixed in the rig frame. The
/// pixels above the object are the same at every table angle (the object turns, the room does
/// not), change when the room is turned, and are not the lamp-lit twin's backdrop; a room that
/// is not there is refused naming the rig file and the key.
#[test]
fn the_twin_lit_by_a_room_turns_the_object_not_the_room() {
    let dir = tempfile::tempdir().unwrap();
    let room = write_room(dir.path());
    let room = room.to_str().unwrap();
    let frame = |rig: &Path, angle: f64| {
        let rig = Arc::new(Rig::load(rig).unwrap());
        let atlas = rig.renderer.scene.initial_atlas(64);
        let twin = DigitalTwin::new(rig.clone(), &atlas, Box::new(|| Err("unused".into())), 1);
        let pose = Pose {
            angle_deg: angle,
            horizontal_m: rig.horizontal_distance(1.5).unwrap(),
        };
        twin.render(pose, 0).unwrap()
    };
    let sub = tempfile::tempdir().unwrap();
    let lit = rig_in_room(sub.path(), Some(room), 0.0);
    let (a, b) = (frame(&lit, 0.0), frame(&lit, 70.0));
    // Rows above both objects' boxes see only the room.
    let top = a.mask_box.unwrap()[1].min(b.mask_box.unwrap()[1]).floor() as u32;
    assert!(
        top >= 4,
        "the test view needs backdrop rows above the object (top {top})"
    );
    let rows = |f: &cac::physical::twin::TwinFrame| -> Vec<u8> {
        (0..top * 96)
            .flat_map(|i| f.image.get_pixel(i % 96, i / 96).0)
            .collect()
    };
    let diff = |x: &[u8], y: &[u8]| {
        x.iter()
            .zip(y)
            .map(|(p, q)| p.abs_diff(*q) as f64)
            .sum::<f64>()
            / x.len() as f64
    };
    assert_eq!(rows(&a), rows(&b), "the room moved with the table");
    assert_ne!(a.image, b.image, "the object turned");
    let turned = rig_in_room(sub.path(), Some(room), 180.0);
    let c = frame(&turned, 0.0);
    let moved = diff(&rows(&a), &rows(&c));
    assert!(
        moved > 20.0,
        "turning the room by 180 deg changed the backdrop by {moved} levels"
    );
    let lamp = rig_in_room(sub.path(), None, 0.0);
    let d = frame(&lamp, 0.0);
    assert!(
        diff(&rows(&a), &rows(&d)) > 20.0,
        "the room is not the lamp-lit backdrop"
    );
    // A warm room warms the object: its mean red over blue rises against the cool turn.
    let object_rb = |f: &cac::physical::twin::TwinFrame| {
        let [x1, y1, x2, y2] = f.mask_box.unwrap().map(|v| v as u32);
        let (mut r, mut b) = (0.0, 0.0);
        for y in y1..y2.min(72) {
            for x in x1..x2.min(96) {
                let p = f.image.get_pixel(x, y).0;
                (r, b) = (r + p[0] as f64, b + p[2] as f64);
            }
        }
        r / b.max(1.0)
    };
    // The halves split the room along the camera's axis at turns 0 and 180; at 90 and 270 the
    // side the camera sees faces the warm half, then the cool one.
    let warm = object_rb(&frame(&rig_in_room(sub.path(), Some(room), 90.0), 0.0));
    let cool = object_rb(&frame(&rig_in_room(sub.path(), Some(room), 270.0), 0.0));
    eprintln!(
        "room: backdrop moved {moved:.1} levels by a 180-deg turn; object red/blue {warm:.3} \
         facing the warm half, {cool:.3} facing the cool half"
    );
    assert!(
        warm > cool * 1.05,
        "the room's colour reaches the object: {warm} vs {cool}"
    );
    let bad = rig_in_room(sub.path(), Some("nowhere-room"), 0.0);
    let e = format!("{:#}", Rig::load(&bad).err().expect("refused"));
    assert!(
        e.contains("rig.toml") && e.contains("twin.hdri") && e.contains("nowhere-room"),
        "{e}"
    );
}

/// `[twin.ibl]`: the rig file sets how finely the room's light is evaluated, as a training
/// config's `[environment.ibl]` does (the reflection chain is carried and checked; its shading
/// is `render::ibl`'s unit test). Order 0 and no occlusion rays each shade the object
/// otherwise than the defaults (order 2, 4 rays) and leave the room seen above it as it was; an order above 2
/// or an unknown key is refused naming the rig file.
#[test]
fn the_twin_takes_its_room_light_knobs_from_the_rig_file() {
    let dir = tempfile::tempdir().unwrap();
    let room = write_room(dir.path());
    let room = room.to_str().unwrap();
    let rig_with = |sub: &Path, knobs: &str| {
        let p = rig_in_room(sub, Some(room), 90.0);
        let mut text = std::fs::read_to_string(&p).unwrap();
        text.push_str(knobs);
        std::fs::write(&p, text).unwrap();
        p
    };
    let frame = |rig: &Path| {
        let rig = Arc::new(Rig::load(rig).unwrap());
        let atlas = rig.renderer.scene.initial_atlas(64);
        let twin = DigitalTwin::new(rig.clone(), &atlas, Box::new(|| Err("unused".into())), 1);
        let pose = Pose {
            angle_deg: 0.0,
            horizontal_m: rig.horizontal_distance(1.5).unwrap(),
        };
        twin.render(pose, 0).unwrap()
    };
    let a = tempfile::tempdir().unwrap();
    let fine = frame(&rig_with(a.path(), ""));
    let top = fine.mask_box.unwrap()[1].floor() as u32;
    assert!(
        top >= 4,
        "the test view needs backdrop rows above the object"
    );
    let row_px = |f: &cac::physical::twin::TwinFrame, y0: u32, y1: u32| -> Vec<u8> {
        (y0 * 96..y1 * 96)
            .flat_map(|i| f.image.get_pixel(i % 96, i / 96).0)
            .collect()
    };
    let [x1, y1, x2, y2] = fine.mask_box.unwrap().map(|v| v as u32);
    let object = |f: &cac::physical::twin::TwinFrame| -> Vec<u8> {
        (y1..y2.min(72))
            .flat_map(|y| (x1..x2.min(96)).map(move |x| (x, y)))
            .flat_map(|(x, y)| f.image.get_pixel(x, y).0)
            .collect()
    };
    // Each knob on its own against the defaults (order 2, 4 rays).
    for knob in ["sh_order = 0", "occlusion_rays = 0"] {
        let b = tempfile::tempdir().unwrap();
        let coarse = frame(&rig_with(b.path(), &format!("[twin.ibl]\n{knob}\n")));
        // The upper half of the rows above the object sees only the room; the table top further
        // down is lit by the room too, so the knobs shade it as they shade the object.
        assert_eq!(
            row_px(&fine, 0, top / 2),
            row_px(&coarse, 0, top / 2),
            "{knob} changed the room behind the object"
        );
        let changed = object(&fine)
            .iter()
            .zip(object(&coarse))
            .filter(|(p, q)| **p != *q)
            .count();
        eprintln!("[twin.ibl] {knob}: {changed} object values differ");
        assert!(
            changed > 30,
            "{knob} shades the object like the defaults ({changed} values differ)"
        );
    }
    // The reflection chain's effect on shading is `render::ibl`'s unit test (on this 64×32 room
    // every part reads the sharpest level anyway); here: the rig carries and checks it.
    let levels = |knobs: &str| {
        let d = tempfile::tempdir().unwrap();
        let rig = Rig::load(&rig_with(d.path(), knobs)).unwrap();
        rig.config.twin.ibl.prefilter_levels
    };
    assert_eq!(levels(""), 1, "the default is one level");
    assert_eq!(levels("[twin.ibl]\nprefilter_levels = 6\n"), 6);
    // Bad knobs are refused naming the rig file and what is wrong.
    for (knobs, says) in [
        (
            "[twin.ibl]\nprefilter_levels = 0\n",
            "twin.ibl: prefilter_levels 0",
        ),
        ("[twin.ibl]\nsh_order = 3\n", "twin.ibl: sh_order 3"),
        ("[twin.ibl]\nrays = 4\n", "unknown field `rays`"),
    ] {
        let d = tempfile::tempdir().unwrap();
        let e = match Rig::load(&rig_with(d.path(), knobs)) {
            Ok(_) => panic!("{knobs:?} accepted"),
            Err(e) => format!("{e:#}"),
        };
        assert!(e.contains("rig.toml") && e.contains(says), "{knobs:?}: {e}");
    }
}
