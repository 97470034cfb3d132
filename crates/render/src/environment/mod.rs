//! The environment: the distribution of viewing and lighting conditions an attack is trained
//! under and a texture is evaluated in (the paper's Table 3), sampled with a seed.
//!
//! A [`Condition`] is one draw. Its geometric and lighting part (viewpoint, sun, background,
//! ground) goes to the renderer; its photometric part is applied as tensor ops so gradients pass:
//! print error on the atlas ([`print_error`]), and lighten/darken plus sensor noise on the image
//! ([`photometric`]). [`form`] is the one image-formation call that chains them with the renderer.
//! See `docs/environment.md` for every parameter and its default. Anti-aliasing error against
//! time is measured by `cac-bench` (`cac bench render`).

mod formation;
mod transforms;

pub use formation::{form, form_images, form_planned, plan, plans};
pub use transforms::{photometric, print_error};

use crate::camera::Viewpoint;
use crate::light::{Backdrop, Background, Ground, Lighting};
use crate::skyline::Skyline;
use anyhow::{bail, Context, Result};
use cac_scene::Texture;
use glam::Vec2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;

/// Where the camera may be (on the command line `fv`/`free` or `rv`/`restricted`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ViewpointSet {
    /// Anywhere on the upper half of the viewing sphere within the elevation range.
    Free,
    /// Side views only: azimuth within ±α/2 of either side (α = 120° by default).
    Restricted,
}

cac_core::choices!(ViewpointSet {
    Free => "fv" | "free": "Anywhere on the upper half of the viewing sphere within the elevation range",
    Restricted => "rv" | "restricted": "Side views only: azimuth within ±α/2 of either side (α = 120° by default)",
});

impl ViewpointSet {
    /// `sets` without repeats, in the order given (a command line may name a set twice).
    pub fn distinct(sets: &[ViewpointSet]) -> Vec<ViewpointSet> {
        let mut out: Vec<ViewpointSet> = Vec::with_capacity(2);
        for s in sets {
            if !out.contains(s) {
                out.push(*s);
            }
        }
        out
    }
}

/// Scene brightness level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Brightness {
    Bright,
    Dark,
}

cac_core::choices!(Brightness {
    Bright => "bright": "",
    Dark => "dark": "",
});

/// Ambient and sun intensity of one brightness level.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightLevel {
    pub ambient: f32,
    pub sun: f32,
}

/// The `[environment]` table of a scene config. Defaults follow the paper's Table 3.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvConfig {
    /// Camera distance in object lengths (Table 3: 1.0 to 6.0; default 1.5 to 6.0, the 6–26 m at
    /// which street and dash cameras see a 4.3 m vehicle whole).
    pub distance_ratio: [f32; 2],
    /// Image-plane translation of the object, fraction of the image (Table 3: ±0.05).
    pub translate: f32,
    /// Camera elevation range in degrees for the free viewpoint set (default 0 to 20°: what
    /// street and dash cameras see; the paper's semi-ellipsoid is 0 to 90°, see
    /// docs/environment.md for P@0.5 on both).
    pub elevation_deg: [f32; 2],
    /// Restricted viewpoint: total azimuth span around each side (Table 3 / paper: 120°).
    pub restricted_alpha_deg: f32,
    /// Background colour per channel (Table 3: 0.1 to 1.0); used with `background_color_prob`.
    pub background_color: [f32; 2],
    /// Probability of a flat background colour instead of sky (or a background image).
    pub background_color_prob: f32,
    /// Optional background images (PNG/JPEG), drawn uniformly when given.
    pub background_images: Vec<PathBuf>,
    /// Render a ground plane.
    pub ground: bool,
    /// Ground textures (PNG/JPEG); empty = a procedural asphalt/grass texture.
    pub ground_textures: Vec<PathBuf>,
    /// Metres per repetition of the ground texture.
    pub ground_tile_m: f32,
    /// A distant skyline (buildings, trees) on the sky's horizon.
    pub skyline: bool,
    /// Additive lighten/darken (Table 3: ±0.15).
    pub light_add: f32,
    /// Multiplicative lighten/darken (Table 3: 0.5 to 2.0).
    pub light_mul: [f32; 2],
    /// Per-channel additive print error (Table 3: ±0.15).
    pub channel_add: f32,
    /// Per-channel multiplicative print error (Table 3: 0.7 to 1.3).
    pub channel_mul: [f32; 2],
    /// Gaussian noise standard deviation (Table 3: 0 to 0.1).
    pub noise_std: [f32; 2],
    /// Sun elevation range (degrees).
    pub sun_elevation_deg: [f32; 2],
    /// Probability that a drawn condition lights the object's ambient from an open sky over the
    /// ground (`Lighting::sky_occlusion`) rather than from every direction: a physical renderer's
    /// ambient, which the textures must survive (docs/attack.md, "Second renderer"). Default 0:
    /// the evaluation protocol's ambient; training configs may raise it.
    pub sky_occlusion: f32,
    pub bright: LightLevel,
    pub dark: LightLevel,
    /// Photographed HDR environments ([`crate::ibl`]): names of Blender's eight (`city`,
    /// `courtyard`, `forest`, `interior`, `night`, `studio`, `sunrise`, `sunset`) or paths to
    /// equirectangular EXR/HDR files. Empty (the default): the sun and ambient above.
    pub hdri: Vec<String>,
    /// Probability that a drawn condition is lit by one of `hdri` (drawn uniformly) instead of
    /// the sun and ambient.
    pub hdri_share: f32,
    /// Turn of the environment about the vertical axis, degrees (drawn uniformly).
    pub hdri_rotation_deg: [f32; 2],
    /// Exposure of the environment in stops (drawn uniformly; 0: as photographed).
    pub hdri_exposure_stops: [f32; 2],
    /// How finely the renderer evaluates an environment's light.
    pub ibl: crate::ibl::IblSettings,
}

impl Default for EnvConfig {
    fn default() -> Self {
        EnvConfig {
            distance_ratio: [1.5, 6.0],
            translate: 0.05,
            elevation_deg: [0.0, 20.0],
            restricted_alpha_deg: 120.0,
            background_color: [0.1, 1.0],
            background_color_prob: 0.25,
            background_images: vec![],
            ground: true,
            ground_textures: vec![],
            ground_tile_m: 3.0,
            skyline: true,
            light_add: 0.15,
            light_mul: [0.5, 2.0],
            channel_add: 0.15,
            channel_mul: [0.7, 1.3],
            noise_std: [0.0, 0.1],
            sun_elevation_deg: [25.0, 70.0],
            sky_occlusion: 0.0,
            bright: LightLevel {
                ambient: 0.45,
                sun: 0.70,
            },
            dark: LightLevel {
                ambient: 0.16,
                sun: 0.24,
            },
            hdri: vec![],
            hdri_share: 1.0,
            hdri_rotation_deg: [0.0, 360.0],
            hdri_exposure_stops: [0.0, 0.0],
            ibl: crate::ibl::IblSettings::default(),
        }
    }
}

fn check_range(name: &str, r: [f32; 2], lo: f32, hi: f32) -> Result<()> {
    if !(r[0].is_finite() && r[1].is_finite() && r[0] <= r[1] && r[0] >= lo && r[1] <= hi) {
        bail!("environment.{name} = {r:?} must be an ordered range within [{lo}, {hi}]");
    }
    Ok(())
}

impl EnvConfig {
    pub fn validate(&self) -> Result<()> {
        check_range("distance_ratio", self.distance_ratio, 0.01, 1e4)?;
        check_range("elevation_deg", self.elevation_deg, -89.9, 90.0)?;
        check_range("background_color", self.background_color, 0.0, 1.0)?;
        check_range("light_mul", self.light_mul, 0.0, 100.0)?;
        check_range("channel_mul", self.channel_mul, 0.0, 100.0)?;
        check_range("noise_std", self.noise_std, 0.0, 10.0)?;
        check_range("sun_elevation_deg", self.sun_elevation_deg, 0.0, 90.0)?;
        check_range("hdri_rotation_deg", self.hdri_rotation_deg, -720.0, 720.0)?;
        check_range("hdri_exposure_stops", self.hdri_exposure_stops, -20.0, 20.0)?;
        self.ibl.check().context("environment.ibl")?;
        for (n, v) in [
            ("translate", self.translate),
            ("light_add", self.light_add),
            ("channel_add", self.channel_add),
            ("sky_occlusion", self.sky_occlusion),
            ("hdri_share", self.hdri_share),
        ] {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                bail!("environment.{n} = {v} must be within [0, 1]");
            }
        }
        if !(self.restricted_alpha_deg > 0.0 && self.restricted_alpha_deg <= 180.0) {
            bail!("environment.restricted_alpha_deg must be within (0, 180]");
        }
        if !(self.ground_tile_m > 0.0 && self.ground_tile_m.is_finite()) {
            bail!("environment.ground_tile_m must be positive");
        }
        Ok(())
    }
}

/// One draw from the environment distribution.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Condition {
    pub viewpoint: Viewpoint,
    pub brightness: Brightness,
    pub sun_azimuth_deg: f32,
    pub sun_elevation_deg: f32,
    /// `None`: sky (or a background image when configured); `Some`: a flat colour.
    pub background_color: Option<[f32; 3]>,
    pub background_image: Option<usize>,
    pub ground_texture: usize,
    pub ground_offset: [f32; 2],
    pub light_add: f32,
    pub light_mul: f32,
    pub channel_add: [f32; 3],
    pub channel_mul: [f32; 3],
    pub noise_std: f32,
    pub noise_seed: u64,
    /// The ambient comes from an open sky over the ground (see `EnvConfig::sky_occlusion`).
    #[serde(default)]
    pub sky_occlusion: bool,
    /// The photographed environment that lights this view, if any (`EnvConfig::hdri`).
    #[serde(default)]
    pub hdri: Option<HdriDraw>,
}

/// One view's draw of a photographed environment.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HdriDraw {
    /// Index into `EnvConfig::hdri`.
    pub index: usize,
    pub rotation_deg: f32,
    pub exposure_stops: f32,
}

impl Condition {
    /// A plain condition: no photometric change, sky background, ground at the origin.
    pub fn plain(viewpoint: Viewpoint, brightness: Brightness) -> Self {
        Condition {
            viewpoint,
            brightness,
            sun_azimuth_deg: 135.0,
            sun_elevation_deg: 50.0,
            background_color: None,
            background_image: None,
            ground_texture: 0,
            ground_offset: [0.0; 2],
            light_add: 0.0,
            light_mul: 1.0,
            channel_add: [0.0; 3],
            channel_mul: [1.0; 3],
            noise_std: 0.0,
            noise_seed: 0,
            sky_occlusion: false,
            hdri: None,
        }
    }
}

/// A free viewpoint's azimuth (degrees) drawn within 30° of the front (0°) or the back (180°)
/// with probability `share`, and on the sides (30°–150°, 210°–330°) otherwise; uniform within
/// each sector. `share` = 1/3 is the uniform azimuth of [`Environment::sample`]'s free set.
pub fn azimuth_with_front_back_share(share: f32, rng: &mut impl Rng) -> f32 {
    let ends = rng.random_bool(share.clamp(0.0, 1.0) as f64);
    let far = rng.random_bool(0.5);
    if ends {
        let a =
            (rng.random_range(-30.0f32..30.0) + if far { 180.0 } else { 0.0 }).rem_euclid(360.0);
        // rem_euclid rounds a tiny negative angle up to 360.0 in f32: that is the front.
        if a >= 360.0 {
            0.0
        } else {
            a
        }
    } else {
        rng.random_range(30.0f32..150.0) + if far { 180.0 } else { 0.0 }
    }
}

/// Street-level views: `n` azimuths evenly around the object, elevations cycling through
/// 5–15°, at one distance ratio, plain photometrics.
pub fn street_views(n: usize, distance_ratio: f32, brightness: Brightness) -> Vec<Condition> {
    (0..n)
        .map(|k| {
            let az = 360.0 * k as f32 / n as f32 + 7.5;
            let el = 5.0 + 10.0 * ((k * 7) % n) as f32 / (n.max(2) - 1) as f32;
            Condition::plain(Viewpoint::new(az, el, distance_ratio), brightness)
        })
        .collect()
}

/// The environment: its config plus the loaded background, ground and HDR images.
pub struct Environment {
    pub config: EnvConfig,
    backgrounds: Vec<Arc<Texture>>,
    grounds: Vec<Arc<Texture>>,
    hdris: Vec<Arc<crate::ibl::EnvironmentMap>>,
}

impl Environment {
    pub fn new(config: EnvConfig) -> Result<Environment> {
        config.validate()?;
        let load = |p: &PathBuf| -> Result<Arc<Texture>> {
            let img = cac_core::io::load_rgb(p).context("environment image")?;
            Ok(Arc::new(Texture::from_rgb8(&img)))
        };
        let backgrounds = config
            .background_images
            .iter()
            .map(load)
            .collect::<Result<Vec<_>>>()?;
        let mut grounds = config
            .ground_textures
            .iter()
            .map(load)
            .collect::<Result<Vec<_>>>()?;
        if grounds.is_empty() {
            grounds.push(Arc::new(procedural_ground(256)));
        }
        let hdris = config
            .hdri
            .iter()
            .map(|h| crate::ibl::load(h).context("environment.hdri"))
            .collect::<Result<Vec<_>>>()?;
        Ok(Environment {
            config,
            backgrounds,
            grounds,
            hdris,
        })
    }

    /// Draws one condition.
    pub fn sample(
        &self,
        set: ViewpointSet,
        brightness: Brightness,
        rng: &mut impl Rng,
    ) -> Condition {
        let c = &self.config;
        let u = |rng: &mut dyn rand::RngCore, r: [f32; 2]| {
            if r[1] > r[0] {
                rng.random_range(r[0]..=r[1])
            } else {
                r[0]
            }
        };
        let azimuth = match set {
            ViewpointSet::Free => rng.random_range(0.0..360.0),
            ViewpointSet::Restricted => {
                let side = if rng.random_bool(0.5) { 90.0 } else { 270.0 };
                let half = 0.5 * c.restricted_alpha_deg;
                side + rng.random_range(-half..=half)
            }
        };
        // Uniform in solid angle between the elevation bounds.
        let (s0, s1) = (
            c.elevation_deg[0].to_radians().sin(),
            c.elevation_deg[1].to_radians().sin(),
        );
        let elevation = if s1 > s0 {
            rng.random_range(s0..=s1).asin().to_degrees()
        } else {
            c.elevation_deg[0]
        };
        let viewpoint = Viewpoint {
            azimuth_deg: azimuth,
            elevation_deg: elevation,
            distance_ratio: u(rng, c.distance_ratio),
            shift: [
                rng.random_range(-c.translate..=c.translate),
                rng.random_range(-c.translate..=c.translate),
            ],
        };
        let background_color = rng
            .random_bool(c.background_color_prob.clamp(0.0, 1.0) as f64)
            .then(|| [0, 1, 2].map(|_| u(rng, c.background_color)));
        let background_image = (!self.backgrounds.is_empty() && background_color.is_none())
            .then(|| rng.random_range(0..self.backgrounds.len()));
        let mut cond = Condition {
            viewpoint,
            brightness,
            sun_azimuth_deg: rng.random_range(0.0..360.0),
            sun_elevation_deg: u(rng, c.sun_elevation_deg),
            background_color,
            background_image,
            ground_texture: rng.random_range(0..self.grounds.len()),
            ground_offset: [
                rng.random_range(-500.0..500.0),
                rng.random_range(-500.0..500.0),
            ],
            light_add: rng.random_range(-c.light_add..=c.light_add),
            light_mul: u(rng, c.light_mul),
            channel_add: [0, 1, 2].map(|_| rng.random_range(-c.channel_add..=c.channel_add)),
            channel_mul: [0, 1, 2].map(|_| u(rng, c.channel_mul)),
            noise_std: u(rng, c.noise_std),
            noise_seed: rng.random(),
            // Drawn last, and only when asked for: the draws of every other field, and so the
            // protocol's views, stay as they were.
            sky_occlusion: c.sky_occlusion > 0.0 && rng.random_bool(c.sky_occlusion as f64),
            hdri: None,
        };
        // The environment is drawn from a stream of its own (seeded by the condition's noise
        // seed), so that listing environments leaves every other draw of every condition as it
        // was: the same viewpoints, with or without photographed light.
        if !self.hdris.is_empty() {
            let mut own = ChaCha8Rng::seed_from_u64(cond.noise_seed ^ 0x4844_5249_4C49_4748);
            cond.hdri = own.random_bool(c.hdri_share as f64).then(|| HdriDraw {
                index: own.random_range(0..self.hdris.len()),
                rotation_deg: u(&mut own, c.hdri_rotation_deg),
                exposure_stops: u(&mut own, c.hdri_exposure_stops),
            });
        }
        cond
    }

    /// Draws `n` conditions from a seed (same seed, same conditions).
    pub fn sample_n(
        &self,
        n: usize,
        set: ViewpointSet,
        brightness: Brightness,
        seed: u64,
    ) -> Vec<Condition> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| self.sample(set, brightness, &mut rng))
            .collect()
    }

    /// The lighting of a condition. Under a photographed environment its exposure is the light
    /// level (the brightness level then changes nothing).
    pub fn lighting(&self, cond: &Condition) -> Lighting {
        if let Some(h) = cond.hdri {
            let map = self
                .hdris
                .get(h.index)
                .unwrap_or_else(|| {
                    panic!(
                        "condition names environment {} of {}",
                        h.index,
                        self.hdris.len()
                    )
                })
                .clone();
            let ground_albedo = self.config.ground.then(|| {
                crate::light::mean_colour(self.ground(cond)).map(cac_core::colour::decode)
            });
            return Lighting {
                ambient: 0.0,
                sun: 0.0,
                sun_dir: glam::Vec3::Y,
                sky_occlusion: None,
                image: Some(crate::ibl::ImageLight::new(
                    map,
                    h.rotation_deg,
                    h.exposure_stops,
                    ground_albedo,
                    self.config.ibl,
                )),
            };
        }
        let lv = match cond.brightness {
            Brightness::Bright => self.config.bright,
            Brightness::Dark => self.config.dark,
        };
        let mut l = Lighting::sun_at(
            lv.ambient,
            lv.sun,
            cond.sun_azimuth_deg,
            cond.sun_elevation_deg,
        );
        if cond.sky_occlusion && self.config.ground {
            let [r, gr, b] = crate::light::mean_colour(self.ground(cond));
            l.sky_occlusion = Some((r + gr + b) / 3.0);
        }
        l
    }

    /// The file of environment `index` of `EnvConfig::hdri` (as resolved when it was read).
    pub fn hdri_path(&self, index: usize) -> &std::path::Path {
        &self.hdris[index].path
    }

    /// The ground texture a condition draws.
    fn ground(&self, cond: &Condition) -> &Arc<Texture> {
        &self.grounds[cond.ground_texture.min(self.grounds.len() - 1)]
    }

    /// The background and ground of a condition.
    pub fn backdrop(&self, cond: &Condition) -> Backdrop {
        let dim = match cond.brightness {
            Brightness::Bright => 1.0,
            Brightness::Dark => 0.4,
        };
        let background = match (cond.background_color, cond.background_image) {
            (Some(c), _) => Background::Color(c),
            (None, Some(i)) => {
                Background::Image(self.backgrounds[i.min(self.backgrounds.len() - 1)].clone())
            }
            (None, None) => Background::Sky {
                horizon: [0.80 * dim, 0.85 * dim, 0.90 * dim],
                zenith: [0.35 * dim, 0.55 * dim, 0.85 * dim],
                // Each view faces another part of the ring (phase from the ground offset).
                skyline: self.config.skyline.then(|| Skyline {
                    phase_deg: cond.ground_offset[0] * 0.72,
                    light: dim,
                }),
            },
        };
        let ground = self.config.ground.then(|| Ground {
            texture: self.ground(cond).clone(),
            tile_m: self.config.ground_tile_m,
            offset: Vec2::from(cond.ground_offset),
        });
        Backdrop { background, ground }
    }
}

/// A procedural ground texture: grey asphalt with fine grain and faint patches (tileable).
pub fn procedural_ground(res: usize) -> Texture {
    use cac_scene::generate::value_noise;
    let mut t = Texture::solid(res, res, [0.0; 3]);
    let period = 8.0;
    for y in 0..res {
        for x in 0..res {
            let (u, v) = (
                x as f32 / res as f32 * period,
                y as f32 / res as f32 * period,
            );
            // Tileable: blend noise at (u,v) and its wrap-around copies.
            let n = |f: f32, s: u32| {
                let (a, b) = (u * f, v * f);
                let p = period * f;
                let (wu, wv) = (u / period, v / period);
                let n00 = value_noise(a, b, s);
                let n10 = value_noise(a - p, b, s);
                let n01 = value_noise(a, b - p, s);
                let n11 = value_noise(a - p, b - p, s);
                (n00 * (1.0 - wu) + n10 * wu) * (1.0 - wv) + (n01 * (1.0 - wu) + n11 * wu) * wv
            };
            let g = 0.36 + 0.10 * n(1.0, 11) + 0.10 * (n(16.0, 12) - 0.5);
            t.texels[y * res + x] = [g * 0.97, g, g * 1.02];
        }
    }
    t
}
