//! Image-based lighting's knobs against Cycles (`cac bench ibl`): the object lit by an HDR
//! environment in cac's renderer at each spherical-harmonic order, number of occlusion rays and
//! number of reflection prefilter levels,
//! its error in 8-bit levels against Cycles rendering the same views with the same map, and
//! against cac's own finest setting (the knob's own convergence), with its shading time per
//! view. One [`Table`] row per environment and setting; asserts nothing.

use anyhow::{Context, Result};
use burn::tensor::Device;
use cac_core::report::timer::Stopwatch;
use cac_core::report::Table;
use cac_eval::blender::{self, BlenderSettings};
use cac_eval::realism::{lit_by, views, ViewSet};
use cac_render::config::SceneConfig;
use cac_render::environment::{self, Brightness, Condition, Environment};
use cac_render::ibl::{IblSettings, REFLECTION_LEVELS};
use cac_render::{RenderPlan, Renderer};
use cac_scene::Texture;

/// What the benchmark renders: one mesh in its original paint, the free viewpoint set.
#[derive(Clone, Debug)]
pub struct IblBenchJob {
    pub mesh: String,
    /// Environments (Blender's names or files).
    pub hdri: Vec<String>,
    pub views: usize,
    pub seed: u64,
    /// The scene config with the render size and samples set.
    pub cfg: SceneConfig,
    pub blender: BlenderSettings,
}

/// The settings measured: each order at 16 rays, each ray count at order 2 (one reflection
/// level), the default with the whole reflection chain, and the reference.
pub fn settings() -> Vec<IblSettings> {
    let s = |sh_order, occlusion_rays, prefilter_levels| IblSettings {
        sh_order,
        occlusion_rays,
        prefilter_levels,
    };
    vec![
        s(0, 16, 1),
        s(1, 16, 1),
        s(2, 0, 1),
        s(2, 4, 1),
        s(2, 16, 1),
        s(2, 64, 1),
        s(2, 4, REFLECTION_LEVELS),
    ]
}

/// cac's finest setting of the converging knobs (order, rays), the reference each converges to;
/// one reflection level, so the chain's row says how far it moves the image.
pub const REFERENCE: IblSettings = IblSettings {
    sh_order: 2,
    occlusion_rays: 256,
    prefilter_levels: 1,
};

/// Mean absolute difference (8-bit levels, over channels) of `a` and `b` over the pixels `keep`
/// selects, and how many it selected.
fn mae(a: &[[f32; 3]], b: &image::RgbImage, keep: impl Fn(usize) -> bool) -> (f64, usize) {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (i, p) in b.pixels().enumerate() {
        if keep(i) {
            #[allow(clippy::needless_range_loop)]
            for c in 0..3 {
                let x = (a[i][c].clamp(0.0, 1.0) * 255.0).round();
                sum += (x - p.0[c] as f32).abs() as f64;
            }
            n += 1;
        }
    }
    (sum / (3 * n.max(1)) as f64, n)
}

/// Runs the benchmark: Cycles once per environment, then cac at each of [`settings`].
pub fn run(job: &IblBenchJob, dev: &Device, on_row: &mut dyn FnMut(&[String])) -> Result<Table> {
    if job.views == 0 || job.hdri.is_empty() {
        anyhow::bail!(
            "cac bench ibl needs at least one view (--views) and one environment (--hdri)"
        );
    }
    let cfg = &job.cfg;
    let mut oc = cfg.object.clone();
    oc.mesh = job.mesh.clone();
    let scene = oc
        .load()
        .with_context(|| format!("loading mesh {}", job.mesh))?;
    let atlas: Texture = scene.initial_atlas(cfg.render.atlas_res);
    let r = Renderer::new(scene, cfg.render.clone())?;
    let env = Environment::new(cfg.environment.clone())?;
    let conds = views(
        ViewSet::Free,
        cfg,
        job.views,
        Brightness::Bright,
        job.seed,
        false,
    )?;
    let mut t = Table::new([
        "environment",
        "sh_order",
        "occlusion_rays",
        "prefilter_levels",
        "shade_ms_per_view",
        "object_mae_cycles",
        "image_mae_cycles",
        "object_mae_reference",
        "object_pixels",
    ]);
    for name in &job.hdri {
        let world = blender::World::new(name, 1.0, 0.0)?;
        let mut bs = job.blender.clone();
        bs.world = Some(world.clone());
        let cycles = blender::render_views(&r, &env, &conds, &atlas, &bs, dev)?;
        let render = |s: IblSettings| -> Result<(Vec<RenderPlan>, f64)> {
            let mut c = cfg.clone();
            c.environment.ibl = s;
            let (env_h, conds_h): (Environment, Vec<Condition>) = lit_by(&c, &world, &conds)?;
            let clock = Stopwatch::start();
            let plans = environment::plans(&r, &env_h, &conds_h)?;
            Ok((plans, clock.ms() / conds.len().max(1) as f64))
        };
        let (reference, _) = render(REFERENCE)?;
        let reference: Vec<Vec<[f32; 3]>> =
            reference.iter().map(|p| p.render_cpu(&atlas)).collect();
        for s in settings().into_iter().chain([REFERENCE]) {
            let (plans, ms) = render(s)?;
            let (mut obj, mut img, mut refe, mut npx, mut nref) = (0.0, 0.0, 0.0, 0usize, 0usize);
            for (k, (p, cy)) in plans.iter().zip(&cycles).enumerate() {
                let ours = p.render_cpu(&atlas);
                let inside = |i: usize| p.coverage[i] >= 0.99 && cy.coverage[i] >= 0.99;
                let (e, n) = mae(&ours, &cy.image, inside);
                let (ei, _) = mae(&ours, &cy.image, |_| true);
                let ref8 = image::RgbImage::from_fn(p.width as u32, p.height as u32, |x, y| {
                    let c = reference[k][y as usize * p.width + x as usize];
                    image::Rgb(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
                });
                let (er, nr) = mae(&ours, &ref8, |i| p.coverage[i] >= 0.99);
                (obj, img, refe) = (obj + e * n as f64, img + ei, refe + er * nr as f64);
                (npx, nref) = (npx + n, nref + nr);
            }
            let v = plans.len().max(1) as f64;
            let row = vec![
                world.name(),
                s.sh_order.to_string(),
                s.occlusion_rays.to_string(),
                s.prefilter_levels.to_string(),
                format!("{ms:.0}"),
                format!("{:.2}", obj / npx.max(1) as f64),
                format!("{:.2}", img / v),
                format!("{:.2}", refe / nref.max(1) as f64),
                npx.to_string(),
            ];
            on_row(&row);
            t.row(row);
        }
    }
    Ok(t)
}
