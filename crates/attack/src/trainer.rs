//! The one optimiser: Adam over a parameterisation of the camouflage, with the step skeleton
//! (draw the iteration's batch, form the images, ensemble loss, backward, step), the constructor
//! checks, resuming from a checkpoint and the log in one place.
//!
//! Two parameterisations ([`Parameterisation`]): the full atlas, texel by texel or as a
//! multi-scale pyramid ([`super::pyramid`]), for CAC, UPC and CAMOU; and a 2D patch pasted on
//! rendered images and tiled onto the atlas ([`super::baselines::patch`]) for AdvPat and
//! ShapeShifter. Not here: the run folder and the checkpointed loop ([`super::run`]).

use super::adam::Adam;
use super::baselines::patch::{self, Patch};
use super::baselines::{self, Method};
use super::checkpoint::{self, Checkpoint};
use super::filaments::{Filaments, Forward};
use super::pyramid;
use crate::config::AttackConfig;
use crate::iteration::{check_health, draw_conditions, ensemble_loss, IterationLog};
use anyhow::{bail, Context, Result};
use burn::tensor::{Device, Tensor, TensorData};
use cac_core::printer::{Printer, Profile, Response};
use cac_detect::Detector;
use cac_render::environment::{self, Condition, Environment};
use cac_render::{RenderPlan, Renderer};
use cac_scene::Texture;
use std::path::Path;
use std::time::Instant;

/// What the optimiser moves, and how that becomes the atlas on the object.
pub enum Parameterisation {
    /// The atlas in `scales` levels ([`pyramid`]; one level: the atlas itself). `paintable`:
    /// the texels a paintable surface can sample, where the coarse levels act (empty for one
    /// level).
    Atlas { scales: usize, paintable: Vec<bool> },
    /// A 2D patch pasted on rendered images, tiled onto the atlas.
    Patch(Patch),
    /// A choice among an FDM printer's filaments per region ([`super::filaments`]): what the
    /// printer makes, trained through the printer.
    Filaments(Filaments),
    /// The requested atlas, rendered through a full-colour or paper printer's fitted response
    /// ([`super::response`]).
    Response(Response),
}

/// A training run bound to a renderer, an environment and its source detectors.
pub struct Trainer<'a> {
    pub config: AttackConfig,
    pub renderer: &'a Renderer,
    pub env: &'a Environment,
    pub detectors: Vec<&'a dyn Detector>,
    /// An autodiff device (2D methods render their backgrounds on its inner device).
    pub device: Device,
    /// Iteration, optimiser state, parameters (for 2D methods: the patch) and log.
    pub state: Checkpoint,
    pub param: Parameterisation,
    /// Ray-cast and shade the next iteration's views on another thread while this one's
    /// detectors run ([`Trainer::step`]): on by default when the device is not the host's CPU
    /// (a GPU leaves the cores idle). Off for Flex and libtorch's CPU: both compete for the same
    /// cores, which measured no faster on Flex and 14% slower on libtorch (whose OpenMP threads
    /// spin while the renderer's take their cores) on two cores (docs/detectors.md).
    pub plan_ahead: bool,
    /// The next iteration's views when planned ahead; `None` before the first step, when not
    /// planning ahead, and for 2D methods.
    next_plans: Option<(usize, Vec<RenderPlan>)>,
}

impl<'a> Trainer<'a> {
    /// A run of `config.method` from its start. `init` is the initial atlas (the object's
    /// texture or a chosen one; resized to the renderer's atlas): where a full-atlas method
    /// starts, and the texture a 2D method's patch is pasted over (the patch starts mid-grey,
    /// Thys et al.'s grey start).
    pub fn new(
        config: AttackConfig,
        renderer: &'a Renderer,
        env: &'a Environment,
        detectors: Vec<&'a dyn Detector>,
        device: Device,
        init: &Texture,
    ) -> Result<Self> {
        config.validate()?;
        if detectors.len() != config.models.len() {
            bail!(
                "{} detectors given for {} configured models",
                detectors.len(),
                config.models.len()
            );
        }
        for d in &detectors {
            config.goal_for(*d)?;
        }
        let res = renderer.settings.atlas_res;
        let init = if init.width != res || init.height != res {
            init.resized(res, res)
        } else {
            init.clone()
        };
        let (side, scales, params, param) = if config.method.is_2d() {
            let p = config.patch_res;
            let patch = Patch::new(renderer, init, config.patch_tiles);
            (p, 1, vec![0.5; p * p * 3], Parameterisation::Patch(patch))
        } else {
            pyramid::check(res, config.scales)?;
            let atlas: Vec<f32> = init.texels.iter().flatten().copied().collect();
            let paintable = if config.scales > 1 {
                baselines::atlas::paintable_texels(&renderer.scene, res)
            } else {
                vec![]
            };
            let params = pyramid::from_atlas(&atlas, res, config.scales);
            let param = Parameterisation::Atlas {
                scales: config.scales,
                paintable,
            };
            (res, config.scales, params, param)
        };
        let state = Checkpoint {
            iteration: 0,
            atlas_res: side,
            scales,
            filament_params: 0,
            adam: Adam::new(params.len(), config.lr),
            atlas: params,
            log: vec![],
        };
        Ok(Trainer {
            plan_ahead: !cac_detect::computes_on_host(&device),
            config,
            renderer,
            env,
            detectors,
            device,
            state,
            param,
            next_plans: None,
        })
    }

    /// Continues from the checkpoint in `run_dir`, which must hold parameters of this run's
    /// shape.
    pub fn resume(mut self, run_dir: &Path) -> Result<Self> {
        let ck = checkpoint::load(run_dir)?;
        let what = match self.param {
            Parameterisation::Atlas { .. } => "checkpoint atlas",
            Parameterisation::Patch(_) => "checkpoint patch",
            Parameterisation::Filaments(_) => "checkpoint filament choice",
            Parameterisation::Response(_) => "checkpoint atlas",
        };
        if ck.atlas_res != self.state.atlas_res {
            bail!(
                "{}: {what} is {}², the run asks for {}²",
                run_dir.display(),
                ck.atlas_res,
                self.state.atlas_res
            );
        }
        if ck.scales != self.state.scales {
            bail!(
                "{}: checkpoint has {} atlas levels, the run asks for {}",
                run_dir.display(),
                ck.scales,
                self.state.scales
            );
        }
        if ck.atlas.len() != self.state.atlas.len() {
            bail!(
                "{}: the checkpoint holds {} parameters, the run asks for {} (a run trained \
                 through a printer resumes with the same printer profile)",
                run_dir.display(),
                ck.atlas.len(),
                self.state.atlas.len()
            );
        }
        self.state = ck;
        Ok(self)
    }

    /// Trains through a multi-material FDM printer from here on: the atlas becomes a choice
    /// among its filaments per region ([`Filaments`]), started from the nearest filament of the
    /// current atlas; the optimiser starts afresh. Full-atlas methods at one scale only.
    pub fn through_filaments(mut self, f: Filaments) -> Result<Self> {
        match self.param {
            Parameterisation::Atlas { scales: 1, .. } if f.res == self.state.atlas_res => {}
            _ => bail!(
                "training through a printer's filaments needs a full-atlas method at one scale \
                 (--scales 1) on the renderer's atlas"
            ),
        }
        let init = f.init(&self.atlas());
        self.state.adam = Adam::new(init.len(), self.config.lr);
        self.state.filament_params = init.len();
        self.state.atlas = init;
        self.param = Parameterisation::Filaments(f);
        Ok(self)
    }

    /// The conditions of iteration `i` (a pure function of the seed and `i`).
    pub fn conditions(&self, i: usize) -> Vec<Condition> {
        draw_conditions(self.env, &self.config, i)
    }

    /// The camouflage atlas as it goes on the object.
    pub fn atlas(&self) -> Texture {
        match &self.param {
            Parameterisation::Atlas { .. } => texture(self.state.atlas_res, &self.leaf()),
            Parameterisation::Patch(p) => p.on_object(&self.patch()),
            Parameterisation::Filaments(f) => f.hard(&self.state.atlas),
            Parameterisation::Response(_) => texture(self.state.atlas_res, &self.state.atlas),
        }
    }

    /// The trained parameters as an image: the atlas, or the 2D patch.
    pub fn patch(&self) -> Texture {
        texture(self.state.atlas_res, &self.leaf())
    }

    /// Extra images for the run folder (name, image): the 2D patch; through a printer's
    /// response, the atlas as printed.
    pub(crate) fn extra_images(&self) -> Vec<(String, image::RgbImage)> {
        match &self.param {
            Parameterisation::Atlas { .. } | Parameterisation::Filaments(_) => vec![],
            Parameterisation::Response(r) => {
                let printed = super::response::forward(r, &self.state.atlas);
                let t = texture(self.state.atlas_res, &printed);
                vec![("as_printed.png".into(), t.to_rgb8())]
            }
            Parameterisation::Patch(_) => vec![("patch.png".into(), self.patch().to_rgb8())],
        }
    }

    /// What the gradient is taken with respect to (row-major RGB, `atlas_res²`): the atlas the
    /// parameters compose to (through a printer's filaments: iteration `i`'s choice, with what
    /// its backward pass needs), or the patch.
    fn leaf_at(&self, i: usize) -> (Vec<f32>, Option<Forward>) {
        match &self.param {
            Parameterisation::Filaments(f) => {
                let fw = f.forward(&self.state.atlas, i, self.config.iterations);
                (fw.atlas.clone(), Some(fw))
            }
            Parameterisation::Response(r) => (super::response::forward(r, &self.state.atlas), None),
            _ => (self.leaf(), None),
        }
    }

    /// Trains through `config.printer`'s profile, when there is one: an FDM profile trains the
    /// filaments' choice ([`Trainer::through_filaments`]); a full-colour or paper profile renders
    /// the requested atlas through its fitted response ([`super::response`]).
    pub fn through_printer(self, config: &AttackConfig) -> Result<Self> {
        let Some(path) = &config.printer else {
            return Ok(self);
        };
        let profile = Profile::load(path)?;
        match profile.printer()? {
            Printer::Response(r) => self.through_response(r),
            fdm => {
                let res = self.state.atlas_res;
                let f = Filaments::new(&fdm, &self.renderer.scene, res, config.seed)?;
                self.through_filaments(f)
            }
        }
    }

    /// Renders the requested atlas through a printer's fitted response from here on.
    pub fn through_response(mut self, r: Response) -> Result<Self> {
        match self.param {
            Parameterisation::Atlas { scales: 1, .. } => {}
            _ => bail!(
                "training through a printer's response needs a full-atlas method at --scales 1"
            ),
        }
        self.param = Parameterisation::Response(r);
        Ok(self)
    }

    /// The filaments trained through, if any.
    pub fn filaments(&self) -> Option<&Filaments> {
        match &self.param {
            Parameterisation::Filaments(f) => Some(f),
            _ => None,
        }
    }

    /// [`Trainer::leaf_at`] outside training: the parameters as they stand (the hard choice for
    /// filaments).
    fn leaf(&self) -> Vec<f32> {
        let (r, k) = (self.state.atlas_res, self.state.scales);
        match &self.param {
            Parameterisation::Filaments(f) => f
                .hard(&self.state.atlas)
                .texels
                .into_iter()
                .flatten()
                .collect(),
            Parameterisation::Atlas { paintable, .. } if k > 1 => {
                // Projected parameters compose to [0, 1] up to rounding; the clamp removes that.
                let mut a = pyramid::compose(&self.state.atlas, r, k, paintable);
                a.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
                a
            }
            _ => self.state.atlas.clone(),
        }
    }

    /// The images of iteration `i` as a function of `leaf`, and the object boxes in them. The
    /// views' plans are the prefetched ones when they are iteration `i`'s.
    fn images(&mut self, i: usize, leaf: Tensor<4>) -> Result<(Tensor<4>, Vec<Option<[f32; 4]>>)> {
        match &self.param {
            Parameterisation::Atlas { .. }
            | Parameterisation::Filaments(_)
            | Parameterisation::Response(_) => {
                let conds = self.conditions(i);
                let plans = match self.next_plans.take() {
                    Some((j, plans)) if j == i => plans,
                    _ => environment::plans(self.renderer, self.env, &conds)?,
                };
                let images = environment::form_planned(&plans, leaf, &conds);
                Ok((images, plans.iter().map(|p| p.object_box).collect()))
            }
            Parameterisation::Patch(p) => {
                let conds = draw_conditions(self.env, &self.config, i);
                let run = (self.config.seed, i);
                p.images(self.renderer, self.env, &conds, run, leaf, &self.device)
            }
        }
    }

    /// One Adam step on the parameters from the gradient with respect to the leaf (`fw`: the
    /// leaf's forward pass through filaments).
    fn update(&mut self, g: &[f32], fw: Option<Forward>) {
        let (r, k) = (self.state.atlas_res, self.state.scales);
        match &self.param {
            Parameterisation::Filaments(f) => {
                let fw = fw.expect("a filament leaf comes with its forward pass");
                let gl = f.backward(&fw, g);
                self.state.adam.step_unclipped(&mut self.state.atlas, &gl);
            }
            Parameterisation::Response(resp) => {
                let gr = super::response::backward(resp, &self.state.atlas, g);
                self.state.adam.step(&mut self.state.atlas, &gr);
            }
            Parameterisation::Atlas { paintable, .. } if k > 1 => {
                let gp = pyramid::adjoint(g, r, k, paintable);
                self.state.adam.step_unclipped(&mut self.state.atlas, &gp);
                pyramid::project(&mut self.state.atlas, r, k, paintable);
            }
            _ => {
                self.state.adam.step(&mut self.state.atlas, g);
            }
        }
    }

    /// One iteration: form the images (ray-cast, shade and composite the views), detect, loss,
    /// backward, Adam step. With [`Trainer::plan_ahead`], another thread ray-casts and shades
    /// the next iteration's views while the detectors run forward and backward (they depend on
    /// the seed and the iteration only, not on the atlas); the result is the same bit for bit.
    /// `ms_render` is the ray casting and shading, the compositing, and any wait for views
    /// planned ahead.
    pub fn step(&mut self) -> Result<IterationLog> {
        let i = self.state.iteration;
        let t0 = Instant::now();
        let r = self.state.atlas_res;
        let (values, fw) = self.leaf_at(i);
        let atlas_range = crate::iteration::value_range(&values);
        let leaf = Tensor::<4>::from_data(TensorData::new(values, [1, r, r, 3]), &self.device)
            .require_grad();
        let (images, objects) = self.images(i, leaf.clone())?;
        let mut ms_render = t0.elapsed().as_secs_f64() * 1e3;
        let prefetch = self.plan_ahead && !matches!(self.param, Parameterisation::Patch(_));
        let (detected, next) = std::thread::scope(|s| {
            let (renderer, env, config) = (self.renderer, self.env, &self.config);
            let next = prefetch.then(|| {
                s.spawn(move || {
                    let conds = draw_conditions(env, config, i + 1);
                    environment::plans(renderer, env, &conds)
                })
            });
            let detected = self.detect_and_differentiate(&images, &objects, &leaf);
            let t = Instant::now();
            let next = next.map(|h| h.join().expect("the view prefetch panicked"));
            (detected, next.map(|n| (n, t.elapsed().as_secs_f64() * 1e3)))
        });
        let (loss_value, g, proposals, ms_forward, ms_backward) = detected?;
        if let Some((next, ms_wait)) = next {
            // A view that cannot be planned is iteration i + 1's error: that step plans it
            // again and reports it.
            self.next_plans = next.ok().map(|plans| (i + 1, plans));
            ms_render += ms_wait;
        }
        check_health(i, loss_value, &g, atlas_range)?;
        let (atlas_min, atlas_max) = atlas_range;
        let t3 = Instant::now();
        let grad_norm = g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
        self.state.adam.lr = self.config.lr_at(i);
        self.update(&g, fw);
        let log = IterationLog {
            iteration: i,
            loss: loss_value,
            grad_norm,
            proposals,
            ms_render,
            ms_forward,
            ms_backward,
            ms_optimiser: t3.elapsed().as_secs_f64() * 1e3,
            atlas_min,
            atlas_max,
        };
        self.state.log.push(log.clone());
        self.state.iteration += 1;
        Ok(log)
    }

    /// The forward pass (loss and proposals) and the gradient with respect to `leaf`, with
    /// their times in ms.
    fn detect_and_differentiate(
        &self,
        images: &Tensor<4>,
        objects: &[Option<[f32; 4]>],
        leaf: &Tensor<4>,
    ) -> Result<(f64, Vec<f32>, usize, f64, f64)> {
        let t1 = Instant::now();
        let (mut loss, proposals) = ensemble_loss(&self.detectors, images, objects, &self.config)?;
        if self.config.method == Method::Advpat {
            loss = loss + patch::total_variation(leaf.clone()) * patch::TV_WEIGHT;
        }
        let loss_value = cac_detect::to_vec(&loss)?[0] as f64;
        let ms_forward = t1.elapsed().as_secs_f64() * 1e3;
        let t2 = Instant::now();
        let grads = loss.backward();
        let g = cac_detect::to_vec(
            &leaf
                .grad(&grads)
                .context("no gradient reached the parameters")?,
        )?;
        let ms_backward = t2.elapsed().as_secs_f64() * 1e3;
        Ok((loss_value, g, proposals, ms_forward, ms_backward))
    }
}

/// A square RGB texture from row-major values.
fn texture(side: usize, v: &[f32]) -> Texture {
    Texture {
        width: side,
        height: side,
        texels: v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    }
}
