//! The video benchmark's measurements (`cac bench video`): a turntable sequence of the default
//! pickup rendered by the viewpoint twin ([`super::twin::render_turntable`]), encoded with each
//! codec, then timed with the one timer (`report::timer`): decoding alone (frames/s) and scoring
//! with each detector (frames scored per second, decode included). One [`Table`] row per codec
//! and model.

use anyhow::Result;
use burn::tensor::Device;
use cac_core::report::timer::Stopwatch;
use cac_core::report::Table;
use cac_detect::Detector;
use cac_video::annotations::Annotations;
use cac_video::decode::OpenOptions;
use cac_video::encode::{encode_sequence, H264, HEVC, MJPEG};
use cac_video::score::ScoreOptions;
use cac_video::twin::{render_turntable, TwinCalibration};
use cac_video::Tools;
use std::path::Path;

/// The rendered sequence and the codecs.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoBench {
    /// Frame size of the rendered sequence.
    pub width: usize,
    pub height: usize,
    /// Frames (one turn of the turntable).
    pub frames: usize,
    /// Codecs (h264, hevc, mjpeg).
    pub codecs: Vec<String>,
}

impl Default for VideoBench {
    /// 640×480, 24 frames (one turn), every measured codec.
    fn default() -> Self {
        VideoBench {
            width: 640,
            height: 480,
            frames: 24,
            codecs: ["h264", "hevc", "mjpeg"].map(String::from).to_vec(),
        }
    }
}

impl VideoBench {
    /// Renders, encodes and times; `dets` are `(name, detector)`.
    pub fn run(
        &self,
        tools: &Tools,
        dets: &[(&str, &dyn Detector)],
        device: &Device,
    ) -> Result<Table> {
        let a = self;
        let dir = tempfile::tempdir()?;
        let gt = a.render_frames(dir.path(), device)?;
        let mut t = Table::new([
            "codec",
            "size",
            "model",
            "frames",
            "decode frames/s",
            "detect ms/frame",
            "scored frames/s",
        ]);
        let size = format!("{}x{}", a.width, a.height);
        for codec in &a.codecs {
            let (args, name): (&[&str], &str) = match codec.as_str() {
                "h264" => (H264, "v.mp4"),
                "hevc" => (HEVC, "v-hevc.mp4"),
                "mjpeg" => (MJPEG, "v.avi"),
                other => anyhow::bail!("unknown codec {other:?}: expected h264, hevc or mjpeg"),
            };
            let path = dir.path().join(name);
            encode_sequence(tools, &dir.path().join("f%04d.png"), 24.0, args, &[], &path)?;
            // Decoding alone.
            let t0 = Stopwatch::start();
            let mut s = cac_video::decode::open(tools, &path, &OpenOptions::default())?;
            let mut n = 0;
            while s.next_frame()?.is_some() {
                n += 1;
            }
            let decode_fps = n as f64 / t0.secs();
            t.row([
                codec.clone(),
                size.clone(),
                "(decode only)".into(),
                n.to_string(),
                format!("{decode_fps:.1}"),
                "".into(),
                "".into(),
            ]);
            for (m, d) in dets {
                let mut s = cac_video::decode::open(tools, &path, &OpenOptions::default())?;
                let t0 = Stopwatch::start();
                let r = cac_video::score::score_stream(
                    s.as_mut(),
                    &gt,
                    &[*d],
                    &ScoreOptions::default(),
                    device,
                    &mut |_, _| Ok(()),
                )?;
                let wall = t0.secs();
                t.row([
                    codec.clone(),
                    size.clone(),
                    m.to_string(),
                    r.frames.len().to_string(),
                    format!("{decode_fps:.1}"),
                    format!("{:.1}", r.summary[0].ms_per_frame),
                    format!("{:.2}", r.frames.len() as f64 / wall),
                ]);
            }
        }
        Ok(t)
    }

    /// Renders one turn of the default pickup with the digital twin into `dir` (`f%04d.png`) and
    /// returns its boxes as annotations.
    fn render_frames(&self, dir: &Path, device: &Device) -> Result<Annotations> {
        let a = self;
        let mut scene = cac_scene::generate::pickup();
        scene.normalise(0.0, None);
        let settings = cac_render::RenderSettings {
            width: a.width,
            height: a.height,
            samples: 2,
            ..Default::default()
        };
        let r = cac_render::Renderer::new(scene, settings)?;
        let env = cac_render::environment::Environment::new(Default::default())?;
        let atlas = r.scene.initial_atlas(r.settings.atlas_res);
        let poses: Vec<(f64, f64)> = (0..a.frames)
            .map(|i| (360.0 * i as f64 / a.frames as f64, 1.6))
            .collect();
        let t0 = Stopwatch::start();
        let calib = TwinCalibration::default();
        let frames = render_turntable(&r, &env, &atlas, &calib, &poses, device)?;
        let mut csv = Table::new(["frame", "x1", "y1", "x2", "y2"]);
        for (i, (img, b)) in frames.iter().enumerate() {
            cac_core::io::save_png_atomic(&dir.join(format!("f{i:04}.png")), img)?;
            if let Some(b) = b {
                csv.row([i.to_string()].into_iter().chain(b.map(|v| v.to_string())));
            }
        }
        let gt_path = dir.join("gt.csv");
        cac_core::io::write_atomic(&gt_path, csv.csv().as_bytes())?;
        eprintln!(
            "rendered {} frames at {}x{} in {:.1} s",
            a.frames,
            a.width,
            a.height,
            t0.secs()
        );
        Annotations::load(&gt_path)
    }
}
