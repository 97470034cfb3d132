//! `cac bench realism`: is the *original* vehicle recognised at all? P@0.5 of each detector for
//! each mesh × texture × renderer × viewpoint set × brightness, printed as a table and written as
//! CSV. Viewpoint sets: `street` (12-ish azimuths, elevation 5–15°, distance ratio 1.5, the
//! demo's evaluation views), `free` (the config's free viewpoint distribution) and `hemisphere`
//! (the same with elevation 0–90°). Photometric transforms are off unless `--photometric`.
//! With `--renderers cac,blender` every view is also re-rendered by Blender (Cycles, CPU) at the
//! same camera and lighting (see docs/blender.md). A benchmark, not a test: it asserts nothing.

use super::timer::Stopwatch;
use crate::cli::device;
use anyhow::{Context, Result};
use cac::config::SceneConfig;
use cac::detect::{self, Detector};
use cac::environment::{street_views, Brightness, Condition, Environment, ViewpointSet};
use cac::eval::{self, blender, Protocol};
use cac::render::{RenderSettings, Renderer};
use cac::report::Table;
use cac::scene::textures::{self, Kind};
use cac::scene::Texture;
use clap::ValueEnum;
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ViewSet {
    Street,
    Free,
    Hemisphere,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Which {
    Cac,
    Blender,
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Built-in object names or mesh files (OBJ/glTF/GLB).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "pickup,jeep,../shared/meshes/CesiumMilkTruck/CesiumMilkTruck.glb"
    )]
    pub meshes: Vec<String>,
    /// Viewpoint sets.
    #[arg(long, value_delimiter = ',', default_value = "street,free,hemisphere")]
    pub sets: Vec<ViewSet>,
    /// Views per set and brightness level.
    #[arg(long, default_value_t = 12)]
    pub views: usize,
    /// Image side (pixels).
    #[arg(long, default_value_t = 416)]
    pub size: usize,
    /// Samples per pixel of cac's renderer.
    #[arg(long, default_value_t = 4)]
    pub samples: usize,
    /// Scene config whose [render] field of view and [environment] are used (default: defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Textures: original, natural, naive, random (simple textures on the paintable texels), or
    /// image files (PNG/JPEG atlases).
    #[arg(long, value_delimiter = ',', default_value = "original")]
    pub textures: Vec<String>,
    /// Renderers.
    #[arg(long, value_delimiter = ',', default_value = "cac")]
    pub renderers: Vec<Which>,
    /// Cycles samples per pixel for the Blender renderer.
    #[arg(long, default_value_t = 32)]
    pub blender_samples: usize,
    /// Apply the sampled photometric transforms (lighten/darken, print error, noise) too.
    #[arg(long)]
    pub photometric: bool,
    /// Seed of the sampled viewpoint sets.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Save every rendered view under this folder.
    #[arg(long)]
    pub save: Option<PathBuf>,
    /// CSV output file.
    #[arg(long, default_value = "bench-realism.csv")]
    pub csv: PathBuf,
    /// Target class (a COCO label such as "person"): also report each detector's targeted
    /// success (a target-class box with IoU >= 0.5 and confidence >= 0.3).
    #[arg(long)]
    pub target: Option<String>,
    /// Also write one CSV row per view (viewpoint, hit and best confidence per detector).
    #[arg(long)]
    pub per_view: Option<PathBuf>,
}

/// The conditions of a viewpoint set.
fn views(
    set: ViewSet,
    cfg: &SceneConfig,
    n: usize,
    b: Brightness,
    seed: u64,
    photometric: bool,
) -> Result<Vec<Condition>> {
    let mut env_cfg = cfg.environment.clone();
    let conds = match set {
        ViewSet::Street => return Ok(street_views(n, 1.5, b)),
        ViewSet::Free => Environment::new(env_cfg)?.sample_n(n, ViewpointSet::Free, b, seed),
        ViewSet::Hemisphere => {
            env_cfg.elevation_deg = [0.0, 90.0];
            Environment::new(env_cfg)?.sample_n(n, ViewpointSet::Free, b, seed)
        }
    };
    Ok(conds
        .into_iter()
        .map(|c| {
            if photometric {
                c
            } else {
                Condition {
                    light_add: 0.0,
                    light_mul: 1.0,
                    channel_add: [0.0; 3],
                    channel_mul: [1.0; 3],
                    noise_std: 0.0,
                    ..c
                }
            }
        })
        .collect())
}

fn texture(name: &str, original: &Texture, mask: &[bool]) -> Result<Texture> {
    if name == "original" {
        return Ok(original.clone());
    }
    let t = if name.ends_with(".png") || name.ends_with(".jpg") {
        Texture::from_rgb8(&cac::io::load_rgb(std::path::Path::new(name))?)
            .resized(original.width, original.height)
    } else {
        let kind = Kind::from_str(name, true).map_err(|e| {
            anyhow::anyhow!("unknown texture '{name}': {e} (or 'original', or a PNG/JPEG file)")
        })?;
        textures::generate(kind, original.width, 0)?
    };
    Ok(cac::attack::baselines::atlas::paint(original, &t, mask))
}

/// What every row shares: the flags, the scene config, the detectors and the protocol.
struct Bench<'a> {
    a: &'a Args,
    cfg: SceneConfig,
    all: Vec<&'a dyn Detector>,
    proto: Protocol,
    bs: blender::BlenderSettings,
    dev: burn::tensor::Device,
    rows: Table,
    per_view: Table,
}

pub fn run(a: Args) -> Result<()> {
    let mut cfg = match &a.config {
        Some(p) => SceneConfig::from_file(p)?,
        None => SceneConfig::default(),
    };
    cfg.render = RenderSettings {
        width: a.size,
        height: a.size,
        samples: a.samples,
        ..cfg.render
    };
    let dev = device::inference();
    let dets = detect::load_all(&["nanodet", "centernet"], None, &dev)?;
    let bs = blender::BlenderSettings {
        samples: a.blender_samples,
        ..Default::default()
    };
    if a.renderers.contains(&Which::Blender) {
        println!("renderer 2: {}", blender::check(&bs)?);
    }
    println!(
        "P@0.5 = car/truck at IoU >= 0.5, conf >= 0.3; {}² px, {} spp (cac), {} spp (Blender); {} views per row; photometric transforms {}",
        a.size, a.samples, a.blender_samples, a.views, if a.photometric { "on" } else { "off" }
    );
    println!(
        "{:<16} {:<8} {:<9} {:<10} {:<6} {:>8} {:>10} {:>8} {:>8} {:>10} {:>8} {:>6}",
        "mesh",
        "renderer",
        "texture",
        "set",
        "light",
        "nanodet",
        "conf",
        "target",
        "centernet",
        "conf",
        "target",
        "s"
    );
    let mut b = Bench {
        a: &a,
        cfg,
        all: dets.iter().map(|d| d.as_ref()).collect(),
        proto: Protocol::from_labels("car,truck", a.target.as_deref())?,
        bs,
        dev,
        rows: Table::new([
            "mesh",
            "renderer",
            "texture",
            "set",
            "brightness",
            "views",
            "nanodet_p05",
            "nanodet_mean_conf",
            "nanodet_targeted",
            "centernet_p05",
            "centernet_mean_conf",
            "centernet_targeted",
            "seconds",
        ]),
        per_view: Table::new([
            "mesh",
            "renderer",
            "texture",
            "set",
            "brightness",
            "view",
            "azimuth",
            "elevation",
            "distance_ratio",
            "nanodet_hit",
            "nanodet_conf",
            "centernet_hit",
            "centernet_conf",
        ]),
    };
    for mesh in &a.meshes {
        b.mesh(mesh)?;
    }
    cac::io::write_atomic(&a.csv, b.rows.csv().as_bytes())?;
    if let Some(p) = &a.per_view {
        cac::io::write_atomic(p, b.per_view.csv().as_bytes())?;
        println!("wrote {}", p.display());
    }
    println!("wrote {}", a.csv.display());
    Ok(())
}

/// A file's stem, or `name` itself.
fn stem(name: &str) -> String {
    std::path::Path::new(name)
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or(name.to_string())
}

impl Bench<'_> {
    /// Every row of one mesh: textures × sets × brightness levels × renderers.
    fn mesh(&mut self, mesh: &str) -> Result<()> {
        let (a, cfg) = (self.a, &self.cfg);
        let mut oc = cfg.object.clone();
        oc.mesh = mesh.to_string();
        let scene = oc.load().with_context(|| format!("loading mesh {mesh}"))?;
        let original = scene.initial_atlas(cfg.render.atlas_res);
        let mask = cac::attack::baselines::atlas::paintable_texels(&scene, cfg.render.atlas_res);
        let r = Renderer::new(scene, cfg.render.clone())?;
        let env = Environment::new(cfg.environment.clone())?;
        for tname in &a.textures {
            let atlas = texture(tname, &original, &mask)?;
            for &set in &a.sets {
                for b in [Brightness::Bright, Brightness::Dark] {
                    let conds = views(set, &self.cfg, a.views, b, a.seed, a.photometric)?;
                    for &which in &a.renderers {
                        let t0 = Stopwatch::start();
                        let (scores, images) = self.score(which, &r, &env, &conds, &atlas)?;
                        let key = [
                            stem(mesh),
                            format!("{which:?}").to_lowercase(),
                            stem(tname),
                            format!("{set:?}").to_lowercase(),
                            format!("{b:?}").to_lowercase(),
                        ];
                        self.record(key, &conds, &scores, &images, t0.secs())?;
                    }
                }
            }
        }
        Ok(())
    }

    /// Renders `atlas` in `conds` with `which` and scores both detectors: per detector, per view
    /// scores; and the images.
    fn score(
        &self,
        which: Which,
        r: &Renderer,
        env: &Environment,
        conds: &[Condition],
        atlas: &Texture,
    ) -> Result<(Vec<Vec<eval::ImageScore>>, Vec<image::RgbImage>)> {
        let (all, proto, dev) = (&self.all, &self.proto, &self.dev);
        Ok(match which {
            Which::Cac => {
                let o = eval::evaluate(r, env, conds, atlas, all, proto, dev)?;
                (o.scores, o.images)
            }
            Which::Blender => {
                let views = blender::render_views(r, env, conds, atlas, &self.bs, dev)?;
                let s = blender::score_views(&views, all, proto, dev)?;
                (s, views.into_iter().map(|v| v.image).collect())
            }
        })
    }

    /// Saves the images (with --save), adds the per-view rows and the summary row, and prints it.
    fn record(
        &mut self,
        key: [String; 5],
        conds: &[Condition],
        scores: &[Vec<eval::ImageScore>],
        images: &[image::RgbImage],
        secs: f64,
    ) -> Result<()> {
        let [short, wname, tname, sname, bname] = key;
        if let Some(dir) = &self.a.save {
            let d = dir.join(format!("{short}_{wname}_{tname}_{sname}_{bname}"));
            std::fs::create_dir_all(&d)?;
            for (i, img) in images.iter().enumerate() {
                cac::io::save_png_atomic(&d.join(format!("{i:02}.png")), img)?;
            }
        }
        for (i, cd) in conds.iter().enumerate() {
            let v = &cd.viewpoint;
            let (n, c) = (&scores[0][i], &scores[1][i]);
            self.per_view.row([
                short.clone(),
                wname.clone(),
                tname.clone(),
                sname.clone(),
                bname.clone(),
                i.to_string(),
                format!("{:.1}", v.azimuth_deg.rem_euclid(360.0)),
                format!("{:.1}", v.elevation_deg),
                format!("{:.2}", v.distance_ratio),
                (n.hit as u8).to_string(),
                format!("{:.3}", n.best_true_conf),
                (c.hit as u8).to_string(),
                format!("{:.3}", c.best_true_conf),
            ]);
        }
        let (n, c) = (eval::summarise(&scores[0]), eval::summarise(&scores[1]));
        println!(
            "{short:<16} {wname:<8} {tname:<9} {sname:<10} {bname:<6} {:>8.3} {:>10.3} {:>8.3} {:>8.3} {:>10.3} {:>8.3} {secs:>6.0}",
            n.p_at_05,
            n.mean_best_true_conf,
            n.targeted_success,
            c.p_at_05,
            c.mean_best_true_conf,
            c.targeted_success
        );
        self.rows.row([
            short,
            wname,
            tname,
            sname,
            bname,
            conds.len().to_string(),
            format!("{:.4}", n.p_at_05),
            format!("{:.4}", n.mean_best_true_conf),
            format!("{:.4}", n.targeted_success),
            format!("{:.4}", c.p_at_05),
            format!("{:.4}", c.mean_best_true_conf),
            format!("{:.4}", c.targeted_success),
            format!("{secs:.1}"),
        ]);
        Ok(())
    }
}
