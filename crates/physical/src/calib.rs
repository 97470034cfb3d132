//! Calibrated camera intrinsics with plumb-bob lens distortion (`k1, k2, p1, p2, k3`, OpenCV's
//! model), loaded from an OpenCV `FileStorage` YAML (`%YAML:1.0`, `!!opencv-matrix`) or a ROS
//! `camera_info` YAML. Both hold the same numbers in OpenCV's pixel convention (pixel centres at
//! integers); they are shifted by half a pixel into cac's (centres at half-integers).

pub mod yaml;

use anyhow::{bail, Context, Result};
use cac_render::{Camera, Intrinsics};
use glam::{DVec2, Vec2, Vec3};
use serde::{Deserialize, Serialize};
use std::path::Path;
use yaml::Node;

/// A pinhole camera with plumb-bob distortion, in cac's pixel convention.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    pub width: usize,
    pub height: usize,
    pub fx: f64,
    pub fy: f64,
    /// Principal point, cac convention (OpenCV's `cx + 0.5`).
    pub cx: f64,
    pub cy: f64,
    /// `k1, k2, p1, p2, k3`.
    pub dist: [f64; 5],
}

impl CameraModel {
    /// Loads an OpenCV or ROS calibration YAML (told apart by content). Errors name the file and
    /// the field.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read camera calibration {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("in camera calibration {}", path.display()))
    }

    /// Parses calibration YAML text (see [`CameraModel::load`]).
    pub fn parse(text: &str) -> Result<Self> {
        let doc = yaml::parse(text)?;
        let width = int(&doc, "image_width")?;
        let height = int(&doc, "image_height")?;
        let k = matrix(&doc, &["camera_matrix", "cameraMatrix", "K"], 3, 3)?;
        if let Some((Node::Scalar(m), line)) = doc.get("distortion_model") {
            if m != "plumb_bob" && m != "rational_polynomial" {
                bail!("line {line}: distortion_model {m:?} is not supported (expected plumb_bob)");
            }
        }
        let d = matrix(
            &doc,
            &["distortion_coefficients", "dist_coeffs", "distCoeffs", "D"],
            0,
            0,
        )?;
        if !(4..=14).contains(&d.len()) {
            bail!(
                "field distortion_coefficients: expected 4 or 5 numbers (k1 k2 p1 p2 [k3]), found {}",
                d.len()
            );
        }
        if d.iter().skip(5).any(|&v| v != 0.0) {
            bail!("field distortion_coefficients: only the plumb-bob model is supported, but coefficients past k3 are not zero");
        }
        if k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
            bail!("field camera_matrix: expected [fx 0 cx; 0 fy cy; 0 0 1] (no skew), got {k:?}");
        }
        let mut dist = [0.0; 5];
        dist[..d.len().min(5)].copy_from_slice(&d[..d.len().min(5)]);
        let m = CameraModel {
            width,
            height,
            fx: k[0],
            fy: k[4],
            cx: k[2] + 0.5,
            cy: k[5] + 0.5,
            dist,
        };
        if !(m.fx > 0.0 && m.fy > 0.0 && m.width > 0 && m.height > 0) {
            bail!("field camera_matrix: focal lengths and image size must be positive");
        }
        Ok(m)
    }

    /// The same lens at another resolution (focal lengths and principal point scaled; the
    /// distortion acts on normalised coordinates and does not change).
    pub fn scaled(&self, width: usize, height: usize) -> Self {
        let (sx, sy) = (
            width as f64 / self.width as f64,
            height as f64 / self.height as f64,
        );
        CameraModel {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            dist: self.dist,
        }
    }

    /// The pinhole part, for [`Camera`].
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics {
            width: self.width,
            height: self.height,
            fx: self.fx as f32,
            fy: self.fy as f32,
            cx: self.cx as f32,
            cy: self.cy as f32,
        }
    }

    /// Applies the distortion to normalised image coordinates `(x/z, y/z)`.
    pub(crate) fn distort(&self, p: DVec2) -> DVec2 {
        let [k1, k2, p1, p2, k3] = self.dist;
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        DVec2::new(
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Inverts [`CameraModel::distort`] by Newton's method (numerical Jacobian), starting from
    /// the distorted point; within the image of a real lens it converges to < 1e-12.
    pub(crate) fn undistort(&self, d: DVec2) -> DVec2 {
        let mut p = d;
        for _ in 0..30 {
            let r = self.distort(p) - d;
            if r.length_squared() < 1e-24 {
                break;
            }
            let h = 1e-7;
            let jx = (self.distort(p + DVec2::X * h) - self.distort(p)) / h;
            let jy = (self.distort(p + DVec2::Y * h) - self.distort(p)) / h;
            let det = jx.x * jy.y - jy.x * jx.y;
            if det.abs() < 1e-12 {
                break;
            }
            p -= DVec2::new(jy.y * r.x - jy.x * r.y, -jx.y * r.x + jx.x * r.y) / det;
        }
        p
    }

    /// Projects a world point seen by `cam` (its pose; its intrinsics are ignored) to distorted
    /// pixels; `None` behind the camera.
    pub fn project(&self, cam: &Camera, p: Vec3) -> Option<Vec2> {
        let c = (cam.rotation.transpose() * (p - cam.eye)).as_dvec3();
        if c.z <= 1e-9 {
            return None;
        }
        let d = self.distort(DVec2::new(c.x / c.z, c.y / c.z));
        Some(Vec2::new(
            (self.fx * d.x + self.cx) as f32,
            (self.fy * d.y + self.cy) as f32,
        ))
    }

    /// The world-space unit direction of the ray that lands on distorted pixel `(px, py)`.
    pub fn ray(&self, cam: &Camera, px: f32, py: f32) -> Vec3 {
        let d = DVec2::new(
            (px as f64 - self.cx) / self.fx,
            (py as f64 - self.cy) / self.fy,
        );
        let n = self.undistort(d);
        (cam.rotation * Vec3::new(n.x as f32, n.y as f32, 1.0)).normalize()
    }
}

fn int(doc: &Node, key: &str) -> Result<usize> {
    match doc.get(key) {
        Some((Node::Scalar(s), line)) => s
            .parse()
            .map_err(|_| anyhow::anyhow!("line {line}: field {key}: {s:?} is not a whole number")),
        Some((_, line)) => bail!("line {line}: field {key}: expected a number"),
        None => bail!("missing field {key}"),
    }
}

/// A matrix field (`rows`/`cols`/`data` mapping, or a bare sequence); `rows = 0` accepts any size.
fn matrix(doc: &Node, names: &[&str], rows: usize, cols: usize) -> Result<Vec<f64>> {
    let Some((name, (node, line))) = names.iter().find_map(|n| doc.get(n).map(|v| (*n, v))) else {
        bail!("missing field {}", names[0]);
    };
    let (data, shape) = match node {
        Node::Seq(_) => (node, None),
        Node::Map(_) => {
            let data = node
                .get("data")
                .with_context(|| format!("line {line}: field {name}: no `data`"))?
                .0;
            let dim = |k: &str| -> Result<Option<usize>> {
                match node.get(k) {
                    Some((Node::Scalar(s), l)) => s.parse().map(Some).map_err(|_| {
                        anyhow::anyhow!("line {l}: field {name}.{k}: {s:?} is not a whole number")
                    }),
                    _ => Ok(None),
                }
            };
            (data, dim("rows")?.zip(dim("cols")?))
        }
        Node::Scalar(_) => bail!("line {line}: field {name}: expected a matrix"),
    };
    let Node::Seq(items) = data else {
        bail!("line {line}: field {name}.data: expected a list of numbers");
    };
    let mut v = Vec::with_capacity(items.len());
    for (i, it) in items.iter().enumerate() {
        match it {
            Node::Scalar(s) => v.push(s.parse::<f64>().map_err(|_| {
                anyhow::anyhow!("line {line}: field {name}.data[{i}]: {s:?} is not a number")
            })?),
            _ => bail!("line {line}: field {name}.data[{i}]: expected a number"),
        }
    }
    if let Some((r, c)) = shape {
        if r * c != v.len() {
            bail!(
                "line {line}: field {name}: rows × cols = {} but data has {} numbers",
                r * c,
                v.len()
            );
        }
    }
    if rows > 0 && v.len() != rows * cols {
        bail!(
            "line {line}: field {name}: expected {} numbers ({rows}×{cols}), found {}",
            rows * cols,
            v.len()
        );
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> CameraModel {
        CameraModel {
            width: 640,
            height: 480,
            fx: 600.0,
            fy: 602.0,
            cx: 322.0,
            cy: 238.0,
            dist: [-0.28, 0.09, 0.001, -0.0008, -0.012],
        }
    }

    #[test]
    fn undistort_inverts_distort_over_the_image() {
        let m = model();
        for j in 0..=12 {
            for i in 0..=16 {
                let d = DVec2::new(
                    (i as f64 * 40.0 - m.cx) / m.fx,
                    (j as f64 * 40.0 - m.cy) / m.fy,
                );
                let back = m.distort(m.undistort(d));
                assert!((back - d).length() < 1e-9, "{d:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn ray_and_project_agree() {
        let m = model();
        let cam = Camera::look_at(m.intrinsics(), Vec3::new(2.0, 1.0, 0.5), Vec3::ZERO).unwrap();
        for (px, py) in [(3.0f32, 5.0f32), (320.0, 240.0), (630.0, 470.0)] {
            let p = cam.eye + m.ray(&cam, px, py) * 3.0;
            let q = m.project(&cam, p).unwrap();
            assert!((q - Vec2::new(px, py)).length() < 1e-3, "{q:?}");
        }
    }

    #[test]
    fn bad_fields_are_named() {
        let e = CameraModel::parse("image_width: 640\nimage_height: 480\n").unwrap_err();
        assert!(format!("{e:#}").contains("camera_matrix"), "{e:#}");
        let t = "image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 2, 0, 1, 2, 0, 0]\ndistortion_coefficients: [0, 0, 0, 0]\n";
        let e = CameraModel::parse(t).unwrap_err();
        assert!(format!("{e:#}").contains("line 3"), "{e:#}");
        let t = "image_width: 640x\n";
        assert!(format!("{:#}", CameraModel::parse(t).unwrap_err()).contains("image_width"));
    }
}
