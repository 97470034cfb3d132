//! Primary visibility: one ray per sub-pixel sample through a pinhole camera, giving a G-buffer
//! of triangle id, barycentrics, UV, shading normal, depth and object mask, plus hits on the
//! ground plane `y = 0`.
//!
//! Sample positions are fixed (a stratified grid when the count is a square, else the R2
//! low-discrepancy sequence), so the same view always gives the same G-buffer.

use super::accel::Accel;
use super::camera::Camera;
use cac_scene::Scene;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::ops::Range;

/// What a sample's ray hit first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Surface {
    Sky,
    Object,
    Ground,
}

/// One sample's primary hit.
#[derive(Clone, Copy, Debug)]
pub struct Sample {
    pub surface: Surface,
    /// Scene triangle (objects only; `u32::MAX` otherwise).
    pub tri: u32,
    pub bary: Vec2,
    /// Texture coordinate (zero when the triangle has none).
    pub uv: Vec2,
    /// Unit shading normal, turned to face the camera.
    pub normal: Vec3,
    /// Distance along the (unit) ray; infinite for sky.
    pub depth: f32,
    pub position: Vec3,
    /// Unit ray direction.
    pub dir: Vec3,
}

/// The G-buffer of one view, or of a band of its rows: `samples` entries per pixel held,
/// pixel-major (`((y - rows.start) * width + x) * samples + s`).
pub struct GBuffer {
    pub camera: Camera,
    pub width: usize,
    /// The image's height (all of it, whatever `rows` holds).
    pub height: usize,
    /// The image rows held.
    pub rows: Range<usize>,
    pub samples: usize,
    pub data: Vec<Sample>,
}

/// Sub-pixel offsets in `[0,1)²` for `n` samples.
pub(crate) fn sample_offsets(n: usize) -> Vec<Vec2> {
    let n = n.max(1);
    let k = (n as f64).sqrt().round() as usize;
    if k * k == n {
        let mut v = Vec::with_capacity(n);
        for j in 0..k {
            for i in 0..k {
                v.push(Vec2::new(
                    (i as f32 + 0.5) / k as f32,
                    (j as f32 + 0.5) / k as f32,
                ));
            }
        }
        v
    } else {
        // R2 sequence (Roberts 2018).
        let g = 1.324_718_f64;
        let (a1, a2) = (1.0 / g, 1.0 / (g * g));
        (0..n)
            .map(|i| {
                let x = (0.5 + a1 * (i as f64 + 1.0)).fract();
                let y = (0.5 + a2 * (i as f64 + 1.0)).fract();
                Vec2::new(x as f32, y as f32)
            })
            .collect()
    }
}

impl GBuffer {
    /// Casts `samples` primary rays per pixel through the whole image. `ground`: intersect the
    /// plane `y = 0` too.
    pub fn cast(
        scene: &Scene,
        accel: &Accel,
        camera: &Camera,
        samples: usize,
        ground: bool,
    ) -> GBuffer {
        let rows = 0..camera.intrinsics.height;
        let ray = |x, y| camera.ray_dir(x, y);
        Self::cast_rows(scene, accel, camera, samples, ground, &ray, rows)
    }

    /// Casts the image rows `rows` only (a band of the image, so a view can be cast and shaded a
    /// band at a time in little memory), with the world-space ray direction through each image
    /// point `(px, py)` given by `ray` (unit length; e.g. through a lens-distortion model).
    pub(crate) fn cast_rows(
        scene: &Scene,
        accel: &Accel,
        camera: &Camera,
        samples: usize,
        ground: bool,
        ray: &(dyn Fn(f32, f32) -> Vec3 + Sync),
        rows: Range<usize>,
    ) -> GBuffer {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        assert!(rows.end <= h, "rows {rows:?} outside an image of {h} rows");
        let offs = sample_offsets(samples);
        let s = offs.len();
        // An indexed parallel map, so the samples are written in place into one buffer.
        let data: Vec<Sample> = (0..w * rows.len() * s)
            .into_par_iter()
            .map(|i| {
                let (pixel, o) = (i / s, offs[i % s]);
                let (x, y) = (pixel % w, rows.start + pixel / w);
                let dir = ray(x as f32 + o.x, y as f32 + o.y);
                trace_primary(scene, accel, camera.eye, dir, ground)
            })
            .collect();
        GBuffer {
            camera: *camera,
            width: w,
            height: h,
            rows,
            samples: s,
            data,
        }
    }

    /// Fraction of each held pixel's samples that see the object.
    pub fn coverage(&self) -> Vec<f32> {
        self.data
            .chunks_exact(self.samples)
            .map(|c| {
                c.iter().filter(|s| s.surface == Surface::Object).count() as f32
                    / self.samples as f32
            })
            .collect()
    }

    /// The ground-truth box `[x1, y1, x2, y2]` (pixels): the tight box of pixels where the object
    /// is visible in at least one sample; `None` when it is not visible at all.
    pub fn object_box(&self) -> Option<[f32; 4]> {
        let cov = self.coverage();
        let mut b = [f32::MAX, f32::MAX, f32::MIN, f32::MIN];
        let mut any = false;
        for (i, &c) in cov.iter().enumerate() {
            if c > 0.0 {
                let (x, y) = (
                    (i % self.width) as f32,
                    (self.rows.start + i / self.width) as f32,
                );
                b = [
                    b[0].min(x),
                    b[1].min(y),
                    b[2].max(x + 1.0),
                    b[3].max(y + 1.0),
                ];
                any = true;
            }
        }
        any.then_some(b)
    }
}

fn trace_primary(scene: &Scene, accel: &Accel, eye: Vec3, dir: Vec3, ground: bool) -> Sample {
    let t_ground = if ground && dir.y < -1e-6 && eye.y > 0.0 {
        -eye.y / dir.y
    } else {
        f32::INFINITY
    };
    let sky = Sample {
        surface: Surface::Sky,
        tri: u32::MAX,
        bary: Vec2::ZERO,
        uv: Vec2::ZERO,
        normal: Vec3::Y,
        depth: f32::INFINITY,
        position: eye,
        dir,
    };
    match accel.closest(eye, dir, 0.0, t_ground) {
        Some(hit) => {
            let t = &scene.triangles[hit.tri as usize];
            let (b1, b2) = (hit.bary.x, hit.bary.y);
            let b0 = 1.0 - b1 - b2;
            let uv = t.uv.map(|uv| {
                let [a, b, c] = uv.map(|i| scene.uvs[i as usize]);
                a * b0 + b * b1 + c * b2
            });
            let face = scene.face_normal(t).normalize_or_zero();
            let mut n = match t.n {
                Some(nn) => {
                    let [a, b, c] = nn.map(|i| scene.normals[i as usize]);
                    let s = (a * b0 + b * b1 + c * b2).normalize_or_zero();
                    if s == Vec3::ZERO {
                        face
                    } else {
                        s
                    }
                }
                None => face,
            };
            if n.dot(dir) > 0.0 {
                n = -n;
            }
            Sample {
                surface: Surface::Object,
                tri: hit.tri,
                bary: hit.bary,
                uv: uv.unwrap_or(Vec2::ZERO),
                normal: n,
                depth: hit.t,
                position: eye + dir * hit.t,
                dir,
            }
        }
        None if t_ground.is_finite() => Sample {
            surface: Surface::Ground,
            depth: t_ground,
            position: eye + dir * t_ground,
            ..sky
        },
        None => sky,
    }
}
