//! Image-based lighting: a photographed HDR environment (an equirectangular map of linear
//! radiance, as Blender ships eight of them) as the light and the backdrop.
//!
//! The map is split once into a **sun** (the texels around the brightest one whose luminance
//! exceeds `sun_threshold` × the mean, moved into one directional light with a hard shadow) and
//! the **residual**, whose diffuse irradiance is carried by order-2 spherical harmonics
//! (Ramamoorthi & Hanrahan 2001: nine coefficients per channel, irradiance exact for the
//! residual's first three bands), over the upper and the lower hemisphere apart so that a ground
//! plane can replace the lower one with its own lit radiance. The body's occlusion of the
//! residual is a directional visibility ratio from `occlusion_rays` cosine-distributed rays
//! against the BVH; glossy reflections read a box-prefiltered copy of the residual (one level,
//! or a chain that rougher parts read blurrier levels of: `IblSettings::prefilter_levels`).
//!
//! Directions follow Blender's world mapping as `eval::blender` sets it up (the map's up is
//! cac's +Y, turned about it by `rotation_deg`), so Cycles and cac see the same world.
//! cac shades display values: a light of linear irradiance `E` lights a display albedo `a` as
//! `a × srgb(E / π)`, the conversion the Blender job uses for cac's own ambient.

use anyhow::{bail, Context, Result};
use cac_core::colour;
use glam::Vec3;
use std::f32::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The HDR environments Blender's package ships (`datafiles/studiolights/world/NAME.exr`, CC0).
pub const BLENDER_WORLDS: [&str; 8] = [
    "city",
    "courtyard",
    "forest",
    "interior",
    "night",
    "studio",
    "sunrise",
    "sunset",
];

/// Folders where Blender's `studiolights/world` may be installed (Debian's package first).
const WORLD_DIRS: [&str; 2] = [
    "/usr/share/blender/datafiles/studiolights/world",
    "/usr/local/share/blender/datafiles/studiolights/world",
];

/// The file of one of [`BLENDER_WORLDS`] by name, or `name` itself when it is an existing file.
pub fn resolve(name: &str) -> Result<PathBuf> {
    let p = Path::new(name);
    if p.is_file() {
        return Ok(p.to_path_buf());
    }
    if !BLENDER_WORLDS.contains(&name) {
        bail!(
            "HDR environment {name:?} is neither one of Blender's ({}) nor an existing image file",
            BLENDER_WORLDS.join(", ")
        );
    }
    WORLD_DIRS
        .iter()
        .map(|d| Path::new(d).join(format!("{name}.exr")))
        .find(|f| f.is_file())
        .with_context(|| {
            format!(
                "Blender's HDR environment {name:?} is not installed (looked in {}): apt-get install blender-data, or give the .exr file's path",
                WORLD_DIRS.join(", ")
            )
        })
}

/// The environment `name` ([`resolve`]: one of Blender's by name, or a file) read and split at
/// the default [`SUN_THRESHOLD`]; errors name it.
pub fn load(name: &str) -> Result<Arc<EnvironmentMap>> {
    let read = || EnvironmentMap::read(&resolve(name)?, SUN_THRESHOLD);
    Ok(Arc::new(
        read().with_context(|| format!("HDR environment {name:?}"))?,
    ))
}

/// A light's order-2 spherical-harmonic coefficients: 9 per channel.
pub type Sh9 = [[f32; 3]; 9];

/// The directional light taken out of a map: the excess radiance of its brightest region.
#[derive(Clone, Debug, PartialEq)]
pub struct MapSun {
    /// Unit vector towards the light, in the map's frame (rotation 0).
    pub dir: Vec3,
    /// Linear irradiance on a surface facing it, per channel.
    pub irradiance: [f32; 3],
}

/// An equirectangular HDR environment, read and split into sun and residual.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvironmentMap {
    /// The file it was read from.
    pub path: PathBuf,
    pub width: usize,
    pub height: usize,
    /// Linear radiance, row-major from the top row (the zenith), as read.
    pub radiance: Vec<[f32; 3]>,
    pub sun: Option<MapSun>,
    /// The residual's coefficients over the upper (`y > 0`) and the lower hemisphere, map frame.
    pub sh_upper: Sh9,
    pub sh_lower: Sh9,
    /// The coefficients of a radiance of 1 over the lower hemisphere (what a ground replaces).
    pub sh_lower_unit: [f32; 9],
    /// The residual box-filtered by [`REFLECTION_DOWNSAMPLE`] on each side, then halved per
    /// side level by level ([`REFLECTION_LEVELS`] levels, each with its width): what glossy
    /// reflections read, blurrier for rougher parts.
    reflections: Vec<(Vec<[f32; 3]>, usize)>,
}

/// How much smaller, per side, the sharpest map that glossy reflections read is.
pub const REFLECTION_DOWNSAMPLE: usize = 8;

/// Levels of the reflection chain (the sharpest, then each half as wide as the one before).
pub const REFLECTION_LEVELS: usize = 6;

/// Luminance of linear Rec. 709 RGB.
fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// The unit direction (map frame) through the centre of texel `(x, y)` of a `w x h` map.
fn texel_dir(x: usize, y: usize, w: usize, h: usize) -> Vec3 {
    let u = (x as f32 + 0.5) / w as f32;
    let el = (0.5 - (y as f32 + 0.5) / h as f32) * PI;
    let phi = (0.5 - u) * 2.0 * PI;
    Vec3::new(el.cos() * phi.cos(), el.sin(), -el.cos() * phi.sin())
}

/// `d` turned by `angle` (radians) about +Y, in the sense Blender's mapping turns the world's
/// azimuth (`atan2(-z, x)` grows by `angle`).
pub(crate) fn turn(d: Vec3, angle: f32) -> Vec3 {
    let (s, c) = angle.sin_cos();
    let (a, b) = (d.x, -d.z);
    Vec3::new(a * c - b * s, d.y, -(a * s + b * c))
}

/// Continuous texel coordinates (x along the row, y down from the top) of map-frame direction `d`.
fn map_coords(d: Vec3, w: usize, h: usize) -> (f32, f32) {
    let phi = (-d.z).atan2(d.x);
    let u = (0.5 - phi / (2.0 * PI)).rem_euclid(1.0);
    let el = d.y.clamp(-1.0, 1.0).asin();
    (u * w as f32, (0.5 - el / PI) * h as f32)
}

/// Bilinear lookup in an equirectangular image (wrapping in azimuth, clamped at the poles).
fn lookup(img: &[[f32; 3]], w: usize, h: usize, d: Vec3) -> [f32; 3] {
    let (x, y) = map_coords(d, w, h);
    let (x, y) = (x - 0.5, (y - 0.5).clamp(0.0, h as f32 - 1.0));
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let xi = |k: f32| (k as i64).rem_euclid(w as i64) as usize;
    let yi = |k: f32| (k as usize).min(h - 1);
    let mut out = [0.0f32; 3];
    for (xx, yy, wt) in [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x0 + 1.0, y0, fx * (1.0 - fy)),
        (x0, y0 + 1.0, (1.0 - fx) * fy),
        (x0 + 1.0, y0 + 1.0, fx * fy),
    ] {
        let t = img[yi(yy) * w + xi(xx)];
        for c in 0..3 {
            out[c] += wt * t[c];
        }
    }
    out
}

/// The nine real spherical harmonics up to band 2 at unit direction `d`.
pub fn sh_basis(d: Vec3) -> [f32; 9] {
    let (x, y, z) = (d.x, d.y, d.z);
    [
        0.282_095,
        0.488_603 * y,
        0.488_603 * z,
        0.488_603 * x,
        1.092_548 * x * y,
        1.092_548 * y * z,
        0.315_392 * (3.0 * z * z - 1.0),
        1.092_548 * x * z,
        0.546_274 * (x * x - y * y),
    ]
}

/// The cosine lobe's convolution factors per band (π, 2π/3, π/4).
const BAND_FACTOR: [f32; 3] = [PI, 2.0 * PI / 3.0, PI / 4.0];

/// The band of coefficient `k`.
fn band(k: usize) -> usize {
    match k {
        0 => 0,
        1..=3 => 1,
        _ => 2,
    }
}

/// Irradiance (linear, per channel) at a surface of unit normal `n` (map frame) from a light of
/// coefficients `sh`, with the bands up to `order` (0–2).
pub fn sh_irradiance(sh: &Sh9, n: Vec3, order: usize) -> [f32; 3] {
    let y = sh_basis(n);
    let mut e = [0.0f32; 3];
    for (k, yk) in y.iter().enumerate() {
        if band(k) > order {
            break;
        }
        let f = BAND_FACTOR[band(k)] * yk;
        for c in 0..3 {
            e[c] += f * sh[k][c];
        }
    }
    e.map(|v| v.max(0.0))
}

/// Radiance (linear, per channel) of a light of coefficients `sh` in direction `d` (map frame).
pub fn sh_radiance(sh: &Sh9, d: Vec3) -> [f32; 3] {
    let y = sh_basis(d);
    let mut l = [0.0f32; 3];
    for (k, yk) in y.iter().enumerate() {
        for c in 0..3 {
            l[c] += yk * sh[k][c];
        }
    }
    l
}

impl EnvironmentMap {
    /// Reads an equirectangular environment (OpenEXR, including Blender's DWAB-compressed
    /// files, or Radiance HDR) and splits it: texels above `sun_threshold` × the mean luminance
    /// within 15° of the brightest texel become the sun (default threshold: [`SUN_THRESHOLD`]).
    pub fn read(path: &Path, sun_threshold: f32) -> Result<EnvironmentMap> {
        let img = image::open(path)
            .with_context(|| format!("reading HDR environment {}", path.display()))?
            .into_rgb32f();
        let (w, h) = (img.width() as usize, img.height() as usize);
        let radiance: Vec<[f32; 3]> = img.pixels().map(|p| p.0).collect();
        Self::from_radiance(path.to_path_buf(), w, h, radiance, sun_threshold)
    }

    /// [`EnvironmentMap::read`] of a map already in memory (linear radiance from the top row).
    pub fn from_radiance(
        path: PathBuf,
        w: usize,
        h: usize,
        radiance: Vec<[f32; 3]>,
        sun_threshold: f32,
    ) -> Result<EnvironmentMap> {
        check_radiance(&path, w, h, &radiance)?;
        // Lossy compression (Blender's maps are DWAB) rings slightly below zero: no light.
        let radiance: Vec<[f32; 3]> = radiance
            .into_iter()
            .map(|t| t.map(|v| v.max(0.0)))
            .collect();
        let (residual, sun) = split_sun(&radiance, w, h, sun_threshold);
        let (sh_upper, sh_lower, sh_lower_unit) = residual_sh(&residual, w, h);
        let reflections = reflection_chain(&residual, w, h);
        Ok(EnvironmentMap {
            path,
            width: w,
            height: h,
            radiance,
            sun,
            sh_upper,
            sh_lower,
            sh_lower_unit,
            reflections,
        })
    }

    /// The map's full radiance in map-frame direction `d` (what the camera sees of it).
    pub fn radiance_at(&self, d: Vec3) -> [f32; 3] {
        lookup(&self.radiance, self.width, self.height, d)
    }

    /// The prefiltered residual at `level` of the reflection chain (0: the sharpest; clamped to
    /// the last) in map-frame direction `d` (what glossy parts reflect).
    pub fn reflection_at(&self, d: Vec3, level: usize) -> [f32; 3] {
        let (texels, rw) = &self.reflections[level.min(self.reflections.len() - 1)];
        lookup(texels, *rw, texels.len() / rw, d)
    }

    /// The angle (radians) a texel of the sharpest reflection level spans in elevation.
    fn reflection_texel_angle(&self) -> f32 {
        let (texels, rw) = &self.reflections[0];
        PI / (texels.len() / rw) as f32
    }
}

/// Refuses a map that is too small, not `w x h`, not equirectangular or not finite.
fn check_radiance(path: &Path, w: usize, h: usize, radiance: &[[f32; 3]]) -> Result<()> {
    if w < 2 || h < 2 || radiance.len() != w * h {
        bail!(
            "HDR environment {}: {w}x{h} is not a usable map",
            path.display()
        );
    }
    if w != 2 * h {
        bail!(
            "HDR environment {}: {w}x{h} is not equirectangular (width must be twice the height)",
            path.display()
        );
    }
    if let Some(i) = radiance
        .iter()
        .position(|t| t.iter().any(|v| !v.is_finite()))
    {
        bail!(
            "HDR environment {}: texel ({}, {}) is {:?} (radiance must be finite)",
            path.display(),
            i % w,
            i / w,
            radiance[i]
        );
    }
    Ok(())
}

/// The solid angle of a texel of row `y` of a `w x h` equirectangular map.
fn texel_solid_angle(y: usize, w: usize, h: usize) -> f32 {
    let el = (0.5 - (y as f32 + 0.5) / h as f32) * PI;
    (2.0 * PI / w as f32) * (PI / h as f32) * el.cos()
}

/// Splits `radiance` into the residual and the sun: the excess over `sun_threshold` × the mean
/// luminance of the texels within 15° of the brightest one (no sun when none exceeds it).
fn split_sun(
    radiance: &[[f32; 3]],
    w: usize,
    h: usize,
    sun_threshold: f32,
) -> (Vec<[f32; 3]>, Option<MapSun>) {
    let d_omega = |y: usize| texel_solid_angle(y, w, h);
    let (mut sum, mut area) = (0.0f64, 0.0f64);
    let (mut peak, mut peak_lum) = (0usize, -1.0f32);
    for (i, t) in radiance.iter().enumerate() {
        let (l, dw) = (luminance(*t), d_omega(i / w));
        sum += (l * dw) as f64;
        area += dw as f64;
        if l > peak_lum {
            (peak, peak_lum) = (i, l);
        }
    }
    let threshold = sun_threshold * (sum / area) as f32;
    let peak_dir = texel_dir(peak % w, peak / w, w, h);
    let cos_cone = 15f32.to_radians().cos();
    let mut residual = radiance.to_vec();
    let (mut sun_e, mut sun_dir) = ([0.0f32; 3], Vec3::ZERO);
    if threshold > 0.0 && peak_lum > threshold {
        for (i, t) in residual.iter_mut().enumerate() {
            let (x, y) = (i % w, i / w);
            let l = luminance(*t);
            let d = texel_dir(x, y, w, h);
            if l > threshold && d.dot(peak_dir) >= cos_cone {
                let k = threshold / l;
                let dw = d_omega(y);
                for c in 0..3 {
                    sun_e[c] += t[c] * (1.0 - k) * dw;
                    t[c] *= k;
                }
                sun_dir += d * (l - threshold) * dw;
            }
        }
    }
    let sun = (luminance(sun_e) > 0.0).then(|| MapSun {
        dir: sun_dir.normalize(),
        irradiance: sun_e,
    });
    (residual, sun)
}

/// The residual's spherical-harmonic coefficients over the upper and the lower hemisphere, and
/// those of a unit radiance over the lower one.
fn residual_sh(residual: &[[f32; 3]], w: usize, h: usize) -> (Sh9, Sh9, [f32; 9]) {
    let (mut sh_upper, mut sh_lower) = ([[0.0f32; 3]; 9], [[0.0f32; 3]; 9]);
    let mut sh_lower_unit = [0.0f32; 9];
    for y in 0..h {
        let dw = texel_solid_angle(y, w, h);
        for x in 0..w {
            let d = texel_dir(x, y, w, h);
            let basis = sh_basis(d);
            let t = residual[y * w + x];
            let upper = d.y > 0.0;
            let sh = if upper { &mut sh_upper } else { &mut sh_lower };
            for k in 0..9 {
                for c in 0..3 {
                    sh[k][c] += t[c] * basis[k] * dw;
                }
                if !upper {
                    sh_lower_unit[k] += basis[k] * dw;
                }
            }
        }
    }
    (sh_upper, sh_lower, sh_lower_unit)
}

/// The reflection chain of the residual: box-filtered by [`REFLECTION_DOWNSAMPLE`] per side,
/// then each of the [`REFLECTION_LEVELS`] levels half as wide as the one before.
fn reflection_chain(residual: &[[f32; 3]], w: usize, h: usize) -> Vec<(Vec<[f32; 3]>, usize)> {
    let f = REFLECTION_DOWNSAMPLE;
    let mut reflections = vec![box_filter(residual, w, h, (w / f).max(1), (h / f).max(1))];
    while reflections.len() < REFLECTION_LEVELS {
        let (prev, pw) = reflections.last().expect("the sharpest level");
        let ph = prev.len() / pw;
        let next = box_filter(prev, *pw, ph, (pw / 2).max(1), (ph / 2).max(1));
        reflections.push(next);
    }
    reflections
}

/// `src` (`w x h`) averaged into `ow x oh` boxes (each source texel into the box it falls in,
/// each box divided by the texels it got, so a constant map stays constant at any size).
fn box_filter(
    src: &[[f32; 3]],
    w: usize,
    h: usize,
    ow: usize,
    oh: usize,
) -> (Vec<[f32; 3]>, usize) {
    let index = |i: usize| ((i / w) * oh / h) * ow + (i % w) * ow / w;
    let mut count = vec![0u32; ow * oh];
    for i in 0..src.len() {
        count[index(i)] += 1;
    }
    let mut out = vec![[0.0f32; 3]; ow * oh];
    for (i, t) in src.iter().enumerate() {
        let b = index(i);
        let k = 1.0 / count[b] as f32;
        for c in 0..3 {
            out[b][c] += t[c] * k;
        }
    }
    (out, ow)
}

/// The default sun threshold: texels brighter than 20 × the map's mean luminance.
pub const SUN_THRESHOLD: f32 = 20.0;

/// How finely cac's renderer evaluates an environment's light (each knob trades error against
/// run time; `cac bench ibl` measures them against Cycles).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IblSettings {
    /// Spherical-harmonic bands of the residual's irradiance: 0 (its mean), 1 or 2.
    pub sh_order: usize,
    /// Rays per shading sample that find the body's occlusion of the residual (0: unoccluded).
    pub occlusion_rays: usize,
    /// Levels of the reflection chain glossy parts choose from by their roughness (1: every part
    /// reads the sharpest, 1/8 per side; up to [`REFLECTION_LEVELS`], each half as wide).
    pub prefilter_levels: usize,
}

impl Default for IblSettings {
    fn default() -> Self {
        IblSettings {
            sh_order: 2,
            occlusion_rays: 4,
            prefilter_levels: 1,
        }
    }
}

impl IblSettings {
    /// Refuses orders above 2, more than 1024 occlusion rays and prefilter levels outside
    /// 1..=[`REFLECTION_LEVELS`], naming the values.
    pub fn check(&self) -> anyhow::Result<()> {
        if self.sh_order > 2 || self.occlusion_rays > 1024 {
            anyhow::bail!(
                "sh_order {} must be 0, 1 or 2 and occlusion_rays {} at most 1024",
                self.sh_order,
                self.occlusion_rays
            );
        }
        if !(1..=REFLECTION_LEVELS).contains(&self.prefilter_levels) {
            anyhow::bail!(
                "prefilter_levels {} must be within 1..={REFLECTION_LEVELS}",
                self.prefilter_levels
            );
        }
        Ok(())
    }

    /// The reflection level a part of GGX roughness `roughness` reads
    /// ([`cac_scene::Material::roughness`]): the one whose texels span about its lobe's width,
    /// α = roughness² radians; 0 with one level.
    pub fn reflection_level(&self, roughness: f32, texel_angle: f32) -> usize {
        if self.prefilter_levels <= 1 {
            return 0;
        }
        let lobe = roughness * roughness;
        let level = (lobe / texel_angle).log2().round();
        (level.max(0.0) as usize).min(self.prefilter_levels - 1)
    }
}

/// An environment as one view's light: the map, turned and scaled, over an optional ground.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageLight {
    pub map: Arc<EnvironmentMap>,
    /// Turn about +Y, degrees (Blender's mapping rotation).
    pub rotation_deg: f32,
    /// Radiance scale (1: as photographed; an exposure of `s` stops is `2^s`).
    pub strength: f32,
    /// The ground's mean albedo (linear) when a ground plane replaces the lower hemisphere.
    pub ground_albedo: Option<[f32; 3]>,
    pub settings: IblSettings,
}

impl ImageLight {
    /// `map` turned by `rotation_deg` about +Y, at an exposure of `exposure_stops` (radiance ×
    /// 2^stops), over a ground of linear albedo `ground_albedo` if there is one.
    pub fn new(
        map: Arc<EnvironmentMap>,
        rotation_deg: f32,
        exposure_stops: f32,
        ground_albedo: Option<[f32; 3]>,
        settings: IblSettings,
    ) -> ImageLight {
        ImageLight {
            map,
            rotation_deg,
            strength: exposure_stops.exp2(),
            ground_albedo,
            settings,
        }
    }

    fn to_map(&self, d: Vec3) -> Vec3 {
        turn(d, self.rotation_deg.to_radians())
    }

    /// Unit vector towards the map's sun (world frame) and its linear irradiance, if it has one.
    pub fn sun(&self) -> Option<(Vec3, [f32; 3])> {
        self.map.sun.as_ref().map(|s| {
            (
                turn(s.dir, -self.rotation_deg.to_radians()),
                s.irradiance.map(|e| e * self.strength),
            )
        })
    }

    /// The radiance of the lit ground (linear), if there is a ground: its albedo times the
    /// irradiance of an upward surface over π (the body's shadow on it is not in this term).
    pub fn ground_radiance(&self) -> Option<[f32; 3]> {
        let albedo = self.ground_albedo?;
        let mut e = sh_irradiance(&self.map.sh_upper, Vec3::Y, self.settings.sh_order);
        if let Some((dir, s)) = self.sun() {
            for c in 0..3 {
                e[c] += s[c] * dir.y.max(0.0) / self.strength;
            }
        }
        Some([0, 1, 2].map(|c| albedo[c] * e[c] * self.strength / PI))
    }

    /// The residual's coefficients (map frame, scaled by the strength) as a surface in the
    /// scene sees them: the upper hemisphere of the map, and below either the map or the lit
    /// ground.
    pub fn residual_sh(&self) -> Sh9 {
        let m = &self.map;
        let below = self.ground_radiance();
        let mut sh = [[0.0f32; 3]; 9];
        // k indexes three tables of the nine coefficients alike.
        #[allow(clippy::needless_range_loop)]
        for k in 0..9 {
            for c in 0..3 {
                let lower = match below {
                    Some(g) => g[c] * m.sh_lower_unit[k] / self.strength,
                    None => m.sh_lower[k][c],
                };
                sh[k][c] = (m.sh_upper[k][c] + lower) * self.strength;
            }
        }
        sh
    }

    /// The residual's irradiance at world-frame normal `n` from coefficients `sh`
    /// ([`ImageLight::residual_sh`]).
    pub fn irradiance(&self, sh: &Sh9, n: Vec3) -> [f32; 3] {
        sh_irradiance(sh, self.to_map(n), self.settings.sh_order)
    }

    /// The residual's luminance arriving from world direction `d` (weights of occlusion rays).
    pub fn residual_luminance(&self, sh: &Sh9, d: Vec3) -> f32 {
        luminance(sh_radiance(sh, self.to_map(d))).max(0.0)
    }

    /// What the camera sees along world direction `d` (display value per channel).
    pub fn backdrop(&self, d: Vec3) -> [f32; 3] {
        let l = self.map.radiance_at(self.to_map(d));
        l.map(|v| colour::encode(v * self.strength))
    }

    /// What a glossy part of GGX roughness `roughness` reflects along world direction `r`
    /// (display value per channel): the lit ground below the horizon when there is one, the
    /// prefiltered residual above, at the level its roughness picks ([`IblSettings`]).
    pub fn reflected(&self, r: Vec3, roughness: f32) -> [f32; 3] {
        let level = self
            .settings
            .reflection_level(roughness, self.map.reflection_texel_angle());
        let l = match self.ground_radiance() {
            Some(g) if r.y < 0.0 => g,
            _ => self
                .map
                .reflection_at(self.to_map(r), level)
                .map(|v| v * self.strength),
        };
        l.map(colour::encode)
    }
}

/// `n` directions about `normal`, cosine-distributed (stratified on a spiral, turned by
/// `phase` in [0, 1) so that neighbouring samples do not share one pattern).
pub(crate) fn cosine_directions(normal: Vec3, n: usize, phase: f32) -> impl Iterator<Item = Vec3> {
    let (t, b) = normal.any_orthonormal_pair();
    let golden = 2.399_963_f32;
    (0..n).map(move |k| {
        let r2 = (k as f32 + 0.5) / n as f32;
        let (s, c) = (golden * k as f32 + phase * 2.0 * PI).sin_cos();
        let r = r2.sqrt();
        (t * (r * c) + b * (r * s) + normal * (1.0 - r2).max(0.0).sqrt()).normalize()
    })
}

#[cfg(test)]
// The tests index the nine coefficients' three channels side by side.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A smooth seeded map (a few broad lobes), linear radiance.
    fn smooth_map(w: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let lobes: Vec<(Vec3, [f32; 3])> = (0..4)
            .map(|_| {
                let d = Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0;
                (
                    d.normalize(),
                    [0, 1, 2].map(|_| rng.random_range(0.2f32..1.5)),
                )
            })
            .collect();
        let h = w / 2;
        (0..w * h)
            .map(|i| {
                let d = texel_dir(i % w, i / w, w, h);
                let mut c = [0.1f32; 3];
                for (ld, lc) in &lobes {
                    let k = d.dot(*ld).max(0.0).powi(2);
                    for j in 0..3 {
                        c[j] += lc[j] * k;
                    }
                }
                c
            })
            .collect()
    }

    /// Irradiance at `n` by summing the whole map (the reference SH is held to).
    fn brute_irradiance(m: &EnvironmentMap, n: Vec3) -> [f32; 3] {
        let (w, h) = (m.width, m.height);
        let mut e = [0.0f64; 3];
        for y in 0..h {
            let el = (0.5 - (y as f32 + 0.5) / h as f32) * PI;
            let dw = (2.0 * PI / w as f32) * (PI / h as f32) * el.cos();
            for x in 0..w {
                let d = texel_dir(x, y, w, h);
                let k = (d.dot(n).max(0.0) * dw) as f64;
                let t = m.radiance[y * w + x];
                for c in 0..3 {
                    e[c] += t[c] as f64 * k;
                }
            }
        }
        e.map(|v| v as f32)
    }

    #[test]
    fn a_uniform_map_gives_pi_times_its_radiance_on_every_surface() {
        let m = EnvironmentMap::from_radiance("u".into(), 64, 32, vec![[0.5; 3]; 64 * 32], 20.0)
            .unwrap();
        assert!(m.sun.is_none(), "a uniform map has no sun");
        let mut sh = m.sh_upper;
        for k in 0..9 {
            for c in 0..3 {
                sh[k][c] += m.sh_lower[k][c];
            }
        }
        for n in [
            Vec3::Y,
            -Vec3::Y,
            Vec3::X,
            Vec3::new(0.3, -0.5, 0.8).normalize(),
        ] {
            let e = sh_irradiance(&sh, n, 2);
            for c in 0..3 {
                assert!((e[c] - 0.5 * PI).abs() < 2e-3 * PI, "{n}: {e:?}");
            }
        }
    }

    #[test]
    fn order_two_irradiance_is_within_three_percent_of_the_summed_map() {
        let w = 128;
        let m = EnvironmentMap::from_radiance("s".into(), w, w / 2, smooth_map(w, 7), 1e9).unwrap();
        let mut sh = m.sh_upper;
        for k in 0..9 {
            for c in 0..3 {
                sh[k][c] += m.sh_lower[k][c];
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (mut worst, mut worst0) = (0.0f32, 0.0f32);
        for _ in 0..64 {
            let n = (Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0).normalize();
            let want = brute_irradiance(&m, n);
            let (got, got0) = (sh_irradiance(&sh, n, 2), sh_irradiance(&sh, n, 0));
            for c in 0..3 {
                worst = worst.max((got[c] - want[c]).abs() / want[c]);
                worst0 = worst0.max((got0[c] - want[c]).abs() / want[c]);
            }
        }
        assert!(worst < 0.03, "order 2: worst relative error {worst}");
        assert!(
            worst0 > 3.0 * worst,
            "order 0 ({worst0}) should be far coarser than order 2"
        );
    }

    /// A constant map stays constant on every level of the chain whatever its size, also where
    /// the boxes do not divide it evenly (2000×1000 halves to odd sides; 100×50 reaches 1 px
    /// early; 36×18).
    #[test]
    fn a_constant_map_is_constant_on_every_reflection_level() {
        for (w, h) in [(2000usize, 1000usize), (100, 50), (36, 18), (1024, 512)] {
            let m = EnvironmentMap::from_radiance("c".into(), w, h, vec![[0.7; 3]; w * h], 1e9)
                .unwrap();
            for (k, (texels, rw)) in m.reflections.iter().enumerate() {
                for (i, t) in texels.iter().enumerate() {
                    assert!(
                        t.iter().all(|v| (v - 0.7).abs() < 1e-5),
                        "{w}x{h} level {k} ({rw} wide) texel {i}: {t:?}"
                    );
                }
            }
        }
    }

    /// The reflection chain: every level keeps the residual's texel mean; a narrow bright patch
    /// spreads and dims level by level; and the level a part reads follows its roughness (one
    /// level: always the sharpest).
    #[test]
    fn rougher_parts_read_blurrier_levels_of_an_energy_keeping_chain() {
        let (w, h) = (256usize, 128usize);
        let mut rad = vec![[0.2f32; 3]; w * h];
        // A 4×4-texel patch 4× the background (under the sun threshold, so it stays residual).
        for y in 60..64 {
            for x in 100..104 {
                rad[y * w + x] = [0.8; 3];
            }
        }
        let m = EnvironmentMap::from_radiance("p".into(), w, h, rad, 1e9).unwrap();
        let mean = |(t, _): &(Vec<[f32; 3]>, usize)| {
            t.iter().map(|c| c[0] as f64).sum::<f64>() / t.len() as f64
        };
        assert_eq!(m.reflections.len(), REFLECTION_LEVELS);
        let m0 = mean(&m.reflections[0]);
        let peak = texel_dir(101, 61, w, h);
        let mut last = f32::INFINITY;
        for (k, level) in m.reflections.iter().enumerate() {
            assert!(
                (mean(level) - m0).abs() < 1e-5 * m0,
                "level {k} mean {}",
                mean(level)
            );
            let p = m.reflection_at(peak, k)[0];
            assert!(p <= last + 1e-6 && p > 0.2, "level {k}: {p} after {last}");
            last = p;
        }
        assert!(
            last < m.reflection_at(peak, 0)[0] * 0.7,
            "the patch did not spread"
        );
        let texel = m.reflection_texel_angle();
        let rough = |n: f32| {
            let mut mat = cac_scene::Material::plain("m", [0.5; 3]);
            mat.shininess = n;
            mat.roughness()
        };
        let chain = IblSettings {
            prefilter_levels: REFLECTION_LEVELS,
            ..IblSettings::default()
        };
        let levels: Vec<usize> = [1000.0, 120.0, 40.0, 16.0, 8.0, 1.0]
            .iter()
            .map(|&n| chain.reflection_level(rough(n), texel))
            .collect();
        assert!(levels.windows(2).all(|p| p[0] <= p[1]), "{levels:?}");
        assert!(levels[0] < levels[5], "{levels:?}");
        assert!(levels.iter().all(|&l| l < REFLECTION_LEVELS));
        // Blender's 1024×512 maps: the sharpest level's texels span π/64; the pickup's body paint
        // (n = 40) reads 1/32 (level 2), its glass (n = 120) 1/16 (level 1).
        let blender = std::f32::consts::PI / 64.0;
        assert_eq!(chain.reflection_level(rough(40.0), blender), 2);
        assert_eq!(chain.reflection_level(rough(120.0), blender), 1);
        let one = IblSettings::default();
        assert!([1000.0, 40.0, 1.0]
            .iter()
            .all(|&n| one.reflection_level(rough(n), texel) == 0));
        assert!(IblSettings {
            prefilter_levels: 0,
            ..one
        }
        .check()
        .is_err());
        assert!(IblSettings {
            prefilter_levels: REFLECTION_LEVELS + 1,
            ..one
        }
        .check()
        .is_err());
    }

    #[test]
    fn the_sun_takes_the_bright_spot_and_conserves_its_energy() {
        let (w, h) = (128, 64);
        let mut rad = smooth_map(w, 11);
        let (sx, sy) = (40, 20);
        rad[sy * w + sx] = [4000.0, 3800.0, 3500.0];
        let m = EnvironmentMap::from_radiance("s".into(), w, h, rad.clone(), 20.0).unwrap();
        let sun = m.sun.as_ref().expect("the spot is a sun");
        assert!(
            sun.dir.dot(texel_dir(sx, sy, w, h)) > 0.9999,
            "{:?}",
            sun.dir
        );
        // Irradiance facing the sun: sun + residual equals the whole map's.
        let n = sun.dir;
        let mut sh = m.sh_upper;
        for k in 0..9 {
            for c in 0..3 {
                sh[k][c] += m.sh_lower[k][c];
            }
        }
        let res = sh_irradiance(&sh, n, 2);
        let want = brute_irradiance(&m, n);
        for c in 0..3 {
            let got = res[c] + sun.irradiance[c];
            assert!(
                (got - want[c]).abs() / want[c] < 0.03,
                "{c}: {got} vs {}",
                want[c]
            );
        }
    }

    #[test]
    fn directions_and_texels_map_onto_each_other() {
        let (w, h) = (64, 32);
        for (x, y) in [(0, 0), (10, 5), (31, 16), (63, 31), (40, 20)] {
            let d = texel_dir(x, y, w, h);
            let (u, v) = map_coords(d, w, h);
            assert!((u - (x as f32 + 0.5)).abs() < 1e-3 && (v - (y as f32 + 0.5)).abs() < 1e-3);
            for a in [0.0f32, 0.7, -2.0] {
                let back = turn(turn(d, a), -a);
                assert!((back - d).length() < 1e-5);
            }
        }
        // Blender's convention: the map's centre column looks along +X, its top row up.
        assert!(texel_dir(w / 2, h / 2, w, h).dot(Vec3::X) > 0.99);
        assert!(texel_dir(3, 0, w, h).y > 0.99);
    }

    #[test]
    fn bad_maps_are_refused_naming_the_file_and_the_texel() {
        let mut rad = vec![[0.2f32; 3]; 64 * 32];
        rad[5 * 64 + 3] = [f32::NAN, 0.0, 0.0];
        let e = EnvironmentMap::from_radiance("bad.exr".into(), 64, 32, rad, 20.0).unwrap_err();
        let s = e.to_string();
        assert!(s.contains("bad.exr") && s.contains("(3, 5)"), "{s}");
        let e = EnvironmentMap::from_radiance("sq.exr".into(), 32, 32, vec![[0.0; 3]; 1024], 20.0)
            .unwrap_err();
        assert!(e.to_string().contains("equirectangular"), "{e}");
        // A black map and a saturated one stay finite.
        for v in [0.0f32, 6.0e4] {
            let m = EnvironmentMap::from_radiance("k".into(), 64, 32, vec![[v; 3]; 2048], 20.0)
                .unwrap();
            let light = ImageLight {
                map: Arc::new(m),
                rotation_deg: 30.0,
                strength: 1.0,
                ground_albedo: Some([0.1; 3]),
                settings: IblSettings::default(),
            };
            let sh = light.residual_sh();
            let e = light.irradiance(&sh, Vec3::new(0.2, -0.9, 0.1).normalize());
            assert!(e.iter().all(|v| v.is_finite()), "{e:?}");
            assert!(light.backdrop(Vec3::Y).iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn cosine_directions_have_the_cosine_mean() {
        // The mean of n·d over a cosine-distributed set is 2/3.
        let n = Vec3::new(0.2, 0.9, -0.3).normalize();
        let m: f32 = cosine_directions(n, 256, 0.37)
            .map(|d| d.dot(n))
            .sum::<f32>()
            / 256.0;
        assert!((m - 2.0 / 3.0).abs() < 0.01, "{m}");
        assert!(cosine_directions(n, 64, 0.1).all(|d| d.dot(n) >= 0.0));
    }
}
