//! The capture manifest: one JSON line per captured frame, appended with a single write and
//! synced, so a kill leaves at worst one partial last line — which [`Manifest::open`] detects,
//! reports and cuts off.

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

/// One captured frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    /// Image file, relative to the session folder.
    pub frame: String,
    /// Table angle (degrees) and distance ratio as planned.
    pub angle: f64,
    pub ratio: f64,
    /// Repeat number, from 0.
    pub repeat: usize,
    /// Seconds since the Unix epoch when the frame was taken.
    pub timestamp: f64,
    /// The turntable's state when the frame was taken (position, move sequence number, driver
    /// counters, rail position).
    pub device: serde_json::Value,
    /// The camera's description of the frame.
    pub camera: String,
    /// What the camera recovered from on the way to this frame (corrupt frames dropped, a
    /// stalled stream restarted, the device reopened); absent when nothing happened.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub camera_events: Vec<String>,
}

impl Entry {
    /// The frame's key in the plan.
    pub fn key(&self) -> (String, usize) {
        (key_of(self.ratio, self.angle), self.repeat)
    }
}

/// `(ratio, angle)` as a stable string key (6 decimals).
pub fn key_of(ratio: f64, angle: f64) -> String {
    format!("{ratio:.6}@{angle:.6}")
}

/// An open manifest, appending.
pub struct Manifest {
    path: PathBuf,
    file: File,
}

/// What [`Manifest::open`] found.
pub struct Loaded {
    pub manifest: Manifest,
    pub entries: Vec<Entry>,
    /// Bytes of a partial last line that were cut off (0 = none).
    pub dropped_bytes: usize,
}

impl Manifest {
    /// Opens (creating) `path`, reads its complete lines, and truncates a partial last line.
    /// A complete line that does not parse is an error naming the line.
    pub fn open(path: &Path) -> Result<Loaded> {
        let text = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(e) => {
                return Err(e).with_context(|| format!("cannot read manifest {}", path.display()))
            }
        };
        let complete = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        let dropped_bytes = text.len() - complete;
        let mut entries = Vec::new();
        for (i, line) in text[..complete].split(|&b| b == b'\n').enumerate() {
            if line.is_empty() {
                continue;
            }
            let e: Entry = serde_json::from_slice(line).with_context(|| {
                format!(
                    "manifest {} line {}: not a frame record",
                    path.display(),
                    i + 1
                )
            })?;
            entries.push(e);
        }
        if dropped_bytes > 0 {
            let f = OpenOptions::new()
                .write(true)
                .open(path)
                .with_context(|| format!("cannot repair manifest {}", path.display()))?;
            f.set_len(complete as u64)
                .and_then(|_| f.sync_all())
                .with_context(|| {
                    format!("cannot cut the partial last line of {}", path.display())
                })?;
        }
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("cannot open manifest {} for appending", path.display()))?;
        Ok(Loaded {
            manifest: Manifest {
                path: path.to_path_buf(),
                file,
            },
            entries,
            dropped_bytes,
        })
    }

    /// Appends one entry as a single write, then syncs.
    pub fn append(&mut self, e: &Entry) -> Result<()> {
        let mut line = serde_json::to_vec(e)?;
        if line.contains(&b'\n') {
            bail!("manifest entry serialised with a newline");
        }
        line.push(b'\n');
        self.file
            .write_all(&line)
            .and_then(|_| self.file.sync_data())
            .with_context(|| format!("cannot append to manifest {}", self.path.display()))
    }
}

/// Reads a manifest without repairing it (for scoring): complete lines only.
pub fn read(path: &Path) -> Result<Vec<Entry>> {
    let text =
        std::fs::read(path).with_context(|| format!("cannot read manifest {}", path.display()))?;
    let complete = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    text[..complete]
        .split(|&b| b == b'\n')
        .enumerate()
        .filter(|(_, l)| !l.is_empty())
        .map(|(i, l)| {
            serde_json::from_slice(l).with_context(|| {
                format!(
                    "manifest {} line {}: not a frame record",
                    path.display(),
                    i + 1
                )
            })
        })
        .collect()
}
