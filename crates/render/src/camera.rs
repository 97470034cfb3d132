//! Pinhole cameras with explicit intrinsics, and orbit viewpoints around an object.
//!
//! Camera frame (OpenCV convention): x right, y down, z forward. A world point `X` projects to
//! pixel `(fx * x/z + cx, fy * y/z + cy)` with `(x, y, z) = R^T (X - eye)`; pixel centres are at
//! half-integers, so pixel `(i, j)` covers `[i, i+1) x [j, j+1)`.

use anyhow::{bail, Result};
use glam::{Mat3, Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// Intrinsic parameters of a pinhole camera (pixels).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub width: usize,
    pub height: usize,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
}

impl Intrinsics {
    /// Square pixels, principal point at the image centre, vertical field of view in degrees.
    pub(crate) fn from_vfov(width: usize, height: usize, vfov_deg: f32) -> Self {
        let f = 0.5 * height as f32 / (0.5 * vfov_deg.to_radians()).tan();
        Intrinsics {
            width,
            height,
            fx: f,
            fy: f,
            cx: width as f32 * 0.5,
            cy: height as f32 * 0.5,
        }
    }
}

/// A posed pinhole camera. `rotation` maps camera axes to world axes (columns: right, down, forward).
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    pub eye: Vec3,
    pub rotation: Mat3,
}

impl Camera {
    /// A camera at `eye` looking at `target`, with world +Y up on screen.
    pub fn look_at(intrinsics: Intrinsics, eye: Vec3, target: Vec3) -> Result<Camera> {
        let fwd = (target - eye).normalize_or_zero();
        if fwd == Vec3::ZERO || !fwd.is_finite() {
            bail!("camera position equals its target");
        }
        let mut right = fwd.cross(Vec3::Y);
        if right.length_squared() < 1e-10 {
            // Looking straight down or up: pick +Z as screen-up's reference.
            right = fwd.cross(Vec3::Z);
        }
        let right = right.normalize();
        let down = fwd.cross(right);
        Ok(Camera {
            intrinsics,
            eye,
            rotation: Mat3::from_cols(right, down, fwd),
        })
    }

    /// The world-space unit direction of the ray through image point `(px, py)` (pixels).
    pub fn ray_dir(&self, px: f32, py: f32) -> Vec3 {
        let k = &self.intrinsics;
        let d = Vec3::new((px - k.cx) / k.fx, (py - k.cy) / k.fy, 1.0);
        (self.rotation * d).normalize()
    }

    /// Projects a world point to pixels; `None` when it is behind the camera.
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        let c = self.rotation.transpose() * (p - self.eye);
        if c.z <= 1e-6 {
            return None;
        }
        let k = &self.intrinsics;
        Some(Vec2::new(k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy))
    }
}

/// Where the camera is, relative to the object: the paper's viewpoint parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Viewpoint {
    /// Degrees about +Y; 0 = in front of the object (on +X), 90 = on its +Z side.
    pub azimuth_deg: f32,
    /// Degrees above the horizontal plane through the object's centre.
    pub elevation_deg: f32,
    /// Camera-to-centre distance in object lengths (the distance ratio).
    pub distance_ratio: f32,
    /// Image-plane shift of the object as a fraction of the image size (x right, y down).
    pub shift: [f32; 2],
}

impl Viewpoint {
    pub fn new(azimuth_deg: f32, elevation_deg: f32, distance_ratio: f32) -> Self {
        Viewpoint {
            azimuth_deg,
            elevation_deg,
            distance_ratio,
            shift: [0.0; 2],
        }
    }

    /// The camera for this viewpoint around an object with bounds `(lo, hi)` and length `len`.
    /// Fails when the camera would sit inside the object's bounding box.
    pub fn camera(&self, k: Intrinsics, lo: Vec3, hi: Vec3, len: f32) -> Result<Camera> {
        if !(self.distance_ratio.is_finite() && self.distance_ratio > 0.0) {
            bail!(
                "distance ratio must be positive, got {}",
                self.distance_ratio
            );
        }
        let target = (lo + hi) * 0.5;
        let (a, e) = (
            self.azimuth_deg.to_radians(),
            self.elevation_deg.to_radians(),
        );
        let dir = Vec3::new(e.cos() * a.cos(), e.sin(), e.cos() * a.sin());
        let eye = target + dir * self.distance_ratio * len;
        let inside = eye.cmpgt(lo - 1e-4).all() && eye.cmplt(hi + 1e-4).all();
        if inside {
            bail!(
                "camera at distance ratio {} (azimuth {}, elevation {}) is inside the object's bounding box",
                self.distance_ratio, self.azimuth_deg, self.elevation_deg
            );
        }
        let mut k = k;
        k.cx -= self.shift[0] * k.width as f32;
        k.cy -= self.shift[1] * k.height as f32;
        Camera::look_at(k, eye, target)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_inverts_ray_direction() {
        let k = Intrinsics::from_vfov(640, 480, 50.0);
        let cam = Camera::look_at(k, Vec3::new(3.0, 2.0, 5.0), Vec3::new(0.0, 0.5, 0.0)).unwrap();
        for (px, py) in [(10.5f32, 20.5f32), (320.0, 240.0), (600.0, 470.0)] {
            let p = cam.eye + cam.ray_dir(px, py) * 7.0;
            let q = cam.project(p).unwrap();
            assert!((q - Vec2::new(px, py)).length() < 1e-3, "{q:?}");
        }
        // The target projects to the principal point, and world up is screen up.
        let c = cam.project(Vec3::new(0.0, 0.5, 0.0)).unwrap();
        assert!((c - Vec2::new(320.0, 240.0)).length() < 1e-3);
        let up = cam.project(Vec3::new(0.0, 1.5, 0.0)).unwrap();
        assert!(up.y < c.y);
    }

    #[test]
    fn camera_inside_bounds_is_an_error() {
        let k = Intrinsics::from_vfov(64, 64, 45.0);
        let (lo, hi) = (Vec3::new(-2.0, 0.0, -1.0), Vec3::new(2.0, 1.5, 1.0));
        let e = Viewpoint::new(0.0, 0.0, 0.3)
            .camera(k, lo, hi, 4.0)
            .unwrap_err();
        assert!(e.to_string().contains("inside"), "{e}");
        assert!(Viewpoint::new(0.0, 0.0, 1.0).camera(k, lo, hi, 4.0).is_ok());
        // Straight down is well defined.
        assert!(Viewpoint::new(0.0, 90.0, 2.0)
            .camera(k, lo, hi, 4.0)
            .is_ok());
    }
}
