//! Resume for long evaluations: each finished texture's records and example views are kept in a
//! cache folder under a key made of everything that decides them (object, render settings,
//! environment, views, protocol, models, texels); a rerun with the same key reuses them.
//!
//! A shard of a sharded evaluation ([`super::shard`]) keeps its part of a texture in a file of its
//! own, `NAME.shard-K-of-N.json` (with its example PNGs), so shards running at once on several
//! machines never write the same file; every file is written to a temporary sibling and renamed.

use super::run::{Example, ImageRecord, TextureResult};
use anyhow::{Context, Result};
use cac_detect::{labels::COCO80, Detection};
use cac_render::environment::{Brightness, ViewpointSet};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// SHA-256 (hex) over a settings value and the atlas texels.
pub fn key(settings: &impl Serialize, texels: &[[f32; 3]]) -> String {
    let mut h = Sha256::new();
    h.update(serde_json::to_vec(settings).unwrap_or_default());
    for t in texels {
        for c in t {
            h.update(c.to_le_bytes());
        }
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

#[derive(Serialize, Deserialize)]
struct Stored {
    key: String,
    /// `(K, N)` for a shard's part, absent for a whole texture.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    shard: Option<(usize, usize)>,
    /// The shard's views, `(group index, view index)`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    views: Vec<(usize, usize)>,
    records: Vec<ImageRecord>,
    skipped: usize,
    examples: Vec<StoredExample>,
}

#[derive(Serialize, Deserialize)]
struct StoredExample {
    set: ViewpointSet,
    brightness: Brightness,
    view: usize,
    gt: [f32; 4],
    /// Per model: (class id, score, box).
    detections: Vec<Vec<(usize, f32, [f32; 4])>>,
    /// Per model, the detections' labels, where a model's are not COCO-80's (its own classes).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    labels: Vec<Vec<String>>,
}

/// The labels of `ds` where one is not the COCO-80 label of its id (a model's own classes).
fn own_labels(detections: &[Vec<Detection>]) -> Vec<Vec<String>> {
    let coco = |d: &Detection| COCO80.get(d.class_id) == Some(&d.label);
    if detections.iter().flatten().all(coco) {
        return vec![];
    }
    detections
        .iter()
        .map(|ds| ds.iter().map(|d| d.label.to_string()).collect())
        .collect()
}

/// A stored label as a detection's `&'static str` (COCO labels without allocating).
fn static_label(l: &str) -> &'static str {
    match COCO80.iter().find(|c| **c == l) {
        Some(c) => c,
        None => Box::leak(l.to_string().into_boxed_str()),
    }
}

/// The file-name stem of a texture's cache files (letters and digits, others as `_`).
pub(crate) fn safe_name(name: &str) -> String {
    name.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

/// The stem of shard `k` of `n` of a texture: `NAME.shard-K-of-N`.
pub(crate) fn shard_stem(name: &str, k: usize, n: usize) -> String {
    format!("{}.shard-{k}-of-{n}", safe_name(name))
}

fn json_path(dir: &Path, stem: &str) -> PathBuf {
    dir.join(format!("{stem}.json"))
}

fn example_path(dir: &Path, stem: &str, k: usize) -> PathBuf {
    dir.join(format!("{stem}.ex{k}.png"))
}

/// Writes one texture's result (JSON and example PNGs), atomically.
pub fn store(dir: &Path, name: &str, key: &str, r: &TextureResult) -> Result<()> {
    store_stem(dir, &safe_name(name), key, None, vec![], r).map(|_| ())
}

/// Writes shard `k` of `n`'s part of a texture (its `views`), atomically, into its own file;
/// returns the JSON file's path.
pub(crate) fn store_shard(
    dir: &Path,
    name: &str,
    key: &str,
    (k, n): (usize, usize),
    views: &[(usize, usize)],
    r: &TextureResult,
) -> Result<PathBuf> {
    store_stem(
        dir,
        &shard_stem(name, k, n),
        key,
        Some((k, n)),
        views.to_vec(),
        r,
    )
}

fn store_stem(
    dir: &Path,
    stem: &str,
    key: &str,
    shard: Option<(usize, usize)>,
    views: Vec<(usize, usize)>,
    r: &TextureResult,
) -> Result<PathBuf> {
    // Examples first, the JSON last: a JSON file in place means its examples are complete.
    for (k, e) in r.examples.iter().enumerate() {
        cac_core::io::save_png_atomic(&example_path(dir, stem, k), &e.image)?;
    }
    let st = Stored {
        key: key.into(),
        shard,
        views,
        records: r.records.clone(),
        skipped: r.skipped,
        examples: r
            .examples
            .iter()
            .map(|e| StoredExample {
                set: e.set,
                brightness: e.brightness,
                view: e.view,
                gt: e.gt,
                detections: e
                    .detections
                    .iter()
                    .map(|ds| ds.iter().map(|d| (d.class_id, d.score, d.bbox)).collect())
                    .collect(),
                labels: own_labels(&e.detections),
            })
            .collect(),
    };
    let path = json_path(dir, stem);
    cac_core::io::write_atomic(&path, &serde_json::to_vec(&st)?)?;
    Ok(path)
}

/// The stored result of `name` if its key matches (None when absent or stale).
pub fn load(dir: &Path, name: &str, key: &str) -> Result<Option<TextureResult>> {
    let stem = safe_name(name);
    let Ok(bytes) = std::fs::read(json_path(dir, &stem)) else {
        return Ok(None);
    };
    let st: Stored = match serde_json::from_slice(&bytes) {
        Ok(st) => st,
        Err(_) => return Ok(None),
    };
    if st.key != key || st.shard.is_some() {
        return Ok(None);
    }
    Ok(Some(restore(dir, &stem, st)?))
}

/// One shard's stored part of a texture.
pub struct ShardPart {
    /// The JSON file it was read from.
    pub path: PathBuf,
    pub key: String,
    /// `(K, N)`: shard K of N.
    pub shard: (usize, usize),
    pub views: Vec<(usize, usize)>,
    pub result: TextureResult,
}

/// The shard files of texture `name` in `dir` (`NAME.shard-*.json`), sorted by name.
pub(crate) fn shard_files(dir: &Path, name: &str) -> Result<Vec<PathBuf>> {
    let prefix = format!("{}.shard-", safe_name(name));
    let rd = match std::fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(vec![]),
        Err(e) => return Err(e).with_context(|| format!("cannot list {}", dir.display())),
    };
    let mut out = vec![];
    for e in rd {
        let e = e.with_context(|| format!("cannot list {}", dir.display()))?;
        let f = e.file_name().to_string_lossy().into_owned();
        if f.starts_with(&prefix) && f.ends_with(".json") {
            out.push(e.path());
        }
    }
    out.sort();
    Ok(out)
}

/// The shard's stored part whose key matches `key` (None when absent, unreadable or stale).
pub(crate) fn load_shard(
    dir: &Path,
    name: &str,
    key: &str,
    (k, n): (usize, usize),
) -> Result<Option<TextureResult>> {
    let path = json_path(dir, &shard_stem(name, k, n));
    if !path.exists() {
        return Ok(None);
    }
    match read_shard(&path) {
        Ok(p) if p.key == key && p.shard == (k, n) => Ok(Some(p.result)),
        _ => Ok(None),
    }
}

/// Reads a shard file's number, key and views, not its examples (errors name the file).
pub(crate) fn read_shard_header(path: &Path) -> Result<ShardHeader> {
    let st = read_stored(path)?;
    Ok(ShardHeader {
        path: path.to_path_buf(),
        key: st.key,
        shard: st
            .shard
            .with_context(|| format!("{} holds no shard number", path.display()))?,
        views: st.views,
    })
}

/// A shard file's identity: which shard, written with which settings, covering which views.
pub(crate) struct ShardHeader {
    pub path: PathBuf,
    pub key: String,
    /// `(K, N)`: shard K of N.
    pub shard: (usize, usize),
    pub views: Vec<(usize, usize)>,
}

fn read_stored(path: &Path) -> Result<Stored> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_slice(&bytes)
        .with_context(|| format!("{} is not a readable shard file", path.display()))
}

/// Reads a shard file with its example views (errors name the file).
pub fn read_shard(path: &Path) -> Result<ShardPart> {
    let st = read_stored(path)?;
    let shard = st
        .shard
        .with_context(|| format!("{} holds no shard number", path.display()))?;
    let f = path.file_name().unwrap_or_default().to_string_lossy();
    let stem = f.strip_suffix(".json").unwrap_or(&f).to_string();
    let dir = path.parent().unwrap_or(Path::new("."));
    let (key, views) = (st.key.clone(), st.views.clone());
    let result =
        restore(dir, &stem, st).with_context(|| format!("shard file {}", path.display()))?;
    Ok(ShardPart {
        path: path.to_path_buf(),
        key,
        shard,
        views,
        result,
    })
}

fn restore(dir: &Path, stem: &str, st: Stored) -> Result<TextureResult> {
    let mut examples = vec![];
    for (k, e) in st.examples.into_iter().enumerate() {
        let p = example_path(dir, stem, k);
        let image = cac_core::io::load_rgb(&p).context("cached example view")?;
        examples.push(Example {
            set: e.set,
            brightness: e.brightness,
            view: e.view,
            image,
            gt: e.gt,
            detections: e
                .detections
                .into_iter()
                .enumerate()
                .map(|(m, ds)| {
                    ds.into_iter()
                        .enumerate()
                        .map(|(k, (c, score, bbox))| Detection {
                            class_id: c,
                            label: match e.labels.get(m).and_then(|l| l.get(k)) {
                                Some(l) => static_label(l),
                                None => COCO80[c.min(79)],
                            },
                            score,
                            bbox,
                        })
                        .collect()
                })
                .collect(),
        });
    }
    Ok(TextureResult {
        records: st.records,
        skipped: st.skipped,
        examples,
    })
}
