//! The digital twin as a camera model of the turntable rig: the object's silhouette box at a
//! turntable angle and distance ratio ([`TwinProjector`], a [`Projector`]), and rendered turntable
//! sequences (fixtures for tests, the throughput benchmark).
//!
//! Turntable angle `θ` maps to the viewpoint azimuth `azimuth_at_zero + direction · θ`
//! (conventions.md: azimuth 0 looks at the front); the camera stays at `elevation_deg`.

use super::log::Projector;
use crate::environment::{self, Brightness, Condition, Environment};
use crate::render::{self, gbuffer::GBuffer, Renderer, Viewpoint};
use crate::scene::Texture;
use anyhow::{Context, Result};
use burn::tensor::Device;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::Mutex;

/// How the rig's turntable angle relates to the twin's viewpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TwinCalibration {
    /// Viewpoint azimuth (degrees) at turntable angle 0.
    pub azimuth_at_zero_deg: f64,
    /// +1 or −1: the sense of the turntable against the azimuth.
    pub direction: f64,
    pub elevation_deg: f64,
}

impl Default for TwinCalibration {
    fn default() -> Self {
        TwinCalibration {
            azimuth_at_zero_deg: 90.0,
            direction: -1.0,
            elevation_deg: 10.0,
        }
    }
}

impl TwinCalibration {
    pub fn load(path: &std::path::Path) -> Result<Self> {
        let t = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read calibration {}", path.display()))?;
        serde_json::from_str(&t).with_context(|| {
            format!(
                "calibration {}: expected JSON {{azimuth_at_zero_deg, direction, elevation_deg}}",
                path.display()
            )
        })
    }

    pub fn viewpoint(&self, angle_deg: f64, ratio: f64) -> Viewpoint {
        Viewpoint::new(
            (self.azimuth_at_zero_deg + self.direction * angle_deg) as f32,
            self.elevation_deg as f32,
            ratio as f32,
        )
    }
}

/// Boxes by (angle in 0.01°, ratio in 1e-4).
type BoxCache = Mutex<HashMap<(i64, i64), Option<[f32; 4]>>>;

/// Silhouette boxes from the twin's ray caster (1 sample per pixel, at the renderer's size,
/// which must be the video's display size). Boxes are cached per 0.01° and ratio.
pub struct TwinProjector {
    pub renderer: Renderer,
    pub calibration: TwinCalibration,
    cache: BoxCache,
}

impl TwinProjector {
    pub fn new(renderer: Renderer, calibration: TwinCalibration) -> Self {
        TwinProjector {
            renderer,
            calibration,
            cache: Mutex::new(HashMap::new()),
        }
    }
}

impl Projector for TwinProjector {
    fn project(&self, angle_deg: f64, ratio: f64) -> Result<Option<[f32; 4]>> {
        let key = (
            (angle_deg * 100.0).round() as i64,
            (ratio * 1e4).round() as i64,
        );
        if let Some(b) = self.cache.lock().unwrap().get(&key) {
            return Ok(*b);
        }
        let cam = self
            .renderer
            .camera(&self.calibration.viewpoint(angle_deg, ratio))?;
        let r = &self.renderer;
        let b = GBuffer::cast(&r.scene, &r.accel, &cam, 1, false).object_box();
        self.cache.lock().unwrap().insert(key, b);
        Ok(b)
    }
    fn describe(&self) -> String {
        let s = &self.renderer.settings;
        format!(
            "the digital twin ({}x{}, vfov {}°, {:?})",
            s.width, s.height, s.vfov_deg, self.calibration
        )
    }
}

/// Renders the object at each `(angle, ratio)` of a turntable sequence (plain sky, ground, sun
/// fixed to the camera side), returning the frames and the silhouette boxes.
pub fn render_turntable(
    r: &Renderer,
    env: &Environment,
    atlas: &Texture,
    calib: &TwinCalibration,
    poses: &[(f64, f64)],
    device: &Device,
) -> Result<Vec<(image::RgbImage, Option<[f32; 4]>)>> {
    let mut out = Vec::with_capacity(poses.len());
    for &(angle, ratio) in poses {
        let c = Condition::plain(calib.viewpoint(angle, ratio), Brightness::Bright);
        let t = render::atlas_tensor(atlas, device);
        let (img, plans) = environment::form(r, env, std::slice::from_ref(&c), t)?;
        out.push((render::to_images(&img).remove(0), plans[0].object_box));
    }
    Ok(out)
}
