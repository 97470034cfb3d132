//! The emulated webcam of the V4L2 tests: builds `tools/fakecam/fakecam.c` (an `LD_PRELOAD` shim
//! that answers a fake `/dev/videoN` as a UVC camera does) with the C compiler, writes its frame
//! bank (the frames it shows per rig pose, as baseline JPEG and packed YUYV), and sets up a `cac`
//! command to run against it.

#![allow(dead_code)]

use image::RgbImage;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// The fake device node (nothing exists there; the shim answers for it).
pub const DEV: &str = "/dev/video7";

/// The shim, compiled once per test process; `Err` (what is missing, for tests/support's
/// `missing`, a failure under `CI=true`) when there is no C compiler.
pub fn shim() -> Result<PathBuf, String> {
    static S: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    S.get_or_init(|| {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/fakecam/fakecam.c");
        let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("fakecam.so");
        let o = match Command::new("cc")
            .args([
                "-O2", "-shared", "-fPIC", "-Wall", "-Wextra", "-Werror", "-o",
            ])
            .arg(&out)
            .arg(&src)
            .args(["-ldl", "-lpthread"])
            .output()
        {
            Ok(o) => o,
            Err(e) => {
                return Err(format!(
                    "a C compiler (`cc`) to build the emulated webcam from {}: {e}",
                    src.display()
                ))
            }
        };
        assert!(
            o.status.success(),
            "cc {}:\n{}",
            src.display(),
            String::from_utf8_lossy(&o.stderr)
        );
        Ok(out)
    })
    .clone()
}

/// BT.601 limited-range RGB → packed YUYV (the chroma of a pixel pair averaged), the inverse
/// of cac's `yuyv_to_rgb` up to rounding.
pub fn rgb_to_yuyv(img: &RgbImage) -> Vec<u8> {
    let q = |v: f32| v.round().clamp(0.0, 255.0) as u8;
    let yuv = |p: &image::Rgb<u8>| {
        let [r, g, b] = p.0.map(f32::from);
        (
            16.0 + 0.257 * r + 0.504 * g + 0.098 * b,
            128.0 - 0.148 * r - 0.291 * g + 0.439 * b,
            128.0 + 0.439 * r - 0.368 * g - 0.071 * b,
        )
    };
    let mut out = Vec::with_capacity(img.width() as usize * img.height() as usize * 2);
    for y in 0..img.height() {
        for x in (0..img.width()).step_by(2) {
            let (y0, u0, v0) = yuv(img.get_pixel(x, y));
            let (y1, u1, v1) = yuv(img.get_pixel(x + 1, y));
            out.extend_from_slice(&[q(y0), q((u0 + u1) / 2.0), q(y1), q((v0 + v1) / 2.0)]);
        }
    }
    out
}

/// One frame of the bank: the pose it shows (table steps within a revolution, rail steps) and
/// its files.
#[derive(Debug, Clone)]
pub struct BankFrame {
    pub table_step: i64,
    pub rail_step: i64,
    pub jpeg: PathBuf,
    pub yuyv: PathBuf,
    pub width: u32,
    pub height: u32,
}

impl BankFrame {
    /// What cac must capture from this frame as MJPEG (sent without its Huffman tables).
    pub fn mjpeg_rgb(&self) -> RgbImage {
        cac::physical::camera::decode::decode_mjpeg(&std::fs::read(&self.jpeg).unwrap()).unwrap()
    }

    /// What cac must capture from this frame as YUYV at neutral exposure and white balance.
    pub fn yuyv_rgb(&self) -> RgbImage {
        let w = self.width;
        cac::physical::camera::decode::yuyv_to_rgb(
            &std::fs::read(&self.yuyv).unwrap(),
            w,
            self.height,
            2 * w as usize,
        )
        .unwrap()
    }
}

/// Writes `dir/index.txt` and the frames: `rev` table steps per revolution, then per frame
/// its pose and image (baseline JPEG with the standard Huffman tables, and YUYV).
pub fn write_bank(dir: &Path, rev: i64, frames: &[(i64, i64, RgbImage)]) -> Vec<BankFrame> {
    std::fs::create_dir_all(dir).unwrap();
    let mut index = format!("rev {rev}\n");
    let mut out = Vec::new();
    for (i, (t, r, img)) in frames.iter().enumerate() {
        let (w, h) = img.dimensions();
        let name = format!("f{i:03}_{w}x{h}");
        let jpeg = dir.join(format!("{name}.jpg"));
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90)
            .encode_image(img)
            .unwrap();
        std::fs::write(&jpeg, bytes).unwrap();
        let yuyv = dir.join(format!("{name}.yuyv"));
        std::fs::write(&yuyv, rgb_to_yuyv(img)).unwrap();
        index += &format!("{t} {r} {w} {h} {name}.jpg {name}.yuyv\n");
        out.push(BankFrame {
            table_step: *t,
            rail_step: *r,
            jpeg,
            yuyv,
            width: w,
            height: h,
        });
    }
    std::fs::write(dir.join("index.txt"), index).unwrap();
    out
}

/// How the emulated camera behaves for one run.
#[derive(Debug, Clone, Default)]
pub struct Camera {
    pub bank: PathBuf,
    /// File with the rig's physical pose ("<table steps> <rail steps>"); none: pose (0, 0).
    pub pose: Option<PathBuf>,
    /// `FAKECAM_FAULTS`.
    pub faults: String,
    /// `FAKECAM_FORMATS` (empty: MJPG then YUYV).
    pub formats: String,
    /// The shim's event log.
    pub log: PathBuf,
}

impl Camera {
    /// Makes `cmd` (a process not yet started) see the emulated camera at [`DEV`].
    pub fn apply(&self, shim: &Path, cmd: &mut Command) {
        cmd.env("LD_PRELOAD", shim)
            .env("FAKECAM_DEV", DEV)
            .env("FAKECAM_BANK", &self.bank)
            .env("FAKECAM_LOG", &self.log)
            .env("FAKECAM_FAULTS", &self.faults);
        if let Some(p) = &self.pose {
            cmd.env("FAKECAM_POSE", p);
        }
        if !self.formats.is_empty() {
            cmd.env("FAKECAM_FORMATS", &self.formats);
        }
    }

    /// The log's lines so far.
    pub fn log_lines(&self) -> Vec<String> {
        std::fs::read_to_string(&self.log)
            .unwrap_or_default()
            .lines()
            .map(str::to_string)
            .collect()
    }

    /// The faults the camera reports having fired.
    pub fn fired(&self) -> Vec<String> {
        self.log_lines()
            .iter()
            .filter_map(|l| l.strip_prefix("fault ").map(str::to_string))
            .collect()
    }
}
