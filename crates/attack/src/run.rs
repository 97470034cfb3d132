//! A training run on disk: the run folder and the checkpointed loop that fills it.
//!
//! A run folder holds `run.json` (versions, the scene and attack settings, the iteration reached,
//! the per-iteration log, whether it finished: enough to reproduce the run), `atlas.png`,
//! `loss.png`, `views.png` (when finished), `patch.png` (2D methods) and `checkpoint/`
//! ([`super::checkpoint`]). [`RunDir`] creates one (refusing a folder that already holds a run),
//! opens one with its settings, or opens the one that matches given settings (all but
//! `iterations`, which may grow); [`RunDir::train`] runs the remaining iterations, checkpointing
//! every `checkpoint_every` and rewriting the folder. `cac train`, `cac demo` and `cac study`
//! all go through here. Not here: the optimiser ([`crate::trainer::Trainer`]).

use super::curve::{self, CurvePoint, Judge};
use super::{checkpoint, report};
use crate::baselines::Method;
use crate::config::AttackConfig;
use crate::iteration::IterationLog;
use crate::trainer::Trainer;
use anyhow::{bail, Context, Result};
use cac_core::choice::Choice;
use cac_core::report::timer::format_duration;
use cac_render::config::SceneConfig;
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

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
    /// Seconds of training so far: the run's clock, across resumes, without the curve's
    /// scoring ([`super::curve`]).
    #[serde(default)]
    pub train_seconds: f64,
    /// The time budget the run's iterations were chosen for (`cac train --budget`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget_seconds: Option<f64>,
    /// The texture scored along the run (`cac train --eval-every`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub curve: Vec<CurvePoint>,
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
    pub fn open_or_create(path: &Path, scene: SceneConfig, attack: AttackConfig) -> Result<RunDir> {
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

    /// Seconds of training the run's clock records (across resumes; without the curve's
    /// scoring): 0 before its first write.
    pub fn train_seconds(&self) -> Result<f64> {
        if !self.path.join("run.json").exists() {
            return Ok(0.0);
        }
        Ok(RunFile::read(&self.path)?.train_seconds)
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
        let progress = if progress {
            Progress::Bar
        } else {
            Progress::Quiet
        };
        self.train_along(tr, Along::new(progress)).map(|_| ())
    }

    /// [`RunDir::train`] with what `along` asks besides: progress as a bar or as lines, a time
    /// budget (which sets a new run's iterations and stops the run cleanly when it is spent),
    /// and the curve (the texture scored at fixed points of the training clock). Returns
    /// whether the run reached its iterations.
    pub fn train_along(&self, tr: &mut Trainer, mut along: Along) -> Result<bool> {
        std::fs::create_dir_all(&self.path)
            .with_context(|| format!("cannot create run folder {}", self.path.display()))?;
        let prior = RunFile::read(&self.path)
            .ok()
            .filter(|_| tr.state.iteration > 0);
        let mut record = Record {
            train_seconds: prior.as_ref().map_or(0.0, |p| p.train_seconds),
            budget_seconds: prior.as_ref().and_then(|p| p.budget_seconds),
            curve: prior.map_or(vec![], |p| p.curve),
        };
        if let Some(budget) = along.budget_s {
            if tr.state.iteration > 0 {
                bail!("--budget sets a new run's iterations; a resumed run continues to the {} its run.json records", tr.config.iterations);
            }
            let spent = fit_to_budget(tr, budget)?;
            record.train_seconds = spent;
            record.budget_seconds = Some(budget);
        }
        let mut clock = Clock::from(record.train_seconds);
        let mut ticker = Ticker::new(&along.progress, tr);
        self.write_record(tr, false, &record)?;
        if let Some(c) = &along.curve {
            if record.curve.is_empty() {
                record
                    .curve
                    .push(self.curve_point(c.as_ref(), tr, &mut clock)?);
                ticker.curve(record.curve.last());
            }
        }
        let total = tr.config.iterations;
        let mut stopped = false;
        while tr.state.iteration < total {
            if along.budget_s.is_some_and(|b| clock.seconds() >= b) {
                stopped = true;
                break;
            }
            let log = tr.step()?;
            ticker.step(&log, total, clock.seconds(), along.budget_s);
            let (k, it) = (tr.config.checkpoint_every, tr.state.iteration);
            let due = along.curve.as_ref().and_then(|c| {
                let last = record.curve.last().map_or(0.0, |p| p.train_s);
                (clock.seconds() >= last + c.every_s() && it < total).then_some(c)
            });
            if let Some(c) = due {
                record
                    .curve
                    .push(self.curve_point(c.as_ref(), tr, &mut clock)?);
                ticker.curve(record.curve.last());
            }
            if k > 0 && it % k == 0 && it < total {
                checkpoint::save(&self.path, &tr.state)?;
                record.train_seconds = clock.seconds();
                self.write_record(tr, false, &record)?;
            }
        }
        if let Some(c) = along.curve.take() {
            if record.curve.last().map(|p| p.iteration) != Some(tr.state.iteration) {
                record
                    .curve
                    .push(self.curve_point(c.as_ref(), tr, &mut clock)?);
                ticker.curve(record.curve.last());
            }
        }
        ticker.finish();
        checkpoint::save(&self.path, &tr.state)?;
        record.train_seconds = clock.seconds();
        if stopped {
            eprintln!(
                "stopped at the budget ({}) at iteration {} of {}; --resume {} continues",
                format_duration(along.budget_s.unwrap_or(0.0)),
                tr.state.iteration,
                total,
                self.path.display()
            );
        }
        self.write_record(tr, !stopped, &record)?;
        if stopped {
            // What the run made: the views of the atlas it stopped with.
            self.write_views(tr)?;
        }
        Ok(!stopped)
    }

    /// The curve's point for the atlas as it stands, with the run's clock stopped while it
    /// scores; `curve.csv` and `curve.png` are written with it.
    fn curve_point(&self, c: &dyn Judge, tr: &Trainer, clock: &mut Clock) -> Result<CurvePoint> {
        let t = Instant::now();
        let p = c.score(&tr.atlas(), tr.state.iteration, clock.seconds());
        clock.pause(t.elapsed().as_secs_f64());
        p
    }

    /// Writes run.json, atlas.png, the trainer's extra images and loss.png; views.png (rendered
    /// on the trainer's inner device) when `finished`.
    pub fn write(&self, tr: &Trainer, finished: bool) -> Result<()> {
        let record = RunFile::read(&self.path)
            .ok()
            .map_or(Record::default(), |p| Record {
                train_seconds: p.train_seconds,
                budget_seconds: p.budget_seconds,
                curve: p.curve,
            });
        self.write_record(tr, finished, &record)
    }

    fn write_record(&self, tr: &Trainer, finished: bool, record: &Record) -> Result<()> {
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
            train_seconds: record.train_seconds,
            budget_seconds: record.budget_seconds,
            curve: record.curve.clone(),
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
        if !record.curve.is_empty() {
            curve::write(&self.path, &record.curve)?;
        }
        if finished {
            self.write_views(tr)?;
        }
        Ok(())
    }

    /// views.png: the atlas in 8 street-level views, rendered on the trainer's inner device.
    fn write_views(&self, tr: &Trainer) -> Result<()> {
        let dev = tr.device.clone().inner();
        let sheet = report::views_sheet(tr.renderer, tr.env, &tr.atlas(), 8, &dev)?;
        cac_core::io::save_png_atomic(&self.path.join("views.png"), &sheet)
    }
}

/// What run.json records beside the trainer's state.
#[derive(Clone, Debug, Default)]
struct Record {
    train_seconds: f64,
    budget_seconds: Option<f64>,
    curve: Vec<CurvePoint>,
}

/// How the loop reports progress.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Progress {
    /// A progress bar (on a terminal).
    Bar,
    /// A line on stderr every this many seconds (a file, a pipe, a Slurm job): iteration, loss,
    /// ms per iteration, the latest curve point, time left.
    Lines { every_s: f64 },
    /// Nothing.
    Quiet,
}

/// What a run does besides training ([`RunDir::train_along`]).
pub struct Along<'c> {
    pub progress: Progress,
    /// Seconds of training at most: a new run's iterations are fitted to it
    /// ([`fit_to_budget`]), and the run stops cleanly when it is spent.
    pub budget_s: Option<f64>,
    /// The texture scored along the run.
    pub curve: Option<Box<dyn Judge + 'c>>,
}

impl Along<'_> {
    /// Progress only.
    pub fn new(progress: Progress) -> Self {
        Along {
            progress,
            budget_s: None,
            curve: None,
        }
    }
}

/// Iterations timed to fit a new run to a budget (after two warm-up iterations): with 3, a
/// 10-minute run at 512² ended 72 s early.
const TIMED_ITERATIONS: usize = 6;

/// Sets `tr`'s iterations to what fits in `budget_s` seconds: times two warm-up and
/// [`TIMED_ITERATIONS`] iterations, then puts the trainer back at its start (the run is the one
/// `--iterations N` gives, N written to run.json) and returns the seconds spent timing, which
/// the budget includes. The iterations are the budget left over the slowest timed iteration,
/// less 3 % for checkpoints and the closing writes; at least one.
pub fn fit_to_budget(tr: &mut Trainer, budget_s: f64) -> Result<f64> {
    if !(budget_s > 0.0 && budget_s.is_finite()) {
        bail!("--budget must be a positive time, got {budget_s} s");
    }
    let start = tr.state.clone();
    let t = Instant::now();
    tr.step()?;
    tr.step()?;
    let mut times = vec![];
    for _ in 0..TIMED_ITERATIONS {
        let s = Instant::now();
        tr.step()?;
        times.push(s.elapsed().as_secs_f64());
    }
    tr.state = start;
    let spent = t.elapsed().as_secs_f64();
    let left = (budget_s - spent) * 0.95;
    let per = cac_core::report::timer::median(times);
    tr.config.iterations = ((left / per).floor() as usize).max(1);
    Ok(spent)
}

/// The run's clock: seconds of training before this session plus this session's, less the
/// time the curve's scoring took.
struct Clock {
    before: f64,
    started: Instant,
    paused: f64,
}

impl Clock {
    fn from(before: f64) -> Self {
        Clock {
            before,
            started: Instant::now(),
            paused: 0.0,
        }
    }
    fn seconds(&self) -> f64 {
        self.before + self.started.elapsed().as_secs_f64() - self.paused
    }
    fn pause(&mut self, s: f64) {
        self.paused += s;
    }
}

/// Progress as the run goes: a bar, lines at a steady interval, or nothing.
struct Ticker {
    bar: Option<ProgressBar>,
    every_s: Option<f64>,
    last_line: Instant,
    curve: Option<String>,
}

impl Ticker {
    fn new(progress: &Progress, tr: &Trainer) -> Self {
        let bar = (*progress == Progress::Bar).then(|| {
            let pb = ProgressBar::new(tr.config.iterations as u64);
            pb.set_style(
                ProgressStyle::with_template(
                    "{bar:30} {pos}/{len} iterations, loss {msg}, ETA {eta}",
                )
                .expect("template"),
            );
            pb.set_position(tr.state.iteration as u64);
            pb
        });
        let every_s = match progress {
            Progress::Lines { every_s } => Some(every_s.max(0.0)),
            _ => None,
        };
        Ticker {
            bar,
            every_s,
            last_line: Instant::now(),
            curve: None,
        }
    }

    fn step(&mut self, log: &IterationLog, total: usize, train_s: f64, budget_s: Option<f64>) {
        if let Some(pb) = &self.bar {
            pb.set_length(total as u64);
            pb.set_message(format!("{:.4}", log.loss));
            pb.inc(1);
        }
        let Some(every) = self.every_s else { return };
        let done = log.iteration + 1;
        if self.last_line.elapsed().as_secs_f64() < every && done < total {
            return;
        }
        self.last_line = Instant::now();
        let ms = log.ms_render + log.ms_forward + log.ms_backward + log.ms_optimiser;
        let per = train_s / done.max(1) as f64;
        let mut left = (total - done.min(total)) as f64 * per;
        if let Some(b) = budget_s {
            left = left.min((b - train_s).max(0.0));
        }
        let mut line = format!(
            "iteration {done}/{total}, loss {:.4}, {ms:.0} ms/iteration, {} trained, about {} left",
            log.loss,
            format_duration(train_s),
            format_duration(left)
        );
        if let Some(c) = &self.curve {
            line.push_str(&format!("; curve {c}"));
        }
        eprintln!("{line}");
    }

    fn curve(&mut self, p: Option<&CurvePoint>) {
        let Some(p) = p else { return };
        let brief = p.brief();
        match &self.bar {
            Some(pb) => pb.println(format!("curve {brief}")),
            None if self.every_s.is_some() => eprintln!("curve {brief}"),
            None => {}
        }
        self.curve = Some(brief);
    }

    fn finish(&self) {
        if let Some(pb) = &self.bar {
            pb.finish_and_clear();
        }
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
            train_seconds: 0.0,
            budget_seconds: None,
            curve: vec![],
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
