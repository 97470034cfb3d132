//! One scoring of a recording (`cac score-video`): open the input, build its ground truth
//! (annotations, or a turntable log seen by a rig camera), sample and score the frames
//! ([`super::score`]), draw the annotated output, and write the report ([`super::report`]).
//! [`VideoJob::open`] resolves the inputs (so the caller can say what it scores before the
//! detectors run), [`Opened::run`] scores and writes.

use super::annotate::{self, AnnotatedWriter};
use super::log::{LogGroundTruth, LogSegments, TurntableLog};
use super::report;
use crate::annotations::{Annotations, GroundTruth};
use crate::decode::{FrameStream, OpenOptions};
use crate::score::{Sampling, ScoreOptions, Segmenting, VideoScores};
use crate::tools::Tools;
use anyhow::{bail, Context, Result};
use burn::tensor::Device;
use cac_detect::Detector;
use cac_eval::Protocol;
use cac_physical::rig::Rig;
use cac_physical::rig_camera::{RigCamera, TwinCalibration, TwinCamera};
use cac_render::config::ObjectConfig;
use cac_render::{RenderSettings, Renderer};
use std::path::PathBuf;

/// Where the log's ground-truth boxes come from.
#[derive(Clone, Debug)]
pub enum LogCamera {
    /// A calibrated rig file (lens, camera pose, object), as `cac score` uses for sessions.
    Rig(PathBuf),
    /// The viewpoint twin of `mesh` (built-in name or file) with a vertical field of view and a
    /// calibration JSON (default: [`TwinCalibration::default`]).
    Twin {
        mesh: String,
        vfov_deg: f32,
        calibration: Option<PathBuf>,
    },
}

/// When log time 0 is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LogOffset {
    /// Log time = video time + this many seconds.
    Seconds(f64),
    /// The video's creation time (Unix seconds; logs with Unix timestamps such as manifests).
    Creation,
}

impl std::str::FromStr for LogOffset {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<LogOffset> {
        match s {
            "creation" => Ok(LogOffset::Creation),
            s => s
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .map(LogOffset::Seconds)
                .with_context(|| format!("--log-offset {s:?}: seconds or `creation`")),
        }
    }
}

/// A turntable log as ground truth.
#[derive(Clone, Debug)]
pub struct LogTruth {
    pub path: PathBuf,
    pub offset: LogOffset,
    pub camera: LogCamera,
    pub segments: LogSegments,
    /// The ratio of logs that do not record one.
    pub default_ratio: f64,
    /// Score the frames nearest to the log's sample times (step-and-shoot sessions).
    pub at_samples: bool,
}

/// The ground truth of a job.
#[derive(Clone, Debug)]
pub enum Truth {
    /// Annotation CSV or COCO JSON.
    Annotations(PathBuf),
    Log(LogTruth),
}

/// Everything a scoring needs besides the detectors.
#[derive(Clone, Debug)]
pub struct VideoJob {
    pub input: PathBuf,
    pub out: PathBuf,
    pub truth: Truth,
    pub open: OpenOptions,
    /// Frames 0, k, 2k, ... unless `at` (or the log's times) are given.
    pub every: u64,
    /// The frames nearest to these times (seconds).
    pub at: Option<Vec<f64>>,
    /// Fixed time windows (seconds) as segments instead of the ground truth's.
    pub window: Option<f64>,
    pub max_frames: Option<usize>,
    pub protocol: Protocol,
    /// Annotated output: a video (.mp4/.mkv/.avi) or a folder of PNGs.
    pub annotated: Option<PathBuf>,
    pub tools: Tools,
}

/// A job with its input open and its ground truth built.
pub struct Opened<'j> {
    job: &'j VideoJob,
    stream: Box<dyn FrameStream>,
    truth: Box<dyn GroundTruth>,
    options: ScoreOptions,
}

/// What a finished job measured.
pub struct VideoOutcome {
    pub scores: VideoScores,
    /// Timing and output lines, also in the report.
    pub notes: Vec<String>,
    /// The output folder.
    pub out: PathBuf,
}

/// What `cac score-video` prints: the summary table, the notes, what was decoded and scored.
impl std::fmt::Display for VideoOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = &self.scores;
        write!(f, "{}", report::summary_table(s).markdown())?;
        for n in &self.notes {
            writeln!(f, "{n}")?;
        }
        if !s.missed_times.is_empty() {
            writeln!(f, "times outside the video: {:?}", s.missed_times)?;
        }
        let (decoded, scored, without) = (s.decoded, s.frames.len(), s.unannotated);
        let out = self.out.display();
        writeln!(
            f,
            "{decoded} frames decoded, {scored} scored, {without} sampled without ground truth; \
             wrote {out}"
        )
    }
}

impl VideoJob {
    /// Opens the input and builds the ground truth and the sampling.
    pub fn open(&self) -> Result<Opened<'_>> {
        if self.open.rotate_ccw.is_some_and(|r| r % 90 != 0) {
            bail!("--rotate must be 0, 90, 180 or 270");
        }
        let stream = crate::decode::open(&self.tools, &self.input, &self.open)?;
        let (truth, log_times) = self.ground_truth(stream.creation_time(), stream.size())?;
        let sampling = match log_times.or_else(|| self.at.clone()) {
            Some(t) => Sampling::At(t),
            None => Sampling::Every(self.every),
        };
        let options = ScoreOptions {
            sampling,
            segmenting: self
                .window
                .map_or(Segmenting::FromGroundTruth, Segmenting::Window),
            protocol: self.protocol.clone(),
            max_frames: self.max_frames,
        };
        Ok(Opened {
            job: self,
            stream,
            truth,
            options,
        })
    }

    /// The ground truth, and with [`LogTruth::at_samples`] the times to score (video seconds).
    /// `creation` is the video's creation time (Unix seconds) where it records one.
    #[allow(clippy::type_complexity)]
    fn ground_truth(
        &self,
        creation: Option<f64>,
        size: (u32, u32),
    ) -> Result<(Box<dyn GroundTruth>, Option<Vec<f64>>)> {
        let l = match &self.truth {
            Truth::Annotations(p) => return Ok((Box::new(Annotations::load(p)?), None)),
            Truth::Log(l) => l,
        };
        let log = TurntableLog::load(&l.path)?;
        let offset_s = match l.offset {
            LogOffset::Creation => creation.with_context(|| {
                format!(
                    "{} has no creation_time: give --log-offset in seconds",
                    self.input.display()
                )
            })?,
            LogOffset::Seconds(s) => s,
        };
        let t0 = log.samples()[0].t;
        if t0 > 1e8 && offset_s.abs() < 1e8 {
            bail!(
                "{}: times look like Unix seconds ({t0}) but the video starts at 0 s: give \
                 --log-offset creation or the Unix time of the video's first frame",
                l.path.display()
            );
        }
        let times = l
            .at_samples
            .then(|| log.samples().iter().map(|s| s.t - offset_s).collect());
        let gt = LogGroundTruth {
            log,
            camera: l.camera.build(size)?,
            offset_s,
            segments: l.segments,
            default_ratio: l.default_ratio,
        };
        Ok((Box::new(gt), times))
    }
}

impl LogCamera {
    /// The rig camera for frames of `(w, h)` pixels.
    pub fn build(&self, (w, h): (u32, u32)) -> Result<Box<dyn RigCamera>> {
        let (mesh, vfov_deg, calibration) = match self {
            LogCamera::Rig(r) => {
                let rig = Rig::load(r)?;
                rig.check_frame_size((w, h))?;
                return Ok(Box::new(rig));
            }
            LogCamera::Twin {
                mesh,
                vfov_deg,
                calibration,
            } => (mesh, *vfov_deg, calibration),
        };
        let calibration = match calibration {
            Some(c) => TwinCalibration::load(c)?,
            None => TwinCalibration::default(),
        };
        let object = ObjectConfig {
            mesh: mesh.clone(),
            ..Default::default()
        };
        let settings = RenderSettings {
            width: w as usize,
            height: h as usize,
            samples: 1,
            vfov_deg,
            atlas_res: 2,
        };
        let r = Renderer::new(object.load()?, settings)?;
        Ok(Box::new(TwinCamera::new(r, calibration)))
    }
}

impl Opened<'_> {
    /// What is scored.
    pub fn source(&self) -> String {
        self.stream.describe()
    }

    /// Where its ground truth comes from.
    pub fn truth(&self) -> String {
        self.truth.describe()
    }

    /// Scores every sampled frame with each detector (named `names` in the annotated output and
    /// the examples), draws the annotated output, and writes the report into the job's `out`.
    pub fn run(
        mut self,
        detectors: &[&dyn Detector],
        names: &[String],
        device: &Device,
    ) -> Result<VideoOutcome> {
        let job = self.job;
        let (w, h) = self.stream.size();
        let out_fps = match &self.options.sampling {
            Sampling::Every(k) => self.stream.fps() / *k as f64,
            Sampling::At(_) => 2.0,
        };
        let mut writer = match &job.annotated {
            Some(p) => Some(AnnotatedWriter::create(
                &job.tools,
                p,
                (w * names.len() as u32, h),
                out_fps,
            )?),
            None => None,
        };
        let conf = self.options.protocol.confidence;
        let mut examples = report::Examples::new(8);
        let scores = crate::score::score_stream(
            self.stream.as_mut(),
            self.truth.as_ref(),
            detectors,
            &self.options,
            device,
            &mut |f, rec| {
                examples.offer(&f.image, rec, names, conf);
                if let Some(wr) = writer.as_mut() {
                    wr.write(&annotate::draw(&f.image, rec, names, conf), f.index)?;
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
        report::write_all(&job.out, &scores, &notes, &examples.frames)?;
        Ok(VideoOutcome {
            scores,
            notes,
            out: job.out.clone(),
        })
    }
}
