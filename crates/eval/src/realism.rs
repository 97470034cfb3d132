//! The realism benchmark's measurements (`cac bench realism`): is the *original* vehicle
//! recognised at all? P@0.5, mean best confidence and targeted success of NanoDet and CenterNet
//! for each mesh × texture × renderer × viewpoint set × brightness. Viewpoint sets: `street`
//! (12-ish azimuths, elevation 5–15°, distance ratio 1.5, the demo's evaluation views), `free`
//! (the config's free viewpoint distribution), `rv` (its restricted one: side views) and
//! `hemisphere` (the free one with elevation 0–90°).
//! Photometric transforms are off unless asked for. With the Blender renderer every view is also
//! re-rendered by Cycles at the same camera and lighting ([`super::blender`]). Rows come out one
//! at a time (they are slow) and as two tables: one row per combination, one per view.

use super::{blender, Protocol, Summary};
use anyhow::{Context, Result};
use burn::tensor::Device;
use cac_core::report::timer::Stopwatch;
use cac_core::report::Table;
use cac_detect::Detector;
use cac_render::config::SceneConfig;
use cac_render::environment::{street_views, Brightness, Condition, Environment, ViewpointSet};
use cac_render::Renderer;
use cac_scene::textures::{self, Kind};
use cac_scene::Texture;
use std::path::PathBuf;

/// A viewpoint set of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewSet {
    Street,
    /// The protocol's free viewpoint distribution (`fv` in `cac eval`).
    Free,
    /// The protocol's restricted one: side views only (`rv` in `cac eval`).
    Restricted,
    Hemisphere,
}

cac_core::choices!(ViewSet {
    Street => "street": "",
    Free => "free": "The protocol's free viewpoint distribution (`fv` in `cac eval`)",
    Restricted => "rv" | "restricted": "The protocol's restricted one: side views only (`rv` in `cac eval`)",
    Hemisphere => "hemisphere": "",
});

/// A renderer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Which {
    Cac,
    Blender,
}

cac_core::choices!(Which {
    Cac => "cac": "",
    Blender => "blender": "",
});

/// Everything the benchmark needs besides the detectors (NanoDet, then CenterNet). `cac bench
/// realism`'s flags map onto it but for the scene config, Blender's settings and the protocol,
/// which the command builds from its others.
#[derive(Clone, Debug)]
pub struct RealismJob {
    /// Built-in object names or mesh files (OBJ/glTF/GLB).
    pub meshes: Vec<String>,
    /// Viewpoint sets.
    pub sets: Vec<ViewSet>,
    /// Views per set and brightness level.
    pub views: usize,
    /// The scene config with the render size and samples already set.
    pub cfg: SceneConfig,
    /// Textures: original, natural, naive, random (simple textures on the paintable texels), or
    /// image files (PNG/JPEG atlases).
    pub textures: Vec<String>,
    /// Renderers.
    pub renderers: Vec<Which>,
    pub blender: blender::BlenderSettings,
    /// Apply the sampled photometric transforms (lighten/darken, print error, noise) too.
    pub photometric: bool,
    /// Light the scene with these HDR environments instead of the bright and dark levels (one
    /// row per environment), in both renderers (cac's image-based lighting, Cycles' world):
    /// Blender's own (city, courtyard, forest, interior, night, studio, sunrise, sunset) or
    /// equirectangular image files.
    pub hdri: Vec<String>,
    /// Strength of the HDR environments (1: as photographed).
    pub hdri_strength: f32,
    /// Turn of the HDR environments about the vertical axis, degrees.
    pub hdri_rotation: f32,
    /// Seed of the sampled viewpoint sets.
    pub seed: u64,
    /// Save every rendered view under this folder.
    pub save: Option<PathBuf>,
    /// Render every texture as this printer makes it (a printer profile; both renderers take the
    /// same as-printed atlas).
    pub printer: Option<PathBuf>,
    pub protocol: Protocol,
}

impl Default for RealismJob {
    /// The pickup, the jeep and the Cesium milk truck (`../shared`); street, free and hemisphere
    /// views, 12 per set and level, seed 0; the original texture in cac's renderer only; no
    /// photometric transforms, no HDR light, no printer; the default scene, Blender settings and
    /// protocol (the command sets the render size from its flags).
    fn default() -> Self {
        RealismJob {
            meshes: [
                "pickup",
                "jeep",
                "../shared/meshes/CesiumMilkTruck/CesiumMilkTruck.glb",
            ]
            .map(String::from)
            .to_vec(),
            sets: vec![ViewSet::Street, ViewSet::Free, ViewSet::Hemisphere],
            views: 12,
            cfg: Default::default(),
            textures: ["original"].map(String::from).to_vec(),
            renderers: vec![Which::Cac],
            blender: Default::default(),
            photometric: false,
            hdri: vec![],
            hdri_strength: 1.0,
            hdri_rotation: 0.0,
            seed: 0,
            save: None,
            printer: None,
            protocol: Default::default(),
        }
    }
}

/// The columns of the per-view table (`--per-view`), which `cac bench agreement` reads back.
pub const PER_VIEW_COLUMNS: [&str; 15] = [
    "mesh",
    "renderer",
    "texture",
    "set",
    "light",
    "view",
    "azimuth",
    "elevation",
    "distance_ratio",
    "nanodet_hit",
    "nanodet_conf",
    "nanodet_targeted",
    "centernet_hit",
    "centernet_conf",
    "centernet_targeted",
];

/// One combination's figures, per detector.
pub struct Row {
    /// Mesh stem, renderer, texture stem, set, light ("bright", "dark" or "hdri:NAME").
    pub key: [String; 5],
    pub views: usize,
    pub nanodet: Summary,
    pub centernet: Summary,
    pub seconds: f64,
}

/// The two CSV tables.
pub struct Tables {
    pub rows: Table,
    pub per_view: Table,
}

/// What every row shares.
struct Bench<'a> {
    a: &'a RealismJob,
    all: &'a [&'a dyn Detector],
    dev: &'a Device,
    t: Tables,
    on_row: &'a mut dyn FnMut(&Row),
}

/// Runs the benchmark with `dets` (NanoDet, CenterNet), calling `on_row` as each row is done.
pub fn run(
    job: &RealismJob,
    dets: &[&dyn Detector],
    dev: &Device,
    on_row: &mut dyn FnMut(&Row),
) -> Result<Tables> {
    let mut b = Bench {
        a: job,
        all: dets,
        dev,
        on_row,
        t: Tables {
            rows: Table::new([
                "mesh",
                "renderer",
                "texture",
                "set",
                "light",
                "views",
                "nanodet_p05",
                "nanodet_mean_conf",
                "nanodet_targeted",
                "centernet_p05",
                "centernet_mean_conf",
                "centernet_targeted",
                "seconds",
            ]),
            per_view: Table::new(PER_VIEW_COLUMNS),
        },
    };
    for mesh in &job.meshes {
        b.mesh(mesh)?;
    }
    Ok(b.t)
}

/// The conditions of a viewpoint set.
pub fn views(
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
        ViewSet::Restricted => {
            Environment::new(env_cfg)?.sample_n(n, ViewpointSet::Restricted, b, seed)
        }
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

/// The environment and conditions that light `conds` by `world` in cac's renderer (its
/// strength as an exposure, its rotation as Blender's).
pub fn lit_by(
    cfg: &SceneConfig,
    world: &blender::World,
    conds: &[Condition],
) -> Result<(Environment, Vec<Condition>)> {
    let mut ec = cfg.environment.clone();
    ec.hdri = vec![world.image.clone()];
    let env = Environment::new(ec)?;
    let draw = cac_render::environment::HdriDraw {
        index: 0,
        rotation_deg: world.rotation_deg,
        exposure_stops: world.strength.log2(),
    };
    let conds = conds
        .iter()
        .map(|c| Condition {
            hdri: Some(draw),
            ..c.clone()
        })
        .collect();
    Ok((env, conds))
}

fn texture(name: &str, original: &Texture, mask: &[bool]) -> Result<Texture> {
    if name == "original" {
        return Ok(original.clone());
    }
    let t = if name.ends_with(".png") || name.ends_with(".jpg") {
        Texture::from_rgb8(&cac_core::io::load_rgb(std::path::Path::new(name))?)
            .resized(original.width, original.height)
    } else {
        let kind = cac_core::choice::parse_ignoring_case::<Kind>(name).map_err(|e| {
            anyhow::anyhow!("unknown texture '{name}': {e} (or 'original', or a PNG/JPEG file)")
        })?;
        textures::generate(kind, original.width, 0)?
    };
    Ok(cac_scene::paint::paint(original, &t, mask))
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
        let (a, cfg) = (self.a, &self.a.cfg);
        let mut oc = cfg.object.clone();
        oc.mesh = mesh.to_string();
        let scene = oc.load().with_context(|| format!("loading mesh {mesh}"))?;
        let original = scene.initial_atlas(cfg.render.atlas_res);
        let mask = cac_scene::paint::paintable_texels(&scene, cfg.render.atlas_res);
        let r = Renderer::new(scene, cfg.render.clone())?;
        let env = Environment::new(cfg.environment.clone())?;
        let printer = match &a.printer {
            Some(p) => Some(cac_core::printer::Profile::load(p)?.printer()?),
            None => None,
        };
        for tname in &a.textures {
            let mut atlas = texture(tname, &original, &mask)?;
            if let Some(p) = &printer {
                super::textures::as_printed(&mut atlas, p);
            }
            for &set in &a.sets {
                for (b, world) in self.lights()? {
                    let conds = views(set, cfg, a.views, b, a.seed, a.photometric)?;
                    // cac's rows under an environment: the same views, lit by the same map.
                    let lit = world.as_ref().map(|w| lit_by(cfg, w, &conds)).transpose()?;
                    let light = match &world {
                        Some(w) => format!("hdri:{}", w.name()),
                        None => format!("{b:?}").to_lowercase(),
                    };
                    let mut blender = a.blender.clone();
                    blender.world = world;
                    for &which in &a.renderers {
                        let t0 = Stopwatch::start();
                        let (env, conds) = match (&lit, which) {
                            (Some((e, c)), Which::Cac) => (e, c),
                            _ => (&env, &conds),
                        };
                        let (scores, images) =
                            self.score(which, &r, env, conds, &atlas, &blender)?;
                        let key = [
                            stem(mesh),
                            match which {
                                Which::Cac => "cac".to_string(),
                                Which::Blender => blender.label(),
                            },
                            stem(tname),
                            format!("{set:?}").to_lowercase(),
                            light.clone(),
                        ];
                        self.record(key, conds, &scores, &images, t0.secs())?;
                    }
                }
            }
        }
        Ok(())
    }

    /// The light levels of a row: bright and dark (the conditions' own light), or each HDR
    /// environment (the viewpoints of the bright level, the environment's light in Blender).
    fn lights(&self) -> Result<Vec<(Brightness, Option<blender::World>)>> {
        let a = self.a;
        if a.hdri.is_empty() {
            return Ok(vec![(Brightness::Bright, None), (Brightness::Dark, None)]);
        }
        a.hdri
            .iter()
            .map(|h| {
                let w = blender::World::new(h, a.hdri_strength, a.hdri_rotation)?;
                Ok((Brightness::Bright, Some(w)))
            })
            .collect()
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
        blender: &blender::BlenderSettings,
    ) -> Result<(Vec<Vec<super::ImageScore>>, Vec<image::RgbImage>)> {
        let (all, proto, dev) = (self.all, &self.a.protocol, self.dev);
        Ok(match which {
            Which::Cac => {
                let o = super::evaluate(r, env, conds, atlas, all, proto, dev)?;
                (o.scores, o.images)
            }
            Which::Blender => {
                let views = blender::render_views(r, env, conds, atlas, blender, dev)?;
                let s = blender::score_views(&views, all, proto, dev)?;
                (s, views.into_iter().map(|v| v.image).collect())
            }
        })
    }

    /// Saves the images (with `save`), adds the per-view rows and the summary row, and hands it on.
    fn record(
        &mut self,
        key: [String; 5],
        conds: &[Condition],
        scores: &[Vec<super::ImageScore>],
        images: &[image::RgbImage],
        secs: f64,
    ) -> Result<()> {
        let [short, wname, tname, sname, bname] = key;
        if let Some(dir) = &self.a.save {
            let d = dir.join(format!("{short}_{wname}_{tname}_{sname}_{bname}"));
            std::fs::create_dir_all(&d)?;
            for (i, img) in images.iter().enumerate() {
                cac_core::io::save_png_atomic(&d.join(format!("{i:02}.png")), img)?;
            }
        }
        for (i, cd) in conds.iter().enumerate() {
            let v = &cd.viewpoint;
            let (n, c) = (&scores[0][i], &scores[1][i]);
            self.t.per_view.row([
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
                (n.targeted as u8).to_string(),
                (c.hit as u8).to_string(),
                format!("{:.3}", c.best_true_conf),
                (c.targeted as u8).to_string(),
            ]);
        }
        let (n, c) = (super::summarise(&scores[0]), super::summarise(&scores[1]));
        self.t.rows.row([
            short.clone(),
            wname.clone(),
            tname.clone(),
            sname.clone(),
            bname.clone(),
            conds.len().to_string(),
            format!("{:.4}", n.p_at_05),
            format!("{:.4}", n.mean_best_true_conf),
            format!("{:.4}", n.targeted_success),
            format!("{:.4}", c.p_at_05),
            format!("{:.4}", c.mean_best_true_conf),
            format!("{:.4}", c.targeted_success),
            format!("{secs:.1}"),
        ]);
        (self.on_row)(&Row {
            key: [short, wname, tname, sname, bname],
            views: conds.len(),
            nanodet: n,
            centernet: c,
            seconds: secs,
        });
        Ok(())
    }
}
