//! `cac bench video`: throughput of offline video scoring. A turntable sequence of the default
//! pickup is rendered by the digital twin, encoded with each codec, then timed: decoding alone
//! (frames/s) and scoring with each detector (frames scored per second, decode included).
//! Prints a table and writes a CSV. A benchmark, not a test: it asserts nothing. Measured by
//! `cac::video::bench`.

use crate::cli::device;
use anyhow::Result;
use cac::detect::{self, Detector};
use cac::video::bench::VideoBench;
use cac::video::Tools;
use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs, Debug)]
pub struct Args {
    /// Frame size of the rendered sequence.
    #[arg(long, default_value_t = 640)]
    pub width: usize,
    #[arg(long, default_value_t = 480)]
    pub height: usize,
    /// Frames (one turn of the turntable).
    #[arg(long, default_value_t = 24)]
    pub frames: usize,
    /// Detectors, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = crate::cli::detect::MODEL_SPECS, default_value = "nanodet,centernet")]
    pub models: Vec<String>,
    /// Codecs, comma-separated (h264, hevc, mjpeg).
    #[arg(long, value_delimiter = ',', default_value = "h264,hevc,mjpeg")]
    pub codecs: Vec<String>,
    /// CSV output file.
    #[arg(long, default_value = "bench-video.csv")]
    pub csv: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let tools = Tools::from_env();
    tools.check()?;
    let device = device::inference();
    let dets = detect::load_all(&a.models, None, &device)?;
    let named: Vec<(&str, &dyn Detector)> = a
        .models
        .iter()
        .zip(&dets)
        .map(|(m, d)| (m.as_str(), d.as_ref()))
        .collect();
    let bench = VideoBench {
        width: a.width,
        height: a.height,
        frames: a.frames,
        codecs: a.codecs.clone(),
    };
    let t = bench.run(&tools, &named, &device)?;
    print!("{}", t.markdown());
    cac::io::write_atomic(&a.csv, t.csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}
