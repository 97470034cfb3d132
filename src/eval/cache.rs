//! Resume for long evaluations: each finished texture's records and example views are kept in a
//! cache folder under a key made of everything that decides them (object, render settings,
//! environment, views, protocol, models, texels); a rerun with the same key reuses them.

use super::run::{Example, ImageRecord, TextureResult};
use crate::detect::{labels::COCO80, Detection};
use crate::environment::{Brightness, ViewpointSet};
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::Path;

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
}

fn stem(dir: &Path, name: &str) -> std::path::PathBuf {
    let safe: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    dir.join(safe)
}

/// Writes one texture's result (JSON and example PNGs), atomically.
pub fn store(dir: &Path, name: &str, key: &str, r: &TextureResult) -> Result<()> {
    let s = stem(dir, name);
    for (k, e) in r.examples.iter().enumerate() {
        crate::io::save_png_atomic(&s.with_extension(format!("ex{k}.png")), &e.image)?;
    }
    let st = Stored {
        key: key.into(),
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
            })
            .collect(),
    };
    crate::io::write_atomic(&s.with_extension("json"), &serde_json::to_vec(&st)?)
}

/// The stored result of `name` if its key matches (None when absent or stale).
pub fn load(dir: &Path, name: &str, key: &str) -> Result<Option<TextureResult>> {
    let s = stem(dir, name);
    let Ok(bytes) = std::fs::read(s.with_extension("json")) else {
        return Ok(None);
    };
    let st: Stored = match serde_json::from_slice(&bytes) {
        Ok(st) => st,
        Err(_) => return Ok(None),
    };
    if st.key != key {
        return Ok(None);
    }
    let mut examples = vec![];
    for (k, e) in st.examples.into_iter().enumerate() {
        let p = s.with_extension(format!("ex{k}.png"));
        let image = crate::io::load_rgb(&p).context("cached example view")?;
        examples.push(Example {
            set: e.set,
            brightness: e.brightness,
            view: e.view,
            image,
            gt: e.gt,
            detections: e
                .detections
                .into_iter()
                .map(|ds| {
                    ds.into_iter()
                        .map(|(c, score, bbox)| Detection {
                            class_id: c,
                            label: COCO80[c.min(79)],
                            score,
                            bbox,
                        })
                        .collect()
                })
                .collect(),
        });
    }
    Ok(Some(TextureResult {
        records: st.records,
        skipped: st.skipped,
        examples,
    }))
}
