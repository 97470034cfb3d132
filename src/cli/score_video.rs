//! `cac score-video INPUT`: offline scoring of a recorded video, image pattern or image folder
//! against annotations or a turntable log (docs/video.md). Parse → `cac::video` → print.

use anyhow::{bail, Result};
use cac::detect;
use cac::eval::Protocol;
use cac::video::job::{LogCamera, LogTruth, Truth, VideoJob};
use cac::video::log::LogSegments;
use cac::video::{OpenOptions, Tools};
use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs, Debug)]
pub struct Args {
    /// A video (H.264/HEVC MP4, MJPEG AVI), an image pattern (`frames/%04d.png`) or an image folder.
    pub input: PathBuf,
    /// Output folder: frames.csv, segments.csv, summary.csv/.md, scores.json, plots, report.html.
    #[arg(long)]
    pub out: PathBuf,
    /// Detectors, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::values::MODEL_SPECS, default_value = "nanodet,centernet")]
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
    #[arg(long, value_parser = crate::cli::values::choice::<LogSegments>(), default_value = "revolution")]
    pub segments: LogSegments,
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
    #[command(flatten)]
    pub open: OpenFlags,
    /// Annotated output: a video (.mp4/.mkv/.avi) or a folder of PNGs.
    #[arg(long)]
    pub annotated: Option<PathBuf>,
    /// Attack target class (by name; one of the models' classes) for the targeted-success column.
    #[arg(long)]
    pub target: Option<String>,
    /// True classes (class names, comma-separated, each one of every model's classes).
    #[arg(long, default_value = "car,truck")]
    pub true_classes: String,
    /// Folder holding the model files (default: the cache, fetched on first use).
    #[arg(long = "models-dir")]
    pub models_dir: Option<PathBuf>,
    /// Input defences in front of every detector, each a column group beside the detector as
    /// it is: NAME[:PARAM] of jpeg, blur, median, bits, resize-pad, tv, lgs (`+` chains several;
    /// docs/eval.md "Defences"), comma-separated.
    #[arg(long = "defence", value_delimiter = ',')]
    pub defences: Vec<String>,
}

/// How to open the input ([`OpenOptions`]).
#[derive(ClapArgs, Debug, Clone)]
pub struct OpenFlags {
    /// Counter-clockwise rotation (0, 90, 180, 270) overriding the video's metadata.
    #[arg(long = "rotate", value_name = "DEGREES")]
    pub rotate_ccw: Option<u32>,
    /// Frame rate of image folders and patterns (their frames carry no times).
    #[arg(long, default_value_t = OpenOptions::default().fps)]
    pub fps: f64,
    /// Decode codecs other than H.264, HEVC, MJPEG and PNG (tolerances not measured).
    #[arg(long = "any-codec")]
    pub allow_any_codec: bool,
}

impl From<OpenFlags> for OpenOptions {
    fn from(f: OpenFlags) -> Self {
        OpenOptions {
            rotate_ccw: f.rotate_ccw,
            fps: f.fps,
            allow_any_codec: f.allow_any_codec,
        }
    }
}

pub fn run(a: Args) -> Result<()> {
    let chains = detect::defence::parse_chains(&a.defences)?;
    let job = job(&a)?;
    let opened = job.open()?;
    let device = super::device::inference();
    let dets = detect::load_all(&a.models, a.models_dir.as_deref(), &device)?;
    let dets = detect::defence::defend(dets, &chains);
    let refs = cac::detect::refs(&dets);
    let names: Vec<String> = dets.iter().map(|d| d.name().to_string()).collect();
    println!("scoring {}", opened.source());
    println!("ground truth: {}", opened.truth());
    let o = opened.run(&refs, &names, &device)?;
    print!("{o}");
    if o.scores.frames.is_empty() {
        bail!("no frame was scored: check the ground truth covers the sampled frames");
    }
    Ok(())
}

/// The library job the flags describe.
fn job(a: &Args) -> Result<VideoJob> {
    let truth = match (&a.annotations, &a.log) {
        (Some(p), None) => Truth::Annotations(p.clone()),
        (None, Some(p)) => Truth::Log(LogTruth {
            path: p.clone(),
            offset: a.log_offset.parse()?,
            camera: match &a.rig {
                Some(r) => LogCamera::Rig(r.clone()),
                None => LogCamera::Twin {
                    mesh: a.mesh.clone(),
                    vfov_deg: a.vfov,
                    calibration: a.calib.clone(),
                },
            },
            segments: a.segments,
            default_ratio: a.ratio,
            at_samples: a.at_log,
        }),
        _ => bail!("give the ground truth: --annotations FILE or --log FILE"),
    };
    Ok(VideoJob {
        input: a.input.clone(),
        out: a.out.clone(),
        truth,
        open: a.open.clone().into(),
        every: a.every,
        at: a.at.clone(),
        window: a.window,
        max_frames: a.max_frames,
        protocol: Protocol::from_labels(&a.true_classes, a.target.as_deref())?,
        annotated: a.annotated.clone(),
        tools: tools(),
    })
}

/// ffmpeg and ffprobe: `$CAC_FFMPEG` / `$CAC_FFPROBE` when set, else on `PATH`.
pub fn tools() -> Tools {
    let var = |k| std::env::var_os(k).map(std::path::PathBuf::from);
    Tools::locate(var("CAC_FFMPEG"), var("CAC_FFPROBE"))
}
