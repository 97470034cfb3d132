//! Fixtures and comparisons of tests/video.rs: the twin-rendered turntable sequence, its videos
//! (written once per test run under the target's tmp folder), direct scoring of frames, PSNR and
//! the codec tolerances.

use cac::detect::{self, preprocess::image_to_tensor, Detector};
use cac::eval::{score_image, ImageScore, Protocol};
use cac::render::{RenderSettings, Renderer};
use cac::video::encode::{encode_sequence, H264, HEVC, MJPEG};
use cac::video::twin::{render_turntable, TwinCalibration};
use cac::video::{self, GroundTruth, OpenOptions, ScoreOptions, Tools, VideoScores};
use image::RgbImage;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

pub const W: usize = 320;
pub const H: usize = 240;
pub const N: usize = 12;
pub const FPS: f64 = 8.0;

pub use crate::support::device as inference;

pub fn settings() -> RenderSettings {
    RenderSettings {
        width: W,
        height: H,
        samples: 1,
        vfov_deg: 45.0,
        atlas_res: 256,
    }
}

pub fn renderer() -> Renderer {
    let mut s = cac::scene::generate::pickup();
    s.normalise(0.0, None);
    Renderer::new(s, settings()).unwrap()
}

/// Turntable angle and distance ratio of frame `i`: two revolutions in 60° steps, the first at
/// ratio 1.5, the second at 2.
pub fn pose(i: usize) -> (f64, f64) {
    (60.0 * i as f64, if i < N / 2 { 1.5 } else { 2.0 })
}

pub struct Fixture {
    pub dir: PathBuf,
    /// The rendered frames (RGB).
    pub frames: Vec<RgbImage>,
    /// The same frames after a lossless round trip through the videos' pixel formats: 4:2:0
    /// chroma, limited range (H.264, HEVC) and full range (MJPEG).
    pub yuv420: Vec<RgbImage>,
    pub yuvj420: Vec<RgbImage>,
    pub boxes: Vec<[f32; 4]>,
}

impl Fixture {
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
}

pub fn tools() -> Tools {
    let var = |k| std::env::var_os(k).map(std::path::PathBuf::from);
    let t = Tools::locate(var("CAC_FFMPEG"), var("CAC_FFPROBE"));
    t.check()
        .expect("ffmpeg and ffprobe are needed for the video tests (.ci/run installs them)");
    t
}

/// Renders the sequence and writes every fixture once per test run.
pub fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let t = tools();
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("video-fixtures");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("png")).unwrap();
        let r = renderer();
        let env = cac::environment::Environment::new(Default::default()).unwrap();
        let atlas = r.scene.initial_atlas(256);
        let poses: Vec<_> = (0..N).map(pose).collect();
        let out = render_turntable(
            &r,
            &env,
            &atlas,
            &TwinCalibration::default(),
            &poses,
            &inference(),
        )
        .unwrap();
        let mut csv = String::from("frame,x1,y1,x2,y2,segment\n");
        let mut log = String::from("t,angle_deg,ratio\n");
        let (mut frames, mut boxes) = (vec![], vec![]);
        for (i, (img, b)) in out.into_iter().enumerate() {
            let b = b.expect("the object is in view");
            img.save(dir.join(format!("png/f{i:03}.png"))).unwrap();
            let (a, ratio) = pose(i);
            csv += &format!("{i},{},{},{},{},ratio {ratio}\n", b[0], b[1], b[2], b[3]);
            log += &format!("{},{},{ratio}\n", i as f64 / FPS, a % 360.0);
            frames.push(img);
            boxes.push(b);
        }
        std::fs::write(dir.join("gt.csv"), csv).unwrap();
        std::fs::write(dir.join("log.csv"), log).unwrap();
        let pat = dir.join("png/f%03d.png");
        let enc = |codec: &[&str], extra: &[&str], name: &str| {
            encode_sequence(&t, &pat, FPS, codec, extra, &dir.join(name)).unwrap()
        };
        enc(H264, &[], "h264.mp4");
        enc(HEVC, &[], "hevc.mp4");
        enc(MJPEG, &[], "mjpeg.avi");
        // Stored turned a quarter clockwise, as a phone held sideways records; the display matrix
        // says to turn it back a quarter counter-clockwise.
        enc(H264, &["-vf", "transpose=clock"], "stored-cw.mp4");
        let display_rotation = Command::new(&t.ffmpeg)
            .args(["-hide_banner", "-h", "full"])
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).contains("display_rotation"))
            .unwrap_or(false);
        let mut c = Command::new(&t.ffmpeg);
        c.args(["-y", "-v", "error"]);
        if display_rotation {
            c.args(["-display_rotation", "90"]);
        }
        c.arg("-i")
            .arg(dir.join("stored-cw.mp4"))
            .args(["-c", "copy"]);
        if !display_rotation {
            c.args(["-metadata:s:v:0", "rotate=90"]);
        }
        assert!(c.arg(dir.join("rotated.mp4")).status().unwrap().success());
        // Variable frame rate: 0.1 s steps, then 0.25 s steps from frame 8.
        let vfr = format!("settb=1/1000,setpts=({})/TB", vfr_expr());
        enc(
            H264,
            &[
                "-vf",
                &vfr,
                "-fps_mode",
                "passthrough",
                "-enc_time_base",
                "1/1000",
                "-video_track_timescale",
                "1000",
            ],
            "vfr.mp4",
        );
        // A codec outside the supported set, and a file without video.
        enc(&["-c:v", "ffv1"], &[], "ffv1.mkv");
        let s = Command::new(&t.ffmpeg)
            .args([
                "-y",
                "-v",
                "error",
                "-f",
                "lavfi",
                "-i",
                "sine=duration=0.2",
            ])
            .arg(dir.join("audio.m4a"))
            .status()
            .unwrap();
        assert!(s.success());
        let chroma = |fmt: &str| -> Vec<RgbImage> {
            std::fs::create_dir_all(dir.join(fmt)).unwrap();
            let s = Command::new(&t.ffmpeg)
                .args(["-y", "-v", "error", "-i"])
                .arg(&pat)
                .args([
                    "-vf",
                    &format!("format={fmt},format=rgb24"),
                    "-start_number",
                    "0",
                ])
                .arg(dir.join(format!("{fmt}/f%03d.png")))
                .status()
                .unwrap();
            assert!(s.success());
            (0..N)
                .map(|i| cac::io::load_rgb(&dir.join(format!("{fmt}/f{i:03}.png"))).unwrap())
                .collect()
        };
        Fixture {
            yuv420: chroma("yuv420p"),
            yuvj420: chroma("yuvj420p"),
            dir,
            frames,
            boxes,
        }
    })
}

pub fn vfr_time(i: usize) -> f64 {
    0.1 * i as f64 + if i > 7 { 0.15 * (i - 7) as f64 } else { 0.0 }
}

pub fn vfr_expr() -> &'static str {
    "N*0.1+gt(N\\,7)*(N-7)*0.15"
}

pub fn nanodet() -> Box<dyn Detector> {
    detect::load("nanodet", crate::support::models(), &inference()).unwrap()
}

pub fn centernet() -> Box<dyn Detector> {
    detect::load("centernet", crate::support::models(), &inference()).unwrap()
}

/// A frame's score and its matched box and class.
pub type Scored = (ImageScore, Option<([f32; 4], usize)>);

/// The reference: each frame scored directly (no video module involved).
pub fn direct(f: &Fixture, frames: &[RgbImage], d: &dyn Detector) -> Vec<Scored> {
    let p = Protocol::default();
    frames
        .iter()
        .zip(&f.boxes)
        .map(|(img, gt)| {
            let dets = d
                .detect(image_to_tensor(img, &inference()))
                .unwrap()
                .remove(0);
            let m = dets
                .iter()
                .filter(|x| detect::nms::iou(&x.bbox, gt) >= 0.5)
                .max_by(|a, b| a.score.total_cmp(&b.score))
                .map(|x| (x.bbox, x.class_id));
            (score_image(&dets, gt, &p), m)
        })
        .collect()
}

/// Scores an input, collecting the decoded frames of the scored records.
pub fn score(
    input: &Path,
    gt: &dyn GroundTruth,
    dets: &[&dyn Detector],
    opts: &ScoreOptions,
    open: &OpenOptions,
) -> (VideoScores, Vec<RgbImage>) {
    let mut s = video::open(&tools(), input, open).unwrap();
    let mut imgs = vec![];
    let r = video::score_stream(s.as_mut(), gt, dets, opts, &inference(), &mut |f, _| {
        imgs.push(f.image.clone());
        Ok(())
    })
    .unwrap();
    (r, imgs)
}

pub fn psnr(a: &RgbImage, b: &RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// Largest box-corner shift between two boxes (pixels).
pub fn shift(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    (0..4).map(|k| (a[k] - b[k]).abs()).fold(0.0, f32::max)
}

/// Per-frame tolerances for lossy codecs against the same frames in the video's pixel format
/// (docs/video.md): true-class confidence difference per model (also the margin around the
/// confidence threshold inside which a hit may flip), box shift, the least PSNR.
pub fn conf_tol(model: &str) -> f32 {
    if model == "centernet" {
        0.2
    } else {
        0.15
    }
}
/// Median and largest corner shift (pixels, 320x240 frames) of matched boxes of the same class.
pub const MEDIAN_SHIFT_MAX: f32 = 2.5;
pub const SHIFT_MAX: f32 = 6.0;
pub const PSNR_MIN: f64 = 35.0;

/// One frame set against a reference: the printed table row and the problems found.
pub fn measure(
    name: &str,
    model: &str,
    against: &str,
    reference: &[Scored],
    got: &[Scored],
    imgs: &[RgbImage],
    originals: &[RgbImage],
) -> Vec<String> {
    assert_eq!(got.len(), reference.len(), "{name}: every frame scored");
    let (mut dconf, mut dbox, mut min_psnr, mut flips) = (0.0f32, 0.0f32, f64::INFINITY, 0);
    let mut shifts = vec![];
    let mut vanish = 0;
    let tol = conf_tol(model);
    let mut bad = vec![];
    for (k, ((g, gb), (s, mb))) in got.iter().zip(reference).enumerate() {
        // A true-class detection at IoU >= 0.5 may appear or vanish below the threshold (the
        // confidence jumps from or to 0): counted; the hit rule below still applies.
        let both = g.best_true_conf > 0.0 && s.best_true_conf > 0.0;
        let dc = if both {
            (g.best_true_conf - s.best_true_conf).abs()
        } else {
            0.0
        };
        if !both && (g.best_true_conf > 0.0 || s.best_true_conf > 0.0) {
            vanish += 1;
        }
        dconf = dconf.max(dc);
        let q = psnr(&imgs[k], &originals[k]);
        min_psnr = min_psnr.min(q);
        // Box shift of the matched detection, when both see the object as the same class.
        if let (Some((a, ca)), Some((b, cb))) = (mb, gb) {
            if ca == cb {
                dbox = dbox.max(shift(a, b));
                shifts.push(shift(a, b));
            }
        }
        if g.hit != s.hit {
            flips += 1;
            if (s.best_true_conf - 0.3).abs() > tol {
                bad.push(format!(
                    "frame {k}: hit changed though the confidence {} is far from the threshold",
                    s.best_true_conf
                ));
            }
        }
        if dc > tol {
            bad.push(format!(
                "frame {k}: confidence {} vs {} (PSNR {q:.1} dB)",
                g.best_true_conf, s.best_true_conf
            ));
        }
    }
    let p = |v: &[Scored]| v.iter().filter(|x| x.0.hit).count() as f64 / v.len() as f64;
    shifts.sort_by(f32::total_cmp);
    let median = shifts.get(shifts.len() / 2).copied().unwrap_or(0.0);
    println!(
        "| {name} | {model} | {against} | {min_psnr:.1} | {dconf:.3} | {vanish} | {median:.1} / {dbox:.1} | {flips} | {:.3} | {:.3} |",
        p(reference),
        p(got)
    );
    if min_psnr < PSNR_MIN {
        bad.push(format!("PSNR {min_psnr:.1} dB"));
    }
    if median > MEDIAN_SHIFT_MAX || dbox > SHIFT_MAX {
        bad.push(format!(
            "matched boxes moved {median} px (median), {dbox} px (max)"
        ));
    }
    bad
}

/// Checks a video's records against the reference (same frames in the video's pixel format).
pub fn compare(
    name: &str,
    model: &str,
    reference: &[Scored],
    r: &VideoScores,
    m: usize,
    imgs: &[RgbImage],
    originals: &[RgbImage],
) {
    for (k, f) in r.frames.iter().enumerate() {
        assert_eq!(f.index, k as u64);
    }
    let got: Vec<_> = r
        .frames
        .iter()
        .map(|f| {
            let mf = &f.models[m];
            let matched = mf.matched.as_ref().map(|d| (d.0.bbox, d.0.class_id));
            (mf.score.clone(), matched)
        })
        .collect();
    let bad = measure(
        name,
        model,
        "4:2:0 frames",
        reference,
        &got,
        imgs,
        originals,
    );
    assert!(bad.is_empty(), "{name} {model}:\n{}", bad.join("\n"));
}
