//! A training run's checkpoint: everything needed to continue it exactly (iteration, optimiser
//! state, parameters, log), in `RUN/checkpoint/`.
//!
//! The metadata is `state.json` through serde ([`Checkpoint`] and [`Adam`] derive it); the three
//! arrays (parameters, Adam's first and second moments) sit beside it as little-endian `.f32`
//! files, so a 512² atlas is not a megabyte of JSON numbers. A checkpoint is written into a new
//! folder that is then renamed into place, so a crash leaves the previous one whole
//! (`checkpoint.old` is read when `checkpoint` is missing). Checkpoints written before the
//! multi-scale parameterisation (no `scales`) read as one level. Not here: the run folder
//! ([`super::run`]) or the trainer ([`super::trainer`]).

use super::adam::Adam;
use super::pyramid;
use crate::iteration::IterationLog;
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Everything needed to continue a run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Checkpoint {
    pub iteration: usize,
    /// Side of the parameters' finest level: the atlas, or the patch of a 2D method.
    pub atlas_res: usize,
    /// Levels of the parameterisation: `atlas` holds all of them ([`pyramid`]); 1 for a plain
    /// atlas and for 2D patches.
    #[serde(default = "one_level")]
    pub scales: usize,
    /// Trained through a printer's filaments ([`super::filaments`]): how many parameters `atlas`
    /// holds (a logit per filament and region); 0 otherwise.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub filament_params: usize,
    /// Adam's state; its moments are stored beside the metadata (`adam_m.f32`, `adam_v.f32`).
    pub adam: Adam,
    /// The optimised parameters: the atlas itself (row-major RGB) when `scales` is 1. Stored
    /// beside the metadata (`atlas.f32`).
    #[serde(skip)]
    pub atlas: Vec<f32>,
    pub log: Vec<IterationLog>,
}

fn one_level() -> usize {
    1
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

const CHECKPOINT: &str = "checkpoint";
const OLD: &str = "checkpoint.old";

/// Writes the checkpoint into `run_dir/checkpoint/` atomically (a new folder renamed into place).
pub fn save(run_dir: &Path, ck: &Checkpoint) -> Result<()> {
    std::fs::create_dir_all(run_dir)
        .with_context(|| format!("cannot create run folder {}", run_dir.display()))?;
    let tmp = run_dir.join(format!("{CHECKPOINT}.tmp"));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp)?;
    let bin = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    cac_core::io::write_atomic(&tmp.join("atlas.f32"), &bin(&ck.atlas))?;
    cac_core::io::write_atomic(&tmp.join("adam_m.f32"), &bin(&ck.adam.m))?;
    cac_core::io::write_atomic(&tmp.join("adam_v.f32"), &bin(&ck.adam.v))?;
    cac_core::io::write_atomic(
        &tmp.join("state.json"),
        serde_json::to_string(ck)?.as_bytes(),
    )?;
    let dst = run_dir.join(CHECKPOINT);
    let old = run_dir.join(OLD);
    let _ = std::fs::remove_dir_all(&old);
    if dst.exists() {
        std::fs::rename(&dst, &old)?;
    }
    std::fs::rename(&tmp, &dst)?;
    let _ = std::fs::remove_dir_all(&old);
    Ok(())
}

/// Whether `run_dir` holds a complete checkpoint.
pub fn exists(run_dir: &Path) -> bool {
    [CHECKPOINT, OLD]
        .iter()
        .any(|n| run_dir.join(n).join("state.json").is_file())
}

/// Reads the newest complete checkpoint of a run folder.
pub fn load(run_dir: &Path) -> Result<Checkpoint> {
    let dir = [CHECKPOINT, OLD]
        .iter()
        .map(|n| run_dir.join(n))
        .find(|d| d.join("state.json").is_file())
        .with_context(|| format!("{} holds no checkpoint to resume from", run_dir.display()))?;
    let mut ck: Checkpoint = serde_json::from_slice(&std::fs::read(dir.join("state.json"))?)
        .with_context(|| format!("{}: malformed checkpoint state", dir.display()))?;
    let f32s = |name: &str| -> Result<Vec<f32>> {
        let b = std::fs::read(dir.join(name))
            .with_context(|| format!("{}: missing {name}", dir.display()))?;
        if b.len() % 4 != 0 {
            bail!("{}: {name} is truncated", dir.display());
        }
        Ok(b.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    };
    let (res, scales) = (ck.atlas_res, ck.scales);
    if !(1..=8).contains(&scales) {
        bail!(
            "{}: checkpoint has {scales} atlas levels (1..=8)",
            dir.display()
        );
    }
    ck.atlas = f32s("atlas.f32")?;
    (ck.adam.m, ck.adam.v) = (f32s("adam_m.f32")?, f32s("adam_v.f32")?);
    let want = match ck.filament_params {
        0 => pyramid::len(res, scales),
        n => n,
    };
    if ck.atlas.len() != want || ck.adam.m.len() != want || ck.adam.v.len() != want {
        bail!(
            "{}: checkpoint arrays do not match a {res}² atlas in {scales} level(s)",
            dir.display()
        );
    }
    Ok(ck)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(scales: usize) -> Checkpoint {
        let n = pyramid::len(8, scales);
        let mut adam = Adam::new(n, 0.02);
        adam.t = 3;
        adam.m = (0..n).map(|i| i as f32 * 0.25).collect();
        adam.v = (0..n).map(|i| 1.0 / (i + 1) as f32).collect();
        Checkpoint {
            iteration: 3,
            atlas_res: 8,
            scales,
            filament_params: 0,
            adam,
            atlas: (0..n).map(|i| (i % 7) as f32 / 7.0).collect(),
            log: vec![],
        }
    }

    #[test]
    fn a_checkpoint_reads_back_exactly() {
        let dir = tempfile::tempdir().unwrap();
        assert!(!exists(dir.path()));
        let ck = sample(2);
        save(dir.path(), &ck).unwrap();
        assert!(exists(dir.path()));
        let back = load(dir.path()).unwrap();
        assert_eq!((back.iteration, back.atlas_res, back.scales), (3, 8, 2));
        assert_eq!(back.adam, ck.adam);
        assert_eq!(back.atlas, ck.atlas);
    }

    #[test]
    fn a_checkpoint_without_scales_reads_as_one_level() {
        let dir = tempfile::tempdir().unwrap();
        save(dir.path(), &sample(1)).unwrap();
        // The metadata as checkpoints before the multi-scale parameterisation wrote it.
        let state = dir.path().join("checkpoint/state.json");
        let old = r#"{"adam":{"beta1":0.8999999761581421,"beta2":0.9990000128746033,
            "eps":9.99999993922529e-9,"lr":0.019999999552965164,"t":3},"atlas_res":8,
            "iteration":3,"log":[]}"#;
        std::fs::write(&state, old).unwrap();
        let back = load(dir.path()).unwrap();
        assert_eq!(back.scales, 1);
        assert_eq!(back.adam.lr, 0.02f32);
        assert_eq!(back.adam.beta1, 0.9f32);
        assert_eq!(back.adam.eps, 1e-8f32);
        assert_eq!(back.atlas, sample(1).atlas);
        // Arrays of another shape are refused.
        std::fs::write(&state, old.replace("\"atlas_res\":8", "\"atlas_res\":4")).unwrap();
        let e = load(dir.path()).unwrap_err().to_string();
        assert!(e.contains("do not match"), "{e}");
    }
}
