//! The world around the object, described once: light (ambient, one sun, the open sky's
//! occlusion), the ground plane and the backdrop, and what they show along a ray. The renderer
//! shades with it ([`super::shade`]), the evaluation conditions produce it
//! ([`super::environment`]), the physical twin builds it from a rig, and the Blender job is
//! written from it, so every renderer is told the same scene.

use cac_scene::Texture;
use glam::{Vec2, Vec3};
use std::sync::Arc;

/// Ambient plus a directional sun.
#[derive(Clone, Debug, PartialEq)]
pub struct Lighting {
    pub ambient: f32,
    pub sun: f32,
    /// Unit vector towards the sun.
    pub sun_dir: Vec3,
    /// `None`: the object's ambient light comes from every direction alike. `Some(albedo)`: it
    /// comes from an open sky over a ground of that albedo (display value): a surface whose
    /// normal has height `n_y` sees the sky with weight `(1 + n_y) / 2` and the lit ground, whose
    /// light is `albedo × (ambient + sun × sun_y)`, with weight `(1 − n_y) / 2`, as a physical
    /// renderer finds it (the body's occlusion of itself is not modelled).
    pub sky_occlusion: Option<f32>,
    /// A photographed environment that lights the view instead of the ambient and the sun
    /// (which are then 0), and is its backdrop ([`crate::ibl`]).
    pub image: Option<crate::ibl::ImageLight>,
}

impl Lighting {
    /// A sun at the given azimuth/elevation (degrees).
    pub fn sun_at(ambient: f32, sun: f32, azimuth_deg: f32, elevation_deg: f32) -> Self {
        let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
        Lighting {
            ambient,
            sun,
            sun_dir: Vec3::new(e.cos() * a.cos(), e.sin(), e.cos() * a.sin()),
            sky_occlusion: None,
            image: None,
        }
    }
}

/// What is behind the object.
#[derive(Clone, Debug)]
pub enum Background {
    /// A vertical gradient from horizon to zenith colour, with an optional distant skyline.
    Sky {
        horizon: [f32; 3],
        zenith: [f32; 3],
        skyline: Option<super::skyline::Skyline>,
    },
    /// A flat colour.
    Color([f32; 3]),
    /// An image stretched over the whole frame (screen space).
    Image(Arc<Texture>),
}

/// A textured ground plane at `y = 0`.
#[derive(Clone, Debug)]
pub struct Ground {
    pub texture: Arc<Texture>,
    /// Metres covered by one repetition of the texture.
    pub tile_m: f32,
    /// Shift of the texture (metres), so each view sits at another place of the scene.
    pub offset: Vec2,
}

/// Background and optional ground.
#[derive(Clone, Debug)]
pub struct Backdrop {
    pub background: Background,
    pub ground: Option<Ground>,
}

/// The mean texel of a texture (what reflections show of an image background).
pub fn mean_colour(t: &Texture) -> [f32; 3] {
    let n = t.texels.len().max(1) as f32;
    t.texels.iter().fold([0.0f32; 3], |a, t| {
        [a[0] + t[0] / n, a[1] + t[1] / n, a[2] + t[2] / n]
    })
}

/// The colour the environment shows in direction `r` (sky above the horizon, lit ground below),
/// for reflections.
pub(crate) fn environment_colour(
    backdrop: &Backdrop,
    light: &Lighting,
    image_mean: [f32; 3],
    r: Vec3,
) -> [f32; 3] {
    if r.y < 0.0 && backdrop.ground.is_some() {
        let k = (light.ambient + light.sun * light.sun_dir.y.max(0.0)) * 0.35;
        return [k; 3];
    }
    match &backdrop.background {
        Background::Sky {
            horizon, zenith, ..
        } => {
            let t = r.y.max(0.0).sqrt();
            [0, 1, 2].map(|i| horizon[i] * (1.0 - t) + zenith[i] * t)
        }
        Background::Color(c) => *c,
        Background::Image(_) => image_mean,
    }
}

/// The backdrop's colour seen along the view ray `dir` through pixel `(x, y)` of a `w x h`
/// image: the sky gradient by ray height, a flat colour, or the image stretched over the frame.
pub fn background_colour(
    bg: &Background,
    dir: Vec3,
    x: usize,
    y: usize,
    w: usize,
    h: usize,
) -> [f32; 3] {
    match bg {
        Background::Sky {
            horizon,
            zenith,
            skyline,
        } => {
            if let Some(c) = skyline.and_then(|s| s.colour(dir, *horizon)) {
                return c;
            }
            let t = dir.y.max(0.0).sqrt();
            [0, 1, 2].map(|i| horizon[i] * (1.0 - t) + zenith[i] * t)
        }
        Background::Color(c) => *c,
        Background::Image(img) => {
            let (x, y) = (x as f32 + 0.5, y as f32 + 0.5);
            let uv = Vec2::new(x / w as f32, 1.0 - y / h as f32);
            img.sample(uv.clamp(Vec2::splat(0.001), Vec2::splat(0.999)))
        }
    }
}
