//! A training run on disk: the run folder and the checkpointed loop that fills it.
//!
//! A run folder holds `run.json` (versions, the scene and attack settings, the iteration reached,
//! the per-iteration log, whether it finished: enough to reproduce the run), `atlas.png`,
//! `loss.png`, `views.png` (when finished), `patch.png` (2D methods) and `checkpoint/`
//! ([`super::checkpoint`]). [`RunDir`] creates one (refusing a folder that already holds a run),
//! opens one with its settings, or opens the one that matches given settings (all but
//! `iterations`, which may grow); [`RunDir::train`] runs the remaining iterations, checkpointing
//! every `checkpoint_every` and rewriting the folder. `cac train`, `cac demo` and `cac study`
//! all go through here. Not here: the optimiser ([`super::Trainer`]).

use super::{checkpoint, report, AttackConfig, IterationLog, Method, Trainer};
use anyhow::{bail, Context, Result};
use cac_render::config::SceneConfig;
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The burn version the run was made with (recorded in run.json).
const BURN_VERSION: &str = "0.22.1";

/// `run.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(crate) struct RunFile {
    #[serde(default)]
    pub cac_version: String,
    #[serde(default)]
    pub burn_version: String,
    #[serde(default)]
    pub finished: bool,
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub method: Method,
    pub attack: AttackConfig,
    pub scene: SceneConfig,
    #[serde(default)]
    pub iteration: usize,
    #[serde(default)]
    pub log: Vec<IterationLog>,
}

impl RunFile {
    /// Reads `dir/run.json`.
    pub fn read(dir: &Path) -> Result<RunFile> {
        let bytes = std::fs::read(dir.join("run.json"))
            .with_context(|| format!("{} is not a run folder (no run.json)", dir.display()))?;
        serde_json::from_slice(&bytes)
            .with_context(|| format!("{}: malformed run.json", dir.display()))
    }
}

/// A run folder and the settings of its run.
#[derive(Clone, Debug)]
pub struct RunDir {
    pub path: PathBuf,
    pub scene: SceneConfig,
    pub attack: AttackConfig,
    /// Resuming must find a checkpoint (a run opened to be continued); otherwise a folder without
    /// one starts from the beginning.
    must_resume: bool,
}

impl RunDir {
    /// A run of these settings in `path`, started over where it has no checkpoint.
    fn new(path: &Path, scene: SceneConfig, attack: AttackConfig) -> Result<RunDir> {
        attack.validate()?;
        Ok(RunDir {
            path: path.to_path_buf(),
            scene,
            attack,
            must_resume: false,
        })
    }

    /// A new run in `path` (created on the first write); refuses a folder that holds a run.
    pub fn create(path: &Path, scene: SceneConfig, attack: AttackConfig) -> Result<RunDir> {
        if path.join("run.json").exists() {
            bail!(
                "{} already holds a run: use --resume {} or another --out",
                path.display(),
                path.display()
            );
        }
        RunDir::new(path, scene, attack)
    }

    /// The run in `path` with the settings its run.json records; it continues from its last
    /// checkpoint.
    pub fn open(path: &Path) -> Result<RunDir> {
        let run = RunFile::read(path)?;
        Ok(RunDir {
            path: path.to_path_buf(),
            scene: run.scene,
            attack: run.attack,
            must_resume: true,
        })
    }

    /// The run in `path` for `scene` and `attack`: a new one where the folder holds none, the one
    /// there where its settings are these (but for `iterations`), and an error naming the
    /// settings that differ otherwise.
    pub(crate) fn open_or_create(
        path: &Path,
        scene: SceneConfig,
        attack: AttackConfig,
    ) -> Result<RunDir> {
        if !path.join("run.json").exists() {
            return RunDir::create(path, scene, attack);
        }
        let run = RunFile::read(path)?;
        // Iterations may grow; the hide classes matter only in hide mode (runs written before
        // the setting read as `all`, whatever today's default).
        let hide_classes = if run.attack.hide || attack.hide {
            run.attack.hide_classes.clone()
        } else {
            attack.hide_classes.clone()
        };
        let was = AttackConfig {
            iterations: attack.iterations,
            hide_classes,
            ..run.attack
        };
        let mut diff = differences(
            "attack",
            &serde_json::to_value(&was)?,
            &serde_json::to_value(&attack)?,
        );
        diff.extend(differences(
            "scene",
            &serde_json::to_value(&run.scene)?,
            &serde_json::to_value(&scene)?,
        ));
        if !diff.is_empty() {
            bail!(
                "{} holds a run with other settings ({}); remove it or pass another --out",
                path.display(),
                diff.join("; ")
            );
        }
        RunDir::new(path, scene, attack)
    }

    /// Whether the folder holds a checkpoint to continue from.
    pub(crate) fn has_checkpoint(&self) -> bool {
        checkpoint::exists(&self.path)
    }

    /// `tr` (made for this run's settings) continued from the folder's checkpoint where there is
    /// one; a run opened with [`RunDir::open`] must have one.
    pub fn resume<'a>(&self, tr: Trainer<'a>) -> Result<Trainer<'a>> {
        if self.must_resume || self.has_checkpoint() {
            tr.resume(&self.path)
        } else {
            Ok(tr)
        }
    }

    /// Runs the remaining iterations (up to `tr.config.iterations`) with a progress bar when
    /// `progress`, checkpointing every `checkpoint_every` iterations and at the end, and writes
    /// the folder before, at each checkpoint and when finished.
    pub fn train(&self, tr: &mut Trainer, progress: bool) -> Result<()> {
        std::fs::create_dir_all(&self.path)
            .with_context(|| format!("cannot create run folder {}", self.path.display()))?;
        let total = tr.config.iterations;
        let pb = if progress {
            ProgressBar::new(total as u64)
        } else {
            ProgressBar::hidden()
        };
        pb.set_style(
            ProgressStyle::with_template("{bar:30} {pos}/{len} iterations, loss {msg}, ETA {eta}")
                .expect("template"),
        );
        pb.set_position(tr.state.iteration as u64);
        self.write(tr, false)?;
        while tr.state.iteration < total {
            let log = tr.step()?;
            pb.set_message(format!("{:.4}", log.loss));
            pb.inc(1);
            let (k, it) = (tr.config.checkpoint_every, tr.state.iteration);
            if k > 0 && it % k == 0 && it < total {
                checkpoint::save(&self.path, &tr.state)?;
                self.write(tr, false)?;
            }
        }
        pb.finish_and_clear();
        checkpoint::save(&self.path, &tr.state)?;
        self.write(tr, true)
    }

    /// Writes run.json, atlas.png, the trainer's extra images and loss.png; views.png (rendered
    /// on the trainer's inner device) when `finished`.
    pub fn write(&self, tr: &Trainer, finished: bool) -> Result<()> {
        let run = RunFile {
            cac_version: env!("CARGO_PKG_VERSION").into(),
            burn_version: BURN_VERSION.into(),
            finished,
            seed: tr.config.seed,
            method: tr.config.method,
            attack: tr.config.clone(),
            scene: self.scene.clone(),
            iteration: tr.state.iteration,
            log: tr.state.log.clone(),
        };
        // Through a JSON value: its keys are written sorted, as run.json always had them.
        let json = serde_json::to_string_pretty(&serde_json::to_value(&run)?)?;
        cac_core::io::write_atomic(&self.path.join("run.json"), json.as_bytes())?;
        let atlas = tr.atlas();
        cac_core::io::save_png_atomic(&self.path.join("atlas.png"), &atlas.to_rgb8())?;
        for (name, img) in tr.extra_images() {
            cac_core::io::save_png_atomic(&self.path.join(name), &img)?;
        }
        let title = format!("{} loss", tr.config.method.name());
        let plot = report::loss_plot(&tr.state.log, &title, 640, 400)?;
        cac_core::io::save_png_atomic(&self.path.join("loss.png"), &plot)?;
        if finished {
            let dev = tr.device.clone().inner();
            let sheet = report::views_sheet(tr.renderer, tr.env, &atlas, 8, &dev)?;
            cac_core::io::save_png_atomic(&self.path.join("views.png"), &sheet)?;
        }
        Ok(())
    }
}

/// The leaves where two JSON values differ, as `path: there → here`.
fn differences(path: &str, there: &serde_json::Value, here: &serde_json::Value) -> Vec<String> {
    match (there, here) {
        (serde_json::Value::Object(a), serde_json::Value::Object(b)) => {
            let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter()
                .flat_map(|k| {
                    let null = serde_json::Value::Null;
                    differences(
                        &format!("{path}.{k}"),
                        a.get(k).unwrap_or(&null),
                        b.get(k).unwrap_or(&null),
                    )
                })
                .collect()
        }
        _ if there == here => vec![],
        _ => vec![format!("{path}: {there} in the run, {here} asked")],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_run(dir: &Path, scene: &SceneConfig, attack: &AttackConfig) {
        let run = RunFile {
            cac_version: "0".into(),
            burn_version: BURN_VERSION.into(),
            finished: false,
            seed: attack.seed,
            method: attack.method,
            attack: attack.clone(),
            scene: scene.clone(),
            iteration: 0,
            log: vec![],
        };
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join("run.json"), serde_json::to_vec(&run).unwrap()).unwrap();
    }

    #[test]
    fn a_folder_with_a_run_is_refused_or_matched_all_but_iterations() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run");
        let (scene, attack) = (SceneConfig::training(), AttackConfig::default());
        let run = RunDir::create(&path, scene.clone(), attack.clone()).unwrap();
        assert!(!path.exists(), "nothing is written before training");
        assert!(!run.has_checkpoint());
        write_run(&path, &scene, &attack);
        let e = RunDir::create(&path, scene.clone(), attack.clone()).unwrap_err();
        assert!(e.to_string().contains("already holds a run"), "{e}");
        // More iterations: the same run.
        let more = AttackConfig {
            iterations: attack.iterations * 2,
            ..attack.clone()
        };
        let run = RunDir::open_or_create(&path, scene.clone(), more.clone()).unwrap();
        assert_eq!(run.attack, more);
        // Another n or another scene: refused, naming what differs.
        let other = AttackConfig {
            top_n: 50,
            ..attack.clone()
        };
        let e = RunDir::open_or_create(&path, scene.clone(), other).unwrap_err();
        assert!(
            e.to_string()
                .contains("attack.top_n: 300 in the run, 50 asked"),
            "{e}"
        );
        let mut small = scene.clone();
        small.render.width = 64;
        let e = RunDir::open_or_create(&path, small, attack.clone()).unwrap_err();
        assert!(e.to_string().contains("scene.render.width"), "{e}");
        // Opened as it is: its own settings, and resuming needs a checkpoint.
        let run = RunDir::open(&path).unwrap();
        assert_eq!((run.scene, run.attack), (scene, attack));
        let e = RunDir::open(dir.path()).unwrap_err();
        assert!(e.to_string().contains("not a run folder"), "{e}");
    }

    #[test]
    fn hide_classes_count_only_in_hide_mode_and_old_runs_read_as_all() {
        let dir = tempfile::tempdir().unwrap();
        let (scene, attack) = (SceneConfig::training(), AttackConfig::default());
        // A run.json written before the setting existed: no hide_classes.
        let old = dir.path().join("old");
        write_run(&old, &scene, &attack);
        let text = std::fs::read_to_string(old.join("run.json")).unwrap();
        let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
        json["attack"]
            .as_object_mut()
            .unwrap()
            .remove("hide_classes");
        std::fs::write(old.join("run.json"), json.to_string()).unwrap();
        assert_eq!(RunDir::open(&old).unwrap().attack.hide_classes, "all");
        // Not hiding: today's default opens it.
        assert_ne!(attack.hide_classes, "all");
        RunDir::open_or_create(&old, scene.clone(), attack.clone()).unwrap();
        // Hiding: the classes must match.
        let hide = |classes: &str| AttackConfig {
            hide: true,
            hide_classes: classes.into(),
            ..attack.clone()
        };
        let h = dir.path().join("hide");
        write_run(&h, &scene, &hide("all"));
        RunDir::open_or_create(&h, scene.clone(), hide("all")).unwrap();
        let e = RunDir::open_or_create(&h, scene.clone(), hide("car,bus,truck")).unwrap_err();
        assert!(e.to_string().contains("attack.hide_classes"), "{e}");
    }
}
