//! `cac bench detect`: forward and forward+backward time of both detectors at native
//! resolution, batch 1 and 4, and the TFJS reference runner's wasm backend timed in the same
//! run; then the Faster R-CNN models against PyTorch ([`super::frcnn`]); with `--onnx`, users'
//! ONNX detectors against onnxruntime and PyTorch (onnx2torch) at the same thread counts. Prints tables and writes
//! CSVs. A benchmark, not a test: it asserts nothing. Measured by `cac::bench::detect`.

use crate::cli::device;
use anyhow::Result;
use cac::bench::detect as bench;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct DetectBench {
    /// Timed runs per measurement (after one warm-up run).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// CSV output file.
    #[arg(long, default_value = "bench-detect.csv")]
    pub csv: PathBuf,
    /// Installed TFJS reference runner folder (default: $CAC_TFJS_RUNNER, else target/tfjsref).
    #[arg(long)]
    pub runner: Option<PathBuf>,
    /// Image for the TFJS runner (default: a reference image from ../shared, else a noise PNG).
    #[arg(long)]
    pub image: Option<PathBuf>,
    /// Only the Faster R-CNN models (skip CenterNet and NanoDet).
    #[arg(long)]
    pub frcnn_only: bool,
    /// Skip the Faster R-CNN models.
    #[arg(long)]
    pub no_frcnn: bool,
    /// Only the --onnx models.
    #[arg(long)]
    pub onnx_only: bool,
    /// Python with torch + torchvision for the PyTorch columns of the Faster R-CNN table.
    #[arg(long, default_value = "python3")]
    pub python: String,
    /// CSV output file of the Faster R-CNN table.
    #[arg(long, default_value = "bench-detect-frcnn.csv")]
    pub frcnn_csv: PathBuf,
    /// Your ONNX detectors (MODEL.onnx[:CONFIG.toml], comma-separated), timed beside
    /// onnxruntime (run by --python, same thread count).
    #[arg(long, value_delimiter = ',')]
    pub onnx: Vec<String>,
    /// Thread counts for the ONNX table (comma-separated; default: rayon's pool size), the
    /// same for cac, onnxruntime and PyTorch.
    #[arg(long, value_delimiter = ',')]
    pub threads: Vec<usize>,
    /// CSV output file of the ONNX table.
    #[arg(long, default_value = "bench-detect-onnx.csv")]
    pub onnx_csv: PathBuf,
    /// Backends to time side by side (comma-separated: flex, libtorch, cuda, gpu; default: the
    /// one CAC_DEVICE names, else every CPU backend of this build).
    #[arg(long, value_delimiter = ',')]
    pub backends: Vec<String>,
}

pub fn run(a: DetectBench) -> Result<()> {
    if !a.onnx.is_empty() {
        bench_onnx(&a)?;
        if a.onnx_only {
            return Ok(());
        }
    }
    if !a.frcnn_only {
        bench_tfjs(&a)?;
    }
    if !a.no_frcnn {
        let t = super::frcnn::bench(a.runs, &a.python, &super::backends(&a.backends)?)?;
        cac::io::write_atomic(&a.frcnn_csv, t.csv().as_bytes())?;
        println!("wrote {}", a.frcnn_csv.display());
    }
    Ok(())
}

fn bench_tfjs(a: &DetectBench) -> Result<()> {
    let backends = super::backends(&a.backends)?;
    let runner =
        (a.runner.clone()).or_else(|| std::env::var_os("CAC_TFJS_RUNNER").map(PathBuf::from));
    let (runner, image) = (runner.as_deref(), a.image.as_deref());
    let rows = bench::tfjs_models(runner, image, a.runs, &backends, &mut |t| {
        print!("{}", t.markdown_last())
    })?;
    cac::io::write_atomic(&a.csv, rows.csv().as_bytes())?;
    println!("wrote {}", a.csv.display());
    Ok(())
}

fn bench_onnx(a: &DetectBench) -> Result<()> {
    let counts = match a.threads.is_empty() {
        true => vec![rayon::current_num_threads()],
        false => a.threads.clone(),
    };
    let backends = super::backends(&a.backends)?;
    // `detect` with onnxruntime running the graph, beside cac's executor: the library of
    // CAC_ONNXRUNTIME, else the one of --python's onnxruntime package.
    use cac::detect::onnx::runtime;
    if runtime::enabled().is_none() {
        if let Some(lib) = runtime::find_in_python(&a.python) {
            if let Err(e) = runtime::enable(&lib.display().to_string()) {
                eprintln!("detect_onnxruntime_ms n/a: {e:#}");
            }
        }
    }
    match runtime::enabled() {
        Some(lib) => println!("onnxruntime for detect: {}", lib.display()),
        None => println!("onnxruntime for detect: none (detect_onnxruntime_ms n/a)"),
    }
    let mut all: Option<cac::report::Table> = None;
    for threads in counts {
        println!(
            "{threads} threads: cac's backends, onnxruntime (CPU) and PyTorch (onnx2torch, CPU)"
        );
        device::set_threads(threads);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()?;
        let rows = pool.install(|| {
            bench::onnx_models(&a.onnx, a.runs, &a.python, threads, &backends, &mut |t| {
                print!("{}", t.markdown_last())
            })
        })?;
        match &mut all {
            Some(t) => t.rows.extend(rows.rows),
            None => all = Some(rows),
        }
    }
    let rows = all.expect("at least one thread count");
    cac::io::write_atomic(&a.onnx_csv, rows.csv().as_bytes())?;
    println!("wrote {}", a.onnx_csv.display());
    Ok(())
}
