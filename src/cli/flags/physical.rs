//! The physical test's flags (capture, camera check, printer calibration), mapped onto
//! `cac-physical`'s plain settings.

use cac::bench::calibration::CalibrationBench;
use cac::physical::camera_check::CameraCheck;
use cac::physical::capture::CaptureJob;
use cac::physical::print_calib::{CalibrateOptions, ChartSpec, PrinterKind};
use std::path::PathBuf;

/// `CameraCheck`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct CameraCheckFlags {
    /// The rig file: the lens size to capture at and the camera settings to lock.
    #[arg(long)]
    pub rig: PathBuf,
    /// V4L2 device node.
    #[arg(long, default_value = "/dev/video0")]
    pub device: PathBuf,
    /// Frames to capture.
    #[arg(long, default_value_t = 3)]
    pub frames: usize,
    /// Folder for the frames and camera.json.
    #[arg(long)]
    pub out: PathBuf,
}

impl From<CameraCheckFlags> for cac::physical::camera_check::CameraCheck {
    fn from(f: CameraCheckFlags) -> Self {
        CameraCheck {
            rig: f.rig,
            device: f.device,
            frames: f.frames,
            out: f.out,
        }
    }
}

/// `CaptureJob`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct CaptureFlags {
    /// The rig file (calib/rig.toml is an example).
    #[arg(long)]
    pub rig: PathBuf,
    /// Camouflage atlas painted on the object (the twin renders it; recorded in the session;
    /// default: the mesh's own look).
    #[arg(long)]
    pub texture: Option<PathBuf>,
    /// Distance ratios, comma separated (default: the rig file's).
    #[arg(long)]
    pub ratios: Option<String>,
    /// Table angles: START:END:STEP (END exclusive) or a comma list, degrees.
    #[arg(long, default_value = "0:360:15")]
    pub angles: String,
    /// Captures of every (ratio, angle).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Session folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue the session in --out, capturing only missing frames.
    #[arg(long)]
    pub resume: bool,
    /// Seed of the simulated faults and of the twin's sensor noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl From<CaptureFlags> for cac::physical::capture::CaptureJob {
    fn from(f: CaptureFlags) -> Self {
        CaptureJob {
            rig: f.rig,
            texture: f.texture,
            ratios: f.ratios,
            angles: f.angles,
            repeats: f.repeats,
            out: f.out,
            resume: f.resume,
            seed: f.seed,
        }
    }
}

/// `CalibrationBench`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct CalibrationBenchFlags {
    /// Patch counts, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "24,48,96,192")]
    pub patches: Vec<usize>,
    /// Charts (seeds) per count; their figures are averaged.
    #[arg(long, default_value_t = CalibrationBench::default().seeds)]
    pub seeds: u64,
}

impl From<CalibrationBenchFlags> for cac::bench::calibration::CalibrationBench {
    fn from(f: CalibrationBenchFlags) -> Self {
        CalibrationBench {
            patches: f.patches,
            seeds: f.seeds,
        }
    }
}

/// `ChartSpec`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct ChartFlags {
    /// The printer the chart calibrates.
    #[arg(long = "printer", value_parser = crate::cli::values::choice::<PrinterKind>())]
    pub kind: PrinterKind,
    /// Colour patches to print besides the ColorChecker's squares (full-colour and paper).
    #[arg(long, default_value_t = 192)]
    pub patches: usize,
    /// Seed of the patches' colours and places.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Centre-to-centre spacing of your ColorChecker card's patches, mm (its squares are drawn
    /// at this pitch so that the card laid on them covers them).
    #[arg(long, default_value_t = 13.0)]
    pub checker_pitch_mm: f32,
    /// FDM: the filaments, comma separated, each NAME or NAME=#RRGGBB (the nominal colour its
    /// square is drawn in); 2 to 16.
    #[arg(long, value_delimiter = ',')]
    pub filaments: Vec<String>,
}

impl From<ChartFlags> for cac::physical::print_calib::ChartSpec {
    fn from(f: ChartFlags) -> Self {
        ChartSpec {
            kind: f.kind,
            patches: f.patches,
            seed: f.seed,
            checker_pitch_mm: f.checker_pitch_mm,
            filaments: f.filaments,
        }
    }
}

/// `CalibrateOptions`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct CalibrateFlags {
    /// The kind of printer the profile is for (default: the chart's); a photo of a chart made
    /// for another kind is refused.
    #[arg(long = "printer", value_parser = crate::cli::values::choice::<PrinterKind>())]
    pub printer: Option<PrinterKind>,
    /// The profile's name (default: the printer kind and the photo's file name).
    #[arg(long)]
    pub name: Option<String>,
    /// Share of the printed patches held out of the fit to judge it (0 to 0.5).
    #[arg(long, default_value_t = CalibrateOptions::default().held_out)]
    pub held_out: f32,
    /// Seed of the held-out draw.
    #[arg(long, default_value_t = CalibrateOptions::default().seed)]
    pub seed: u64,
    /// Paper: the printable width of the media (roll or sheet), mm; required for paper.
    #[arg(long)]
    pub media_width_mm: Option<f32>,
    /// The camera's calibration (OpenCV or ROS YAML, e.g. calib/camera_opencv.yaml): the chart
    /// is read through its lens distortion (recommended for wide-angle webcams).
    #[arg(long)]
    pub intrinsics: Option<PathBuf>,
    /// FDM: nozzle width, mm.
    #[arg(long, default_value_t = CalibrateOptions::default().nozzle_mm)]
    pub nozzle_mm: f32,
    /// FDM: layer height, mm.
    #[arg(long, default_value_t = CalibrateOptions::default().layer_mm)]
    pub layer_mm: f32,
    /// FDM: the object's longest side as it will be printed, mm; required for fdm.
    #[arg(long)]
    pub object_size_mm: Option<f32>,
}

impl From<CalibrateFlags> for cac::physical::print_calib::CalibrateOptions {
    fn from(f: CalibrateFlags) -> Self {
        CalibrateOptions {
            printer: f.printer,
            name: f.name,
            held_out: f.held_out,
            seed: f.seed,
            media_width_mm: f.media_width_mm,
            intrinsics: f.intrinsics,
            nozzle_mm: f.nozzle_mm,
            layer_mm: f.layer_mm,
            object_size_mm: f.object_size_mm,
        }
    }
}
