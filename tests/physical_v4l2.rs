//! The V4L2 capture path against an emulated UVC webcam (tools/fakecam, an `LD_PRELOAD` shim:
//! these machines have no /dev/video): `cac camera` — the default build, through the
//! `linuxvideo` crate — negotiates the lens's size, locks exposure, white balance and focus and
//! records what the camera runs at; the frames arrive as the camera sent them (MJPEG without
//! Huffman tables, YUYV); a refused size, a corrupt frame, a stalled stream, an unplugged
//! camera and a camera that ignores the frame rate asked are each handled and on the record.

mod fakecam_support;
mod support;

use cac::physical::camera_check::CameraReport;
use fakecam_support::{write_bank, BankFrame, Camera, DEV};
use image::{Rgb, RgbImage};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A smooth picture, different for each `k` (what the camera shows at pose `k`).
fn picture(w: u32, h: u32, k: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        Rgb([
            (x * 200 / w + 30 * k) as u8,
            (y * 180 / h + 20) as u8,
            ((x + y) * 90 / (w + h) + 60 * k) as u8,
        ])
    })
}

/// A rig file whose lens is `w`×`h` (the calibration scaled), with extra `[camera]` lines.
fn rig_file(dir: &Path, w: u32, h: u32, camera_extra: &str) -> PathBuf {
    let p = dir.join(format!("rig_{w}x{h}.toml"));
    let calib = support::root().join("calib/camera_opencv.yaml");
    std::fs::write(
        &p,
        format!(
            r#"ratios = [1.5]
[camera]
intrinsics = "{}"
resolution = [{w}, {h}]
height_m = 0.10
elevation_deg = 5.0
{camera_extra}
[turntable]
axis_m = [0.0, 0.0]
settle_ms = 20
[rail]
present = false
[object]
mesh = "pickup"
length_m = 0.22
"#,
            calib.display()
        ),
    )
    .unwrap();
    p
}

struct Fixture {
    dir: tempfile::TempDir,
    shim: PathBuf,
    /// Pose 0 and pose 1 at 96×72, then the same at 160×120.
    bank: Vec<BankFrame>,
}

fn fixture() -> Option<Fixture> {
    let shim = match fakecam_support::shim() {
        Ok(s) => s,
        Err(what) => {
            support::missing(&what, "apt-get install gcc");
            return None;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<_> = [(96, 72), (160, 120)]
        .into_iter()
        .flat_map(|(w, h)| [(0, 0, picture(w, h, 0)), (6400, 0, picture(w, h, 1))])
        .collect();
    let bank = write_bank(&dir.path().join("bank"), 12_800, &frames);
    // The table stands half a revolution (and a few revolutions) on: pose 1.
    std::fs::write(dir.path().join("pose"), "   32000 0\n").unwrap();
    Some(Fixture { dir, shim, bank })
}

impl Fixture {
    fn camera(&self, name: &str, faults: &str, formats: &str) -> Camera {
        Camera {
            bank: self.dir.path().join("bank"),
            pose: Some(self.dir.path().join("pose")),
            faults: faults.into(),
            formats: formats.into(),
            log: self.dir.path().join(format!("{name}.log")),
        }
    }

    /// `cac camera` against `cam`; the output and the folder it wrote.
    fn check(&self, cam: &Camera, rig: &Path, frames: usize, name: &str) -> (Output, PathBuf) {
        let out = self.dir.path().join(name);
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_cac"));
        cmd.args(["camera", "--device", DEV, "--frames", &frames.to_string()])
            .arg("--rig")
            .arg(rig)
            .arg("--out")
            .arg(&out);
        cam.apply(&self.shim, &mut cmd);
        (cmd.output().expect("run cac camera"), out)
    }

    fn report(out: &Path) -> CameraReport {
        serde_json::from_str(&std::fs::read_to_string(out.join("camera.json")).unwrap()).unwrap()
    }
}

fn ok(o: &Output) -> String {
    support::ok_text("camera", o)
}

fn control(r: &CameraReport, name: &str) -> i32 {
    let s = r
        .settings
        .as_ref()
        .expect("a V4L2 camera records its settings");
    let c = s.controls.iter().find(|c| c.name == name).unwrap();
    assert!(c.auto_off, "{name}: the auto mode was switched off");
    c.value
        .unwrap_or_else(|| panic!("{name} offered and locked"))
}

fn frames(out: &Path, r: &CameraReport) -> Vec<RgbImage> {
    r.frames
        .iter()
        .map(|f| image::open(out.join(&f.file)).unwrap().to_rgb8())
        .collect()
}

#[test]
fn a_uvc_camera_is_negotiated_locked_and_its_frames_arrive_as_sent() {
    let Some(fx) = fixture() else { return };
    let dir = fx.dir.path();

    // MJPEG at the lens's size and 15 frames/s; the controls locked where auto settled.
    let cam = fx.camera("mjpeg", "", "");
    let rig = rig_file(dir, 96, 72, "fps = 15.0");
    let (o, out) = fx.check(&cam, &rig, 4, "mjpeg");
    println!("{}", ok(&o));
    let r = Fixture::report(&out);
    let s = r.settings.clone().unwrap();
    assert_eq!(
        (s.driver.as_str(), s.format.as_str(), s.width, s.height),
        ("uvcvideo", "MJPG", 96, 72)
    );
    assert_eq!((s.fps_asked, s.fps_reported), (Some(15.0), Some(15.0)));
    let measured = s.fps_measured.unwrap();
    assert!(
        (11.0..19.0).contains(&measured),
        "measured {measured} frames/s"
    );
    let (exposure, wb) = (control(&r, "exposure"), control(&r, "white_balance_k"));
    assert_eq!(control(&r, "focus"), 0);
    // Auto exposure / white balance wander (250 ± 60, 4600 ± 300); the lock holds where they were.
    assert!(
        (190..=310).contains(&exposure) && (4300..=4900).contains(&wb),
        "{s:?}"
    );
    let log = cam.log_lines();
    let pos = |l: &str| log.iter().rposition(|x| x == l);
    let manual = pos("s_ctrl 0x9a0901 1").expect("exposure switched to manual");
    let held = pos(&format!("s_ctrl 0x9a0902 {exposure}")).expect("exposure held");
    assert!(manual < held, "manual mode first, then the value");
    assert!(
        pos(&format!("s_ctrl 0x98091a {wb}")).is_some(),
        "white balance held"
    );
    // The frames: what the camera sent for the pose the table is at (without Huffman tables).
    let want = fx.bank[1].mjpeg_rgb();
    let sent = std::fs::metadata(&fx.bank[1].jpeg).unwrap().len();
    for (i, f) in frames(&out, &r).iter().enumerate() {
        assert!(
            *f == want,
            "frame {i} is not the camera's picture of pose 1"
        );
    }
    let served: Vec<u64> = log
        .iter()
        .filter(|l| l.starts_with("frame "))
        .map(|l| l.split(' ').nth(7).unwrap().parse().unwrap())
        .collect();
    assert!(
        served.iter().all(|&n| n < sent),
        "frames sent without their Huffman tables"
    );
    assert!(r.frames.iter().all(|f| f.events.is_empty()) && cam.fired().is_empty());

    // YUYV only, neutral exposure and white balance from the rig file: the camera's pixels.
    let cam = fx.camera("yuyv", "", "YUYV");
    let rig = rig_file(
        dir,
        96,
        72,
        "exposure = 250\nwhite_balance_k = 4600\nfocus = 5",
    );
    let (o, out) = fx.check(&cam, &rig, 3, "yuyv");
    ok(&o);
    let r = Fixture::report(&out);
    assert_eq!(r.settings.as_ref().unwrap().format, "YUYV");
    assert_eq!(
        (
            control(&r, "exposure"),
            control(&r, "white_balance_k"),
            control(&r, "focus")
        ),
        (250, 4600, 5)
    );
    let want = fx.bank[1].yuyv_rgb();
    for f in frames(&out, &r) {
        assert!(f == want, "YUYV frame differs from what the camera sent");
    }

    // YUYV locked where auto settled: auto exposure would change every frame; locked, none do.
    let cam = fx.camera("yuyv_auto", "", "YUYV");
    let rig = rig_file(dir, 96, 72, "");
    let (o, out) = fx.check(&cam, &rig, 4, "yuyv_auto");
    ok(&o);
    let r = Fixture::report(&out);
    assert_eq!(r.settings.as_ref().unwrap().fps_asked, None);
    let f = frames(&out, &r);
    assert!(
        f.windows(2).all(|w| w[0] == w[1]),
        "exposure drifted between frames"
    );

    // A size the camera does not offer: refused before any frame, naming what it offers.
    let cam = fx.camera("size", "", "");
    let rig = rig_file(dir, 100, 75, "");
    let (o, out) = fx.check(&cam, &rig, 2, "size");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains(DEV)
            && err.contains("cannot capture 100x75")
            && err.contains("MJPG 96x72, MJPG 160x120, YUYV 96x72, YUYV 160x120"),
        "{err}"
    );
    assert!(!out.join("camera.json").exists());

    // A camera that accepts 15 frames/s and keeps running at 30: the measured rate says so.
    let cam = fx.camera("rate", "ignore-rate", "");
    let rig = rig_file(dir, 160, 120, "fps = 15.0");
    let (o, out) = fx.check(&cam, &rig, 2, "rate");
    ok(&o);
    let s = Fixture::report(&out).settings.unwrap();
    assert_eq!((s.width, s.fps_reported), (160, Some(15.0)));
    let measured = s.fps_measured.unwrap();
    assert!(
        (24.0..36.0).contains(&measured),
        "measured {measured} frames/s"
    );
    let fired = cam.fired();
    assert!(
        !fired.is_empty() && fired.iter().all(|f| f == "ignore-rate"),
        "{fired:?}"
    );
}

#[test]
fn webcam_faults_are_recovered_and_each_is_on_the_frame_it_delayed() {
    let Some(fx) = fixture() else { return };
    let dir = fx.dir.path();
    let rig = rig_file(dir, 96, 72, "fps = 30.0");
    // Frames 0-4 settle the auto modes, 5-7 are discarded after locking: the faults land on
    // frames the check asks for.
    let cam = fx.camera("faults", "corrupt@10,stall@13,unplug@16:400", "");
    let (o, out) = fx.check(&cam, &rig, 8, "faults");
    println!("{}", ok(&o));
    let r = Fixture::report(&out);
    assert_eq!(
        cam.fired(),
        ["corrupt@10", "stall@13", "unplug@16:400"],
        "the camera's own account"
    );
    let events: Vec<&String> = r.frames.iter().flat_map(|f| &f.events).collect();
    let one = |what: &str| {
        let n = events.iter().filter(|e| e.contains(what)).count();
        assert_eq!(n, 1, "{what}: {events:?}");
    };
    one("corrupt frame dropped: cannot decode MJPEG frame: no end-of-image marker");
    one("no frame within 2.0 s: stream restarted");
    one("device lost");
    assert_eq!(events.len(), 3, "{events:?}");
    let want = fx.bank[1].mjpeg_rgb();
    for (i, f) in frames(&out, &r).iter().enumerate() {
        assert!(*f == want, "frame {i} is not the camera's picture");
    }
    // Reopened after the unplug with the session's values, not the camera's defaults.
    let exposure = control(&r, "exposure");
    let log = cam.log_lines();
    let replug = log
        .iter()
        .position(|l| l.starts_with("fault unplug"))
        .unwrap();
    assert!(
        log[replug..]
            .iter()
            .any(|l| *l == format!("s_ctrl 0x9a0902 {exposure}")),
        "exposure locked again after the reconnect"
    );

    // YUYV: the driver's error flag on a frame.
    let cam = fx.camera("flag", "corrupt@11", "YUYV");
    let (o, out) = fx.check(&cam, &rig, 3, "flag");
    ok(&o);
    let r = Fixture::report(&out);
    let events: Vec<&String> = r.frames.iter().flat_map(|f| &f.events).collect();
    assert_eq!(
        events,
        ["corrupt frame dropped: the driver flagged the buffer"]
    );

    // Unplugged for good: a clear error, and the frames taken before it are kept.
    let cam = fx.camera("gone", "unplug@12", "");
    let (o, out) = fx.check(&cam, &rig, 5, "gone");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("did not come back within 10.0 s") && err.contains(DEV),
        "{err}"
    );
    let r = Fixture::report(&out);
    assert!(!r.frames.is_empty() && r.frames.len() < 5, "{r:?}");
    for f in &r.frames {
        assert!(out.join(&f.file).exists());
    }
}
