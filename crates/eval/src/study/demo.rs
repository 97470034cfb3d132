//! The demo: the main job on the embedded defaults. A short dense-proposals attack on the
//! default vehicle against NanoDet (target "person"), trained on the evaluation protocol's own
//! distribution (scaled down: 320² renders) in a resumable run folder OUT/run/, then scored as
//! `cac eval` scores: before/after P@0.5 and "person" success on protocol views (FV and RV,
//! bright and dark, distance ratio 1.5–6) drawn with a seed the training never saw, with
//! CenterNet as an unseen (transfer) model. Writes the atlases, view sheets with each detector's
//! boxes and summary.json; returns the before/after table as text.

use crate::compare::{before_after, write_sheets, BeforeAfter};
use crate::run::{all_views, evaluate_texture_in, view_groups, ViewPlan};
use crate::Protocol;
use anyhow::Result;
use burn::tensor::Device;
use cac_attack::loss::TargetLoss;
use cac_attack::run::{Along, Progress, RunDir};
use cac_attack::AttackConfig;
use cac_attack::Trainer;
use cac_detect::{self as detect, Detector};
use cac_render::config::{SceneConfig, Stage};
use cac_render::environment::{Environment, ViewpointSet};
use cac_render::{RenderSettings, Renderer};
use cac_scene::Texture;
use std::fmt::Write;
use std::path::PathBuf;
use std::time::Instant;

/// The second scoring and the sheets, in units of the first scoring's time.
const AFTER_SCORING: f64 = 1.25;

/// The least training a budgeted demo does, in seconds.
const MIN_TRAINING_S: f64 = 10.0;

/// The demo's settings (also `cac demo`'s flags).
#[derive(Debug, Clone)]
pub struct DemoJob {
    /// Output folder.
    pub out: PathBuf,
    /// Seed of the training run.
    pub seed: u64,
    /// Attack iterations; `None` (the default) fits them to `budget_s` on this machine.
    pub iterations: Option<usize>,
    /// Wall time the whole demo is fitted to when `iterations` is `None`: the training gets
    /// what is left after scoring the original texture, less the second scoring's estimate
    /// ([`DemoJob::training_budget`]).
    pub budget_s: f64,
    /// Views rendered per iteration. One view per step buys the most quality per second in a
    /// short run (docs/attack.md, the knob table: half the time per iteration).
    pub batch: usize,
    /// The target class's term in every proposal (`cac train --target-loss`): the logit, which
    /// reached more "person" in the same iterations (docs/attack.md, "The demo").
    pub target_loss: TargetLoss,
    /// Protocol views per brightness level and viewpoint set (4 groups: FV/RV × bright/dark).
    pub views: usize,
    /// Seed of the protocol views (not the training seed: the texture never saw these views).
    pub view_seed: u64,
    /// Photographed HDR environments (Blender's by name, e.g. `city,interior`, or .exr/.hdr
    /// files): every training and protocol view is lit by one of them, drawn per view with a
    /// random turn, and shows it behind the vehicle (image-based lighting). Default: the
    /// procedural sun, sky and ground.
    pub hdri: Vec<String>,
}

impl Default for DemoJob {
    /// `cac demo`: into `demo-out`, training seed 0, at batch 1 as many iterations as fit in
    /// 3 minutes in all, the logit target term, 16 protocol views per group on view seed 2026,
    /// the procedural sky.
    fn default() -> Self {
        DemoJob {
            out: PathBuf::from("demo-out"),
            seed: 0,
            iterations: None,
            budget_s: 180.0,
            batch: 1,
            target_loss: TargetLoss::Logit,
            views: 16,
            view_seed: 2026,
            hdri: vec![],
        }
    }
}

/// What the demo's training made.
struct Trained {
    atlas: Texture,
    /// The iteration reached.
    iteration: usize,
    /// The attack as trained (its iterations fitted to the budget when it had one).
    attack: AttackConfig,
    /// Seconds of training the run records (across resumes; fitting it to the budget
    /// included).
    seconds: f64,
    /// The budget this session's training was fitted to (none when resumed or given its
    /// iterations).
    budget_s: Option<f64>,
}

/// What the demo measured.
pub struct DemoOutcome {
    /// The before/after table with its heading, ready to print.
    pub table: String,
    /// Wall time of the whole job.
    pub seconds: f64,
}

impl DemoJob {
    /// Scores the original, trains (or resumes) the run, scores the learned texture, writes the
    /// sheets and summary.json, saying what it does on stdout.
    pub fn run(&self, device: &Device) -> Result<DemoOutcome> {
        let start = Instant::now();
        // The attack's settings are checked before anything is scored or written.
        let attack = self.attack_config();
        attack.validate()?;
        let cfg = self.scene_config();
        let Stage {
            renderer,
            env,
            original,
        } = cfg.stage()?;
        // Scored as `cac eval` renders by default: 512², 4 samples per pixel.
        let settings = RenderSettings {
            width: 512,
            height: 512,
            samples: 4,
            ..cfg.render.clone()
        };
        let eval_renderer = Renderer::new(renderer.scene.clone(), settings)?;
        println!("loading detectors (fetched once into the cache on first use) ...");
        let dets = detect::load_all(&["nanodet", "centernet"], None, device)?;
        let all = detect::refs(&dets);
        let proto = Protocol::from_labels("car,truck", Some(&attack.target))?;
        let plan = ViewPlan {
            views_per_level: self.views,
            seed: self.view_seed,
            ..Default::default()
        };
        let groups = view_groups(&env, &plan);
        let views = all_views(&groups);
        let score = |name: &str, atlas: &Texture| {
            let (r, e) = (&eval_renderer, &env);
            evaluate_texture_in(
                r,
                e,
                &groups,
                &views,
                name,
                atlas,
                &all,
                &proto,
                2,
                device,
                &mut || {},
            )
        };
        let n = 4 * self.views;
        println!("scoring the original texture on {n} protocol views ...");
        let scoring = Instant::now();
        let before = score("original", &original)?;
        let scoring_s = scoring.elapsed().as_secs_f64();
        let budget = self.training_budget(start.elapsed().as_secs_f64(), scoring_s);
        let trained = self.train(&cfg, (&renderer, &env), all[0], &original, budget, device)?;
        println!("scoring the learned texture on the same views ...");
        let after = score("learned", &trained.atlas)?;
        let models = [("nanodet", "white-box"), ("centernet", "transfer")];
        let rows = before_after(("original", &before), ("learned", &after), &models);
        let (sheets, sheet_views) = write_sheets(
            &self.out,
            (&original, &before),
            (&trained.atlas, &after),
            &["nanodet", "centernet"],
        )?;
        let summary = serde_json::json!({
            "protocol": proto,
            "views": plan,
            "scene": cfg,
            "attack": trained.attack,
            "iterations": trained.iteration,
            "training_seconds": trained.seconds,
            "training_budget_seconds": trained.budget_s,
            "results": rows,
            "sheets": sheets,
            "sheet_views": sheet_views,
            "seconds": start.elapsed().as_secs_f64(),
        });
        cac_core::io::write_atomic(
            &self.out.join("summary.json"),
            serde_json::to_string_pretty(&summary)?.as_bytes(),
        )?;
        Ok(DemoOutcome {
            table: self.table(&cfg, &trained, &rows),
            seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// The training preset, with every view lit by one of `--hdri`'s environments when given.
    fn scene_config(&self) -> SceneConfig {
        let mut cfg = SceneConfig::training();
        if !self.hdri.is_empty() {
            cfg.environment.hdri = self.hdri.clone();
            cfg.environment.hdri_share = 1.0;
        }
        cfg
    }

    /// Seconds of training that keep the demo within `budget_s` when its iterations are not
    /// given (`None` when they are): the budget less what is spent, the second scoring and the
    /// sheets (measured at 1.25 times the first scoring: 26 s against 21 on the Intel Xeon),
    /// and 5 % of it to spare. At least [`MIN_TRAINING_S`]: a machine too slow for the budget
    /// still trains, and takes longer.
    pub fn training_budget(&self, spent_s: f64, scoring_s: f64) -> Option<f64> {
        self.iterations.is_none().then(|| {
            let left = 0.95 * (self.budget_s - spent_s) - AFTER_SCORING * scoring_s;
            left.max(MIN_TRAINING_S)
        })
    }

    /// The demo's attack: NanoDet, target "person", checkpoints every 50 iterations; the
    /// iterations are fitted to the budget when not given (1 until then).
    fn attack_config(&self) -> AttackConfig {
        AttackConfig {
            models: vec!["nanodet".into()],
            iterations: self.iterations.unwrap_or(1),
            seed: self.seed,
            batch: self.batch,
            target_loss: self.target_loss,
            checkpoint_every: 50,
            viewpoints: ViewpointSet::Free,
            ..Default::default()
        }
    }

    /// Trains (or resumes) the demo's run in OUT/run, a new run fitted to `budget_s` seconds
    /// of training when given (a resumed one continues to the iterations its run.json records
    /// unless `--iterations` says more); returns the learned atlas and the iteration reached.
    fn train(
        &self,
        cfg: &SceneConfig,
        (renderer, env): (&Renderer, &Environment),
        source: &dyn Detector,
        original: &Texture,
        budget_s: Option<f64>,
        device: &Device,
    ) -> Result<Trained> {
        let path = self.out.join("run");
        let mut attack = self.attack_config();
        if self.iterations.is_none() && path.join("run.json").exists() {
            attack.iterations = RunDir::open(&path)?.attack.iterations;
        }
        let run = RunDir::open_or_create(&path, cfg.clone(), attack.clone())?;
        let training = Device::autodiff(device.clone());
        let tr = Trainer::new(
            attack.clone(),
            renderer,
            env,
            vec![source],
            training,
            original,
        )?;
        let mut tr = run.resume(tr)?;
        let resumed = tr.state.iteration > 0;
        if resumed {
            let it = tr.state.iteration;
            println!("resuming the demo's run at iteration {it}");
        }
        let budget_s = budget_s.filter(|_| !resumed);
        let length = match budget_s {
            Some(b) => format!("for {b:.0} s (as many iterations as fit)"),
            None => format!("{} iterations", attack.iterations),
        };
        println!(
            "training {length} against nanodet (target \"person\", proposals on the object, \
             batch {}, protocol distances) ...",
            self.batch
        );
        let along = Along {
            budget_s,
            ..Along::new(Progress::Bar)
        };
        run.train_along(&mut tr, along)?;
        Ok(Trained {
            atlas: tr.atlas(),
            iteration: tr.state.iteration,
            attack: tr.config.clone(),
            seconds: run.train_seconds()?,
            budget_s,
        })
    }

    /// The before/after table and its heading.
    fn table(&self, cfg: &SceneConfig, trained: &Trained, rows: &[BeforeAfter]) -> String {
        let mut s = String::new();
        let fitted = match trained.budget_s {
            Some(_) => format!(", as many as fit the demo's {:.0} s", self.budget_s),
            None => String::new(),
        };
        let _ = writeln!(
            s,
            "\ntrained {} iterations at batch {} in {:.0} s{fitted} (target loss {}).",
            trained.iteration, self.batch, trained.seconds, self.target_loss
        );
        let _ = writeln!(
            s,
            "{} protocol views (cac eval's: FV and RV x bright and dark, {} each; distance ratio \
             {:?}, elevation {:?} deg; view seed {}, training seed {}); 512², 4 spp.\nhit = car/truck \
             with IoU >= 0.5 and confidence >= 0.3; person = a person box on the vehicle (IoU >= 0.5, \
             confidence >= 0.3).",
            4 * self.views,
            self.views,
            cfg.environment.distance_ratio,
            cfg.environment.elevation_deg,
            self.view_seed,
            self.seed,
        );
        if !cfg.environment.hdri.is_empty() {
            let _ = writeln!(
                s,
                "Every view, in training and in these protocol views, is lit by one of the \
                 photographed environments {} (drawn per view, turned {:?} deg, exposure {:?} \
                 stops) and shows it behind the vehicle; under an environment the bright/dark \
                 level does not change the light.",
                cfg.environment.hdri.join(", "),
                cfg.environment.hdri_rotation_deg,
                cfg.environment.hdri_exposure_stops,
            );
        }
        let _ = writeln!(
            s,
            "{:<22} {:>4} {:>12} {:>12} {:>7} {:>14} {:>14}",
            "model", "set", "P@0.5 before", "P@0.5 after", "drop", "person before", "person after"
        );
        for r in rows {
            let _ = writeln!(
                s,
                "{:<22} {:>4} {:>12.3} {:>12.3} {:>7.3} {:>14.3} {:>14.3}",
                format!("{} ({})", r.model, r.role),
                r.set,
                r.p_at_05_before,
                r.p_at_05_after,
                r.drop,
                r.targeted_before,
                r.targeted_after
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The training gets 95 % of what the budget leaves, less the second scoring's estimate;
    /// never less than the floor; nothing when the iterations are given.
    #[test]
    fn the_training_budget_leaves_room_for_the_second_scoring() {
        let demo = DemoJob::default();
        let b = demo.training_budget(22.0, 20.0).unwrap();
        assert!((b - (0.95 * 158.0 - 25.0)).abs() < 1e-9, "{b}");
        // More spent or a slower scoring leaves less.
        assert!(demo.training_budget(40.0, 20.0).unwrap() < b);
        assert!(demo.training_budget(22.0, 30.0).unwrap() < b);
        // A machine too slow for the budget still trains, for the floor.
        assert_eq!(demo.training_budget(170.0, 60.0), Some(MIN_TRAINING_S));
        let fixed = DemoJob {
            iterations: Some(640),
            ..DemoJob::default()
        };
        assert_eq!(fixed.training_budget(22.0, 20.0), None);
    }
}
