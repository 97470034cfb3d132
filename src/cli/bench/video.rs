//! `cac bench video`: throughput of offline video scoring. A turntable sequence of the default
//! pickup is rendered by the digital twin, encoded with each codec, then timed: decoding alone
//! (frames/s) and scoring with each detector (frames scored per second, decode included).
//! Prints a table and writes a CSV. A benchmark, not a test: it asserts nothing. Measured by
//! `cac::bench::video`.

use crate::cli::device;
use anyhow::Result;
use cac::bench::video::VideoBench;
use cac::detect::{self, Detector};
use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs, Debug)]
pub struct Args {
    #[command(flatten)]
    pub bench: BenchFlags,
    /// Detectors, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::values::MODEL_SPECS, default_value = "nanodet,centernet")]
    pub models: Vec<String>,
    /// CSV output file.
    #[arg(long, default_value = "bench-video.csv")]
    pub csv: PathBuf,
}

/// The rendered sequence and the codecs ([`VideoBench`]).
#[derive(ClapArgs, Debug)]
pub struct BenchFlags {
    /// Frame size of the rendered sequence.
    #[arg(long, default_value_t = VideoBench::default().width)]
    pub width: usize,
    #[arg(long, default_value_t = VideoBench::default().height)]
    pub height: usize,
    /// Frames (one turn of the turntable).
    #[arg(long, default_value_t = VideoBench::default().frames)]
    pub frames: usize,
    /// Codecs, comma-separated (h264, hevc, mjpeg).
    #[arg(long, value_delimiter = ',', default_value = "h264,hevc,mjpeg")]
    pub codecs: Vec<String>,
}

impl From<BenchFlags> for VideoBench {
    fn from(f: BenchFlags) -> Self {
        VideoBench {
            width: f.width,
            height: f.height,
            frames: f.frames,
            codecs: f.codecs,
        }
    }
}

pub fn run(a: Args) -> Result<()> {
    let tools = crate::cli::score_video::tools();
    tools.check()?;
    let device = device::inference();
    let dets = detect::load_all(&a.models, None, &device)?;
    let named: Vec<(&str, &dyn Detector)> = a
        .models
        .iter()
        .zip(&dets)
        .map(|(m, d)| (m.as_str(), d.as_ref()))
        .collect();
    let t = VideoBench::from(a.bench).run(&tools, &named, &device)?;
    print!("{}", t.markdown());
    cac::io::write_atomic(&a.csv, t.csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}
