//! The CAC attack (Algorithm 1 of the paper): learn a camouflage atlas under expectation over
//! transformations with the dense-proposals loss.
//!
//! Each iteration draws a batch of environment conditions (seeded by the run seed and the
//! iteration number, so a resumed run draws the same batches), renders them differentiably, runs
//! every source detector, fixes its proposals (by default the candidates on the object, see
//! [`loss`]), and takes an Adam step on the atlas that lowers the loss over them; the atlas is
//! clipped to [0, 1].
//! Only texels that paintable surfaces sample ever receive a gradient, so only they change.
//!
//! One [`Trainer`] optimises every method over its parameterisation (the atlas, a multi-scale
//! atlas or a 2D patch). A run folder ([`run::RunDir`]: run.json, atlas.png, plots, checkpoints)
//! holds a run; long runs checkpoint every K iterations ([`checkpoint`]), and a resumed run
//! continues exactly where the last checkpoint left off.
//!
//! Crate `cac-attack` (`cac::attack`). The evaluation protocol that judges a run, and the studies
//! that train with the attack and judge with it, are the next crate, `cac-eval`; a run's training
//! curve is scored through the [`curve::Judge`] trait, which `cac-eval` implements.

pub mod adam;
pub mod baselines;
pub mod checkpoint;
mod config;
pub mod curve;
pub mod filaments;
mod iteration;
pub mod loss;
pub mod pyramid;
pub mod report;
pub mod response;
pub mod run;
mod trainer;

pub use baselines::Method;
pub use checkpoint::Checkpoint;
pub use config::{AttackConfig, LrDecay};
pub use iteration::{check_health, draw_conditions, ensemble_loss, value_range, IterationLog};
pub use trainer::{Parameterisation, Trainer};
