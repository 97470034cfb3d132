//! `cac score-video INPUT`: offline scoring of a recorded video, image pattern or image folder
//! against annotations or a turntable log (docs/video.md). Parse → `cac::video` → print.

use anyhow::{bail, Context, Result};
use cac::detect::{self, Detector};
use cac::eval::Protocol;
use cac::physical::rig_camera::{RigCamera, TwinCalibration, TwinCamera};
use cac::render::{RenderSettings, Renderer};
use cac::video::log::{LogGroundTruth, LogSegments, TurntableLog};
use cac::video::{
    annotate, report, Annotations, GroundTruth, OpenOptions, Sampling, ScoreOptions, Segmenting,
    Tools,
};
use clap::{Args as ClapArgs, ValueEnum};
use std::path::PathBuf;

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SegArg {
    Revolution,
    Ratio,
}

#[derive(ClapArgs, Debug)]
pub struct Args {
    /// A video (H.264/HEVC MP4, MJPEG AVI), an image pattern (`frames/%04d.png`) or an image folder.
    pub input: PathBuf,
    /// Output folder: frames.csv, segments.csv, summary.csv/.md, scores.json, plots, report.html.
    #[arg(long)]
    pub out: PathBuf,
    /// Detectors, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = super::detect::ModelSpec, default_value = "nanodet,centernet")]
    pub models: Vec<String>,
    /// Ground truth: annotation CSV or COCO JSON (docs/video.md).
    #[arg(long, conflicts_with = "log")]
    pub annotations: Option<PathBuf>,
    /// Ground truth: turntable log (CSV or JSON lines), projected with the digital twin.
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// Project the log through a calibrated rig file (rig.toml: lens, camera pose, object), as
    /// `cac score` does for capture sessions.
    #[arg(long, requires = "log", conflicts_with = "calib")]
    pub rig: Option<PathBuf>,
    /// Without --rig: the digital twin's calibration JSON {azimuth_at_zero_deg, direction,
    /// elevation_deg} (default: 90, -1, 10) with --mesh and --vfov.
    #[arg(long, requires = "log")]
    pub calib: Option<PathBuf>,
    /// Log time = video time + offset: seconds, or `creation` for the video's creation_time
    /// (Unix seconds, for logs with Unix timestamps such as capture manifests).
    #[arg(long, default_value = "0", allow_hyphen_values = true)]
    pub log_offset: String,
    /// Score the frames nearest to the log's sample times (step-and-shoot sessions: the settled
    /// frames), instead of --every/--at.
    #[arg(long, requires = "log", conflicts_with = "at")]
    pub at_log: bool,
    /// Segments of a logged session.
    #[arg(long, value_enum, default_value = "revolution")]
    pub segments: SegArg,
    /// The twin's object (built-in name or mesh file) and vertical field of view, for --log.
    #[arg(long, default_value = "pickup")]
    pub mesh: String,
    #[arg(long, default_value_t = 45.0)]
    pub vfov: f32,
    /// Distance ratio of logs that do not record one.
    #[arg(long, default_value_t = 2.0)]
    pub ratio: f64,
    /// Score every k-th frame.
    #[arg(long, default_value_t = 1, conflicts_with = "at")]
    pub every: u64,
    /// Score the frames nearest to these times (seconds, comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub at: Option<Vec<f64>>,
    /// Fixed time windows (seconds) as segments, instead of the ground truth's segments.
    #[arg(long)]
    pub window: Option<f64>,
    /// Stop after this many scored frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Frame rate of image folders and patterns.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Counter-clockwise rotation (0, 90, 180, 270) overriding the video's metadata.
    #[arg(long)]
    pub rotate: Option<u32>,
    /// Decode codecs other than H.264, HEVC, MJPEG and PNG (tolerances not measured).
    #[arg(long)]
    pub any_codec: bool,
    /// Annotated output: a video (.mp4/.mkv/.avi) or a folder of PNGs.
    #[arg(long)]
    pub annotated: Option<PathBuf>,
    /// Attack target class (COCO label) for the targeted-success column.
    #[arg(long)]
    pub target: Option<String>,
    /// Folder holding the model files (default: the cache, fetched on first use).
    #[arg(long = "models-dir")]
    pub models_dir: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    if a.rotate.is_some_and(|r| r % 90 != 0) {
        bail!("--rotate must be 0, 90, 180 or 270");
    }
    let tools = Tools::from_env();
    let opts = OpenOptions {
        rotate_ccw: a.rotate,
        fps: a.fps,
        allow_any_codec: a.any_codec,
    };
    let mut stream = cac::video::open(&tools, &a.input, &opts)?;
    let (w, h) = stream.size();
    let (gt, log_times) = ground_truth(&a, stream.creation_time(), (w, h))?;
    let sampling = match log_times.or_else(|| a.at.clone()) {
        Some(t) => Sampling::At(t),
        None => Sampling::Every(a.every),
    };
    let out_fps = match &sampling {
        Sampling::Every(k) => stream.fps() / *k as f64,
        Sampling::At(_) => 2.0,
    };
    let so = ScoreOptions {
        sampling,
        segmenting: a
            .window
            .map_or(Segmenting::FromGroundTruth, Segmenting::Window),
        protocol: protocol(a.target.as_deref())?,
        max_frames: a.max_frames,
    };
    let device = super::device::inference();
    let dets = detect::load_all(&a.models, a.models_dir.as_deref(), &device)?;
    let refs: Vec<&dyn Detector> = dets.iter().map(|d| d.as_ref()).collect();
    let names: Vec<String> = a.models.clone();
    println!("scoring {}", stream.describe());
    println!("ground truth: {}", gt.describe());
    let mut writer = match &a.annotated {
        Some(p) => Some(annotate::AnnotatedWriter::create(
            &tools,
            p,
            (w * names.len() as u32, h),
            out_fps,
        )?),
        None => None,
    };
    let conf = so.protocol.confidence;
    let mut examples = report::Examples::new(8);
    let scores = cac::video::score_stream(
        stream.as_mut(),
        gt.as_ref(),
        &refs,
        &so,
        &device,
        &mut |f, rec| {
            examples.offer(&f.image, rec, &names, conf);
            if let Some(wr) = writer.as_mut() {
                wr.write(&annotate::draw(&f.image, rec, &names, conf), f.index)?;
            }
            Ok(())
        },
    )?;
    let mut notes = vec![format!(
        "decode {:.1} s, detection {:.1} s ({:.2} scored frames/s)",
        scores.decode_s,
        scores.detect_s,
        scores.frames.len() as f64 / (scores.decode_s + scores.detect_s).max(1e-9)
    )];
    if let Some(wr) = writer {
        let p = wr.finish()?;
        notes.push(format!("annotated output: {}", p.display()));
    }
    report::write_all(&a.out, &scores, &notes, &examples.frames)?;
    print_scores(&a, &scores, &notes)
}

/// Video times in seconds.
type Times = Vec<f64>;

/// The ground truth the flags name, and with `--at-log` the times to score (video seconds).
/// `creation` is the video's creation time (Unix seconds) where it records one.
fn ground_truth(
    a: &Args,
    creation: Option<f64>,
    size: (u32, u32),
) -> Result<(Box<dyn GroundTruth>, Option<Times>)> {
    let p = match (&a.annotations, &a.log) {
        (Some(p), None) => return Ok((Box::new(Annotations::load(p)?), None)),
        (None, Some(p)) => p,
        _ => bail!("give the ground truth: --annotations FILE or --log FILE"),
    };
    let log = TurntableLog::load(p)?;
    let offset_s = match a.log_offset.as_str() {
        "creation" => creation.with_context(|| {
            format!(
                "{} has no creation_time: give --log-offset in seconds",
                a.input.display()
            )
        })?,
        s => s
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .with_context(|| format!("--log-offset {s:?}: seconds or `creation`"))?,
    };
    let t0 = log.samples()[0].t;
    if t0 > 1e8 && offset_s.abs() < 1e8 {
        bail!(
            "{}: times look like Unix seconds ({t0}) but the video starts at 0 s: give \
             --log-offset creation or the Unix time of the video's first frame",
            p.display()
        );
    }
    let times = a
        .at_log
        .then(|| log.samples().iter().map(|s| s.t - offset_s).collect());
    let gt = LogGroundTruth {
        log,
        camera: rig_camera(a, size)?,
        offset_s,
        segments: match a.segments {
            SegArg::Revolution => LogSegments::Revolution,
            SegArg::Ratio => LogSegments::Ratio,
        },
        default_ratio: a.ratio,
    };
    Ok((Box::new(gt), times))
}

/// The log's rig camera: the calibrated rig (`--rig`) or the digital twin of `--mesh`.
fn rig_camera(a: &Args, (w, h): (u32, u32)) -> Result<Box<dyn RigCamera>> {
    if let Some(r) = &a.rig {
        let rig = cac::physical::rig::Rig::load(r)?;
        rig.check_frame_size((w, h))?;
        return Ok(Box::new(rig));
    }
    let calibration = match &a.calib {
        Some(c) => TwinCalibration::load(c)?,
        None => TwinCalibration::default(),
    };
    let object = cac::config::ObjectConfig {
        mesh: a.mesh.clone(),
        ..Default::default()
    };
    let settings = RenderSettings {
        width: w as usize,
        height: h as usize,
        samples: 1,
        vfov_deg: a.vfov,
        atlas_res: 2,
    };
    let r = Renderer::new(object.load()?, settings)?;
    Ok(Box::new(TwinCamera::new(r, calibration)))
}

/// The protocol, with `--target`'s class.
fn protocol(target: Option<&str>) -> Result<Protocol> {
    let target = match target {
        Some(t) => {
            Some(detect::labels::class_id(t).with_context(|| format!("unknown COCO class {t:?}"))?)
        }
        None => None,
    };
    Ok(Protocol {
        target,
        ..Default::default()
    })
}

/// Prints the summary table and notes; fails when no frame was scored.
fn print_scores(a: &Args, scores: &cac::video::VideoScores, notes: &[String]) -> Result<()> {
    print!("{}", report::summary_table(scores).markdown());
    for n in notes {
        println!("{n}");
    }
    if !scores.missed_times.is_empty() {
        println!("times outside the video: {:?}", scores.missed_times);
    }
    println!(
        "{} frames decoded, {} scored, {} sampled without ground truth; wrote {}",
        scores.decoded,
        scores.frames.len(),
        scores.unannotated,
        a.out.display()
    );
    if scores.frames.is_empty() {
        bail!("no frame was scored: check the ground truth covers the sampled frames");
    }
    Ok(())
}
