//! The digital twin of the rig's camera: a [`FrameSource`] that renders the textured object at
//! the turntable's *physical* angle and the camera's distance (read at capture time from a
//! [`PoseSource`], e.g. the simulated device's mechanics) through the calibrated lens — rays
//! are cast through the plumb-bob distortion model — then applies exposure, blur and sensor noise
//! (read + shot). Lit by the rig file's lamp and ambient, or by a photographed environment of
//! the room (`[twin] hdri`, image-based lighting). Deterministic for a seed, frame number and pose.

use super::camera::{CameraError, Frame, FrameSource};
use super::rig::Rig;
use cac_render::ibl::ImageLight;
use cac_render::{Backdrop, Background, Ground, Lighting};
use cac_scene::Texture;
use glam::Vec2;
use image::RgbImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::sync::Arc;

/// Where the rig is right now: table angle (degrees) and camera-to-axis distance (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub angle_deg: f64,
    pub horizontal_m: f64,
}

/// Reads the rig's current pose (from a simulated device, an encoder, ...).
pub(crate) type PoseSource = Box<dyn FnMut() -> Result<Pose, String> + Send>;

/// One rendered frame with what the renderer knows about it.
pub struct TwinFrame {
    pub image: RgbImage,
    /// Box of the pixels where the object covers at least one sample (`[x1, y1, x2, y2]`).
    pub mask_box: Option<[f32; 4]>,
    pub pose: Pose,
}

/// The digital twin camera.
pub struct DigitalTwin {
    rig: Arc<Rig>,
    atlas: Texture,
    pose: PoseSource,
    seed: u64,
    index: u64,
}

impl DigitalTwin {
    /// A twin of `rig`'s camera looking at the object painted with `atlas` (resized to a square
    /// of the renderer's atlas size).
    pub fn new(rig: Arc<Rig>, atlas: &Texture, pose: PoseSource, seed: u64) -> Self {
        let r = rig.renderer.settings.atlas_res;
        let atlas = if atlas.width == r && atlas.height == r {
            atlas.clone()
        } else {
            atlas.resized(r, r)
        };
        DigitalTwin {
            rig,
            atlas,
            pose,
            seed,
            index: 0,
        }
    }

    /// Renders the frame seen at `pose`; `frame` picks the noise.
    pub fn render(&self, pose: Pose, frame: u64) -> anyhow::Result<TwinFrame> {
        let rig = &*self.rig;
        let t = &rig.config.twin;
        let cam = rig.camera_at(pose.angle_deg, pose.horizontal_m)?;
        let lens = &rig.lens;
        let ray = |x: f32, y: f32| lens.ray(&cam, x, y);
        let light = match &rig.room {
            // The room turns with the rig frame, not with the object: the map's rotation is
            // the room's plus the table's angle (the object frame turns by -angle).
            Some(map) => Lighting {
                ambient: 0.0,
                sun: 0.0,
                sun_dir: glam::Vec3::Y,
                sky_occlusion: None,
                image: Some(ImageLight::new(
                    map.clone(),
                    t.hdri_rotation_deg + pose.angle_deg as f32,
                    t.hdri_exposure_stops,
                    t.ground.map(|c| c.map(cac_core::colour::decode)),
                    t.ibl,
                )),
            },
            None => Lighting {
                ambient: t.ambient,
                sun: t.lamp,
                sun_dir: rig.lamp_dir(pose.angle_deg),
                sky_occlusion: None,
                image: None,
            },
        };
        let backdrop = Backdrop {
            background: Background::Color(t.background),
            ground: t.ground.map(|c| Ground {
                texture: Arc::new(Texture::solid(2, 2, c)),
                tile_m: 1.0,
                offset: Vec2::ZERO,
            }),
        };
        let plan = rig.renderer.plan_rays(&cam, &ray, &light, &backdrop);
        let rgb = plan.render_cpu(&self.atlas);
        let image = self.sensor(rgb, plan.width, plan.height, frame, pose);
        Ok(TwinFrame {
            image,
            mask_box: plan.object_box,
            pose,
        })
    }

    /// Exposure, blur, read and shot noise, 8-bit quantisation.
    fn sensor(
        &self,
        mut rgb: Vec<[f32; 3]>,
        w: usize,
        h: usize,
        frame: u64,
        pose: Pose,
    ) -> RgbImage {
        // The pose enters the seed too, so a resumed run (frame numbers from 0 again) does not
        // repeat the noise of the first run's frames.
        let pose_bits = pose.angle_deg.to_bits() ^ pose.horizontal_m.to_bits().rotate_left(29);
        let t = &self.rig.config.twin;
        for p in &mut rgb {
            for c in p.iter_mut() {
                *c = (*c * t.exposure).clamp(0.0, 1.0);
            }
        }
        if t.blur_px > 0.0 {
            rgb = blur(&rgb, w, h, t.blur_px);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.seed ^ frame.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ pose_bits.rotate_left(17),
        );
        let unit = Normal::new(0.0f32, 1.0).expect("valid normal");
        let mut img = RgbImage::new(w as u32, h as u32);
        for (i, p) in rgb.iter().enumerate() {
            let px = img.get_pixel_mut((i % w) as u32, (i / w) as u32);
            for c in 0..3 {
                let v = p[c];
                let sigma = (t.read_noise * t.read_noise + t.shot_noise * t.shot_noise * v).sqrt();
                let v = v + sigma * unit.sample(&mut rng);
                px[c] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            }
        }
        img
    }
}

/// Separable Gaussian blur with clamped edges.
fn blur(src: &[[f32; 3]], w: usize, h: usize, sigma: f32) -> Vec<[f32; 3]> {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f32 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|v| v / sum).collect();
    let pass = |src: &[[f32; 3]], horizontal: bool| {
        let mut out = vec![[0.0f32; 3]; src.len()];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let mut acc = [0.0f32; 3];
                for (j, kv) in k.iter().enumerate() {
                    let d = j as isize - r;
                    let (sx, sy) = if horizontal {
                        ((x + d).clamp(0, w as isize - 1), y)
                    } else {
                        (x, (y + d).clamp(0, h as isize - 1))
                    };
                    let s = src[sy as usize * w + sx as usize];
                    for c in 0..3 {
                        acc[c] += kv * s[c];
                    }
                }
                out[y as usize * w + x as usize] = acc;
            }
        }
        out
    };
    pass(&pass(src, true), false)
}

impl FrameSource for DigitalTwin {
    fn capture(&mut self) -> Result<Frame, CameraError> {
        let pose = (self.pose)().map_err(CameraError::Device)?;
        let i = self.index;
        let f = self
            .render(pose, i)
            .map_err(|e| CameraError::Device(format!("{e:#}")))?;
        self.index += 1;
        Ok(Frame {
            image: f.image,
            index: i,
            origin: format!(
                "twin angle={:.3} distance={:.4}",
                pose.angle_deg, pose.horizontal_m
            ),
            events: Vec::new(),
        })
    }

    fn describe(&self) -> String {
        let l = &self.rig.lens;
        format!(
            "digital twin {}x{} fx={:.1} k1={} seed={}",
            l.width, l.height, l.fx, l.dist[0], self.seed
        )
    }
}
