//! onnxruntime as the forward engine of a user's ONNX detector where no gradient is asked for
//! ([`crate::detector::Detector::detect`]: evaluation, scoring of captures and videos, `cac detect`).
//!
//! onnxruntime is what users compare a detector's forward with, and it fuses what an eager
//! executor cannot (convolution with its bias and activation, NCHWc layouts). It comes in through
//! the `ort` crate in its `load-dynamic` mode: nothing is linked or downloaded at build time, and
//! the shared library of the runtime users already have (pip's `onnxruntime` wheel ships
//! `onnxruntime/capi/libonnxruntime.so.*`) is opened when the edge asks for it ([`enable`]; the
//! command line's `CAC_ONNXRUNTIME=PATH|auto`). Gradients always run on cac's own executor
//! ([`super::graph`]), and so do a head the file does not export (cut out before a selection
//! inside the file) and a file whose input or head is not f32. A session per rayon pool size, as
//! libtorch's thread count follows that pool.

use anyhow::{anyhow, bail, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The runtime library that [`enable`] opened, if any.
static LIBRARY: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();

/// The library [`enable`] opened; `None` until then (the ONNX detectors then run on cac's
/// executor alone).
pub fn enabled() -> Option<&'static Path> {
    LIBRARY.get().map(PathBuf::as_path)
}

/// The onnxruntime library inside the `onnxruntime` package of `python`, if it has one.
pub fn find_in_python(python: &str) -> Option<PathBuf> {
    let out = Command::new(python)
        .args([
            "-c",
            "import onnxruntime, os; print(os.path.join(os.path.dirname(onnxruntime.__file__), 'capi'))",
        ])
        .output()
        .ok()?;
    let dir = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
    let mut libs: Vec<PathBuf> = std::fs::read_dir(&dir)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name().and_then(|n| n.to_str()).is_some_and(|n| {
                n.starts_with("libonnxruntime.so")
                    || (n.starts_with("libonnxruntime") && n.ends_with(".dylib"))
                    || n == "onnxruntime.dll"
            })
        })
        .collect();
    // `libonnxruntime.so.1.32.0` before a bare `libonnxruntime.so` link, if both are there.
    libs.sort_by_key(|p| std::cmp::Reverse(p.as_os_str().len()));
    libs.into_iter().next()
}

/// Opens the onnxruntime shared library at `library` (or, for `auto`, the one of `python3`'s
/// `onnxruntime` package) for every ONNX detector loaded after this call. Once per process: a
/// second call with the same library is a no-op, with another one an error.
pub fn enable(library: &str) -> Result<&'static Path> {
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let path = match library {
        "auto" => find_in_python("python3").ok_or_else(|| {
            anyhow!(
                "python3 has no onnxruntime package with a shared library (pip install \
                 onnxruntime), so `auto` finds none: name the library file instead"
            )
        })?,
        p => PathBuf::from(p),
    };
    if !path.is_file() {
        bail!("{}: no such onnxruntime library file", path.display());
    }
    if let Some(open) = enabled() {
        if open == path {
            return Ok(open);
        }
        bail!(
            "{}: onnxruntime is already open from {} in this process",
            path.display(),
            open.display()
        );
    }
    imp::open(&path)?;
    Ok(LIBRARY.get_or_init(|| path))
}

/// One ONNX file in onnxruntime, with a session per thread count of the rayon pool it runs in
/// (the benchmark's rows change it). Runs on one detector are serialised.
pub struct Session {
    file: PathBuf,
    input: String,
    outputs: Vec<String>,
    inner: imp::Inner,
}

impl Session {
    /// `file`'s session that feeds `input` and returns `outputs`, or `None` where these are not
    /// all f32 tensors (an fp16 export: cac's executor runs it in f32). Fails naming the file
    /// when the runtime is not enabled, refuses the file, or the file lacks one of the names.
    pub fn open(file: &Path, input: &str, outputs: &[&str]) -> Result<Option<Self>> {
        if enabled().is_none() {
            bail!(
                "{}: onnxruntime is not enabled (CAC_ONNXRUNTIME)",
                file.display()
            );
        }
        // `Inner` is a unit struct when the crate is built without onnxruntime.
        #[allow(clippy::default_constructed_unit_structs)]
        let s = Session {
            file: file.to_path_buf(),
            input: input.to_string(),
            outputs: outputs.iter().map(|s| s.to_string()).collect(),
            inner: imp::Inner::default(),
        };
        let f32_io = s.inner.check(&s.file, &s.input, &s.outputs)?;
        Ok(f32_io.then_some(s))
    }

    /// The outputs (shape, values) in the order given to [`Session::open`], for the input
    /// `values` of `shape` (row-major f32).
    pub fn run(&self, values: Vec<f32>, shape: &[usize]) -> Result<Vec<(Vec<usize>, Vec<f32>)>> {
        self.inner
            .run(&self.file, &self.input, &self.outputs, values, shape)
    }
}

#[cfg(feature = "onnxruntime")]
mod imp {
    use anyhow::{anyhow, bail, Context, Result};
    use ort::session::builder::GraphOptimizationLevel;
    use ort::session::Session;
    use ort::value::{Tensor, TensorElementType};
    use std::path::Path;
    use std::sync::Mutex;

    static ENVIRONMENT: std::sync::OnceLock<ort::environment::Environment> =
        std::sync::OnceLock::new();

    pub(super) fn open(path: &Path) -> Result<()> {
        if ENVIRONMENT.get().is_some() {
            bail!(
                "{}: onnxruntime is already open in this process",
                path.display()
            );
        }
        let env = ort::init_from(path)
            .map_err(|e| anyhow!("{}: cannot load onnxruntime: {e}", path.display()))?
            .with_name("cac")
            .build()
            .map_err(|e| anyhow!("{}: onnxruntime: {e}", path.display()))?;
        let _ = ENVIRONMENT.set(env);
        Ok(())
    }

    /// The sessions, with the thread count each was built for.
    #[derive(Default)]
    pub(super) struct Inner(Mutex<Vec<(usize, Session)>>);

    fn build(file: &Path, threads: usize) -> Result<Session> {
        let env = ENVIRONMENT
            .get()
            .ok_or_else(|| anyhow!("{}: onnxruntime is not enabled", file.display()))?;
        let err = |e: ort::Error<_>| anyhow!("{}: onnxruntime: {e}", file.display());
        Session::builder(env)
            .map_err(|e| anyhow!("{}: onnxruntime: {e}", file.display()))?
            .with_optimization_level(GraphOptimizationLevel::All)
            .map_err(err)?
            .with_intra_threads(threads)
            .map_err(err)?
            .with_inter_threads(1)
            .map_err(err)?
            // Its threads spin while a run is on (its speed) and stop when it returns: they would
            // otherwise spin on after it, on the cores the renderer needs next.
            .with_config_entry("session.force_spinning_stop", "1")
            .map_err(err)?
            .commit_from_file(file)
            .map_err(|e| {
                anyhow!(
                    "{}: onnxruntime refuses the file: {e} (without onnxruntime enabled, \
                     cac's own executor runs it)",
                    file.display()
                )
            })
    }

    impl Inner {
        /// Whether `input` and `outputs` are all f32 tensors; fails where one is missing.
        pub(super) fn check(&self, file: &Path, input: &str, outputs: &[String]) -> Result<bool> {
            let threads = rayon::current_num_threads();
            let s = build(file, threads)?;
            let f32 =
                |t: &ort::value::ValueType| t.tensor_type() == Some(TensorElementType::Float32);
            let Some(i) = s.inputs().iter().find(|i| i.name() == input) else {
                bail!("{}: onnxruntime sees no input {input:?}", file.display());
            };
            let mut all_f32 = f32(i.dtype());
            for o in outputs {
                let Some(x) = s.outputs().iter().find(|x| x.name() == o) else {
                    bail!("{}: {o:?} is not an output of the file", file.display());
                };
                all_f32 &= f32(x.dtype());
            }
            self.0
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .push((threads, s));
            Ok(all_f32)
        }

        pub(super) fn run(
            &self,
            file: &Path,
            input: &str,
            outputs: &[String],
            values: Vec<f32>,
            shape: &[usize],
        ) -> Result<Vec<(Vec<usize>, Vec<f32>)>> {
            let threads = rayon::current_num_threads();
            let mut sessions = self.0.lock().unwrap_or_else(|e| e.into_inner());
            let at = match sessions.iter().position(|(t, _)| *t == threads) {
                Some(at) => at,
                None => {
                    sessions.push((threads, build(file, threads)?));
                    sessions.len() - 1
                }
            };
            let session = &mut sessions[at].1;
            let dims: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
            let x = Tensor::from_array((dims, values))
                .map_err(|e| anyhow!("{}: onnxruntime input: {e}", file.display()))?;
            let out = session
                .run(ort::inputs![input => x])
                .map_err(|e| anyhow!("{}: onnxruntime: {e}", file.display()))?;
            outputs
                .iter()
                .map(|name| {
                    let v = out
                        .get(name)
                        .with_context(|| format!("{}: no output {name:?}", file.display()))?;
                    let (s, data) = v.try_extract_tensor::<f32>().map_err(|e| {
                        anyhow!("{}: output {name:?} is not f32: {e}", file.display())
                    })?;
                    let dims = s.iter().map(|&d| d as usize).collect();
                    Ok((dims, data.to_vec()))
                })
                .collect()
        }
    }
}

#[cfg(not(feature = "onnxruntime"))]
mod imp {
    use anyhow::{bail, Result};
    use std::path::Path;

    pub(super) fn open(path: &Path) -> Result<()> {
        bail!(
            "{}: this build has no onnxruntime engine (build with --features onnxruntime)",
            path.display()
        )
    }

    #[derive(Default)]
    pub(super) struct Inner;

    impl Inner {
        pub(super) fn check(&self, file: &Path, _: &str, _: &[String]) -> Result<bool> {
            bail!("{}: onnxruntime is not in this build", file.display())
        }
        pub(super) fn run(
            &self,
            file: &Path,
            _: &str,
            _: &[String],
            _: Vec<f32>,
            _: &[usize],
        ) -> Result<Vec<(Vec<usize>, Vec<f32>)>> {
            bail!("{}: onnxruntime is not in this build", file.display())
        }
    }
}
