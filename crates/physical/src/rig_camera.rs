//! The one camera model of the turntable rig ([`RigCamera`]): where the camera stands for a table
//! angle and a distance ratio, and the object's silhouette box it sees there. Every projector of
//! the rig is one of its two implementations:
//! - the calibrated rig ([`Rig`]: the rig file's mount and the calibrated lens, distortion
//!   included; the box is the silhouette projected through the lens, [`super::truth`]). The
//!   capture scorer, the digital twin camera ([`super::twin`]) and `cac score-video --rig` use it;
//! - the viewpoint twin ([`TwinCamera`]: a pinhole renderer at the azimuth
//!   `azimuth_at_zero + direction · θ`, a fixed elevation and the distance ratio, per
//!   [`TwinCalibration`]; the box is the ray-cast silhouette at 1 sample per pixel). Videos of a
//!   turntable without a rig file (`cac score-video --log`) use it.

use super::rig::Rig;
use super::truth::ground_truth_box;
use anyhow::{bail, Context, Result};
use cac_render::{gbuffer::GBuffer, Camera, Renderer, Viewpoint};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::Mutex;

/// A camera of the turntable rig.
pub trait RigCamera {
    /// The camera (pose in the object's frame and the pinhole part of the lens) with the table at
    /// `angle_deg` and the camera at distance ratio `ratio`.
    fn camera(&self, angle_deg: f64, ratio: f64) -> Result<Camera>;
    /// The object's box `x1, y1, x2, y2` in image pixels; `None` when it is out of view.
    fn object_box(&self, angle_deg: f64, ratio: f64) -> Result<Option<[f32; 4]>>;
    /// One line for reports.
    fn describe(&self) -> String;
}

impl<C: RigCamera + ?Sized> RigCamera for Box<C> {
    fn camera(&self, angle_deg: f64, ratio: f64) -> Result<Camera> {
        (**self).camera(angle_deg, ratio)
    }
    fn object_box(&self, angle_deg: f64, ratio: f64) -> Result<Option<[f32; 4]>> {
        (**self).object_box(angle_deg, ratio)
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
}

impl RigCamera for Rig {
    fn camera(&self, angle_deg: f64, ratio: f64) -> Result<Camera> {
        self.camera_at(angle_deg, self.horizontal_distance(ratio)?)
    }
    fn object_box(&self, angle_deg: f64, ratio: f64) -> Result<Option<[f32; 4]>> {
        ground_truth_box(self, angle_deg, self.horizontal_distance(ratio)?)
    }
    fn describe(&self) -> String {
        let l = &self.lens;
        format!(
            "the calibrated rig ({}x{} lens, fx {:.1}, camera {} m high, {}° down)",
            l.width, l.height, l.fx, self.config.camera.height_m, self.config.camera.elevation_deg
        )
    }
}

impl Rig {
    /// Checks that the lens is calibrated (or scaled with `camera.resolution`) at the frames'
    /// size `display` (a video's display size).
    pub fn check_frame_size(&self, display: (u32, u32)) -> Result<()> {
        let (w, h) = (self.lens.width as u32, self.lens.height as u32);
        if (w, h) != display {
            bail!(
                "the rig's lens is calibrated at {w}x{h} but the video's frames are {}x{} \
                 (set camera.resolution in the rig file, or check the rotation)",
                display.0,
                display.1
            );
        }
        Ok(())
    }
}

/// How the turntable angle relates to the viewpoint twin's viewpoint.
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

/// The viewpoint twin: silhouette boxes from the renderer's ray caster (1 sample per pixel, at
/// the renderer's size, which must be the frames' size), cached per 0.01° and 1e-4 of ratio.
pub struct TwinCamera {
    pub renderer: Renderer,
    pub calibration: TwinCalibration,
    cache: BoxCache,
}

impl TwinCamera {
    pub fn new(renderer: Renderer, calibration: TwinCalibration) -> Self {
        TwinCamera {
            renderer,
            calibration,
            cache: Mutex::new(HashMap::new()),
        }
    }
}

impl RigCamera for TwinCamera {
    fn camera(&self, angle_deg: f64, ratio: f64) -> Result<Camera> {
        self.renderer
            .camera(&self.calibration.viewpoint(angle_deg, ratio))
    }
    fn object_box(&self, angle_deg: f64, ratio: f64) -> Result<Option<[f32; 4]>> {
        let key = (
            (angle_deg * 100.0).round() as i64,
            (ratio * 1e4).round() as i64,
        );
        if let Some(b) = self.cache.lock().unwrap().get(&key) {
            return Ok(*b);
        }
        let cam = self.camera(angle_deg, ratio)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use cac_render::RenderSettings;
    use glam::Vec3;
    use std::path::Path;

    /// Distance from the eye to the object's centre, and the eye's azimuth about the vertical
    /// axis through the centre (degrees in [0, 360)).
    fn stand(cam: &Camera, centre: Vec3) -> (f64, f64) {
        let d = cam.eye - centre;
        let az = f64::from(d.z.atan2(d.x)).to_degrees().rem_euclid(360.0);
        (f64::from(d.length()), az)
    }

    #[test]
    fn both_rig_cameras_stand_at_the_ratio_and_see_the_object() {
        let rig = Rig::load(Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../calib/rig.toml"
        )))
        .unwrap();
        let (lo, hi) = rig.renderer.scene.bounds();
        let centre = Vec3::new(0.0, (lo.y + hi.y) * 0.5, 0.0);
        let (w, h) = (rig.lens.width as u32, rig.lens.height as u32);
        rig.check_frame_size((w, h)).unwrap();
        let e = rig.check_frame_size((w + 1, h)).unwrap_err().to_string();
        assert!(e.contains("camera.resolution"), "{e}");
        let twin = TwinCamera::new(
            Renderer::new(
                rig.renderer.scene.clone(),
                RenderSettings {
                    width: 160,
                    height: 120,
                    samples: 1,
                    vfov_deg: 50.0,
                    atlas_res: 2,
                },
            )
            .unwrap(),
            TwinCalibration::default(),
        );
        let cams: [&dyn RigCamera; 2] = [&rig, &twin];
        for (k, c) in cams.into_iter().enumerate() {
            for (angle, ratio) in [(0.0, 2.0), (75.0, 3.0), (200.0, 2.5)] {
                let (dist, _) = stand(&c.camera(angle, ratio).unwrap(), centre);
                let want = ratio * rig.object_length();
                // The twin's viewpoint is about the bounding box's centre, the rig's about the
                // turntable axis at the centre's height: the same point for a centred object
                // within the object's extent.
                assert!(
                    (dist - want).abs() < 0.05 * want,
                    "camera {k} at {angle}°, ratio {ratio}: {dist} m, want {want} m"
                );
                let b = c.object_box(angle, ratio).unwrap().expect("in view");
                assert!(b[0] < b[2] && b[1] < b[3], "camera {k}: {b:?}");
                assert_eq!(
                    c.object_box(angle, ratio).unwrap(),
                    Some(b),
                    "same box again"
                );
            }
        }
        // The calibrated rig's box is the silhouette projected through the lens.
        let d = rig.horizontal_distance(2.0).unwrap();
        assert_eq!(
            rig.object_box(30.0, 2.0).unwrap(),
            ground_truth_box(&rig, 30.0, d).unwrap()
        );
        // Turning the table turns the calibrated camera by the same angle about the axis.
        let (_, a0) = stand(&rig.camera(0.0, 2.0).unwrap(), centre);
        let (_, a1) = stand(&rig.camera(90.0, 2.0).unwrap(), centre);
        assert!(
            ((a1 - a0).rem_euclid(360.0) - 90.0).abs() < 0.5,
            "{a0} -> {a1}"
        );
    }
}
