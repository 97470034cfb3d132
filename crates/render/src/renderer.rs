//! [`Renderer`]: the four primitives put together for one object — the scene's BVH, the
//! [`RenderSettings`] (image size, samples, camera), and a view's [`RenderPlan`] cast and shaded
//! in bands of [`BAND_ROWS`] rows.

use crate::camera::{Camera, Intrinsics, Viewpoint};
use crate::light::{Backdrop, Lighting};
use crate::shade::{self, RenderPlan};
use crate::{accel, gbuffer};
use anyhow::{bail, Result};
use cac_scene::Scene;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Rows of a view cast and shaded together ([`Renderer::plan_rays`]): a band's G-buffer is at
/// most `16 x width x samples` samples (4 MB at 512² and 4 samples).
pub const BAND_ROWS: usize = 16;

/// Image size, sampling and camera settings (the `[render]` table of a scene config).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderSettings {
    pub width: usize,
    pub height: usize,
    /// Samples per pixel (anti-aliasing); see docs/renderer.md for error against time.
    pub samples: usize,
    /// Vertical field of view in degrees.
    pub vfov_deg: f32,
    /// Side of the square camouflage atlas (texels).
    pub atlas_res: usize,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            width: 512,
            height: 512,
            samples: 4,
            vfov_deg: 45.0,
            atlas_res: 512,
        }
    }
}

impl RenderSettings {
    pub fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            bail!(
                "render size {}x{} is out of range (1..=16384)",
                self.width,
                self.height
            );
        }
        if self.samples == 0 || self.samples > 1024 {
            bail!("samples per pixel must be 1..=1024, got {}", self.samples);
        }
        if !(self.vfov_deg > 1.0 && self.vfov_deg < 170.0) {
            bail!(
                "vertical field of view must be within (1, 170) degrees, got {}",
                self.vfov_deg
            );
        }
        if self.atlas_res < 2 || self.atlas_res > 8192 {
            bail!("atlas resolution must be 2..=8192, got {}", self.atlas_res);
        }
        Ok(())
    }

    /// Memory one view holds while it is cast, shaded and composed: 32 bytes per sample (the
    /// G-buffer's hit, barycentrics, normal and texel taps) and 16 per pixel (the image and its
    /// PNG). Calibrated on `cac render` at 8000² and 4 spp: 7.5 GB peak, 30.5 bytes per sample.
    pub(crate) fn bytes_per_view(&self) -> u64 {
        let pixels = (self.width * self.height) as u64;
        pixels * (32 * self.samples as u64 + 16)
    }

    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics::from_vfov(self.width, self.height, self.vfov_deg)
    }
}

/// A scene with its acceleration structure, ready to render views.
pub struct Renderer {
    pub scene: Scene,
    pub accel: accel::Accel,
    pub settings: RenderSettings,
}

impl Renderer {
    /// Refuses settings whose view would not fit the process's memory budget
    /// ([`cac_core::memory::MemoryBudget::current`]).
    pub fn new(scene: Scene, settings: RenderSettings) -> Result<Renderer> {
        settings.validate()?;
        cac_core::memory::MemoryBudget::current()
            .check(
                &format!(
                    "a rendered view of {}x{} pixels at {} samples per pixel",
                    settings.width, settings.height, settings.samples
                ),
                settings.bytes_per_view(),
                "lower the size (--width/--height, --size or the config's [render]) or --samples",
            )
            .map_err(anyhow::Error::from)?;
        let accel = accel::Accel::build(&scene);
        Ok(Renderer {
            scene,
            accel,
            settings,
        })
    }

    /// The camera of a viewpoint (errors when it would be inside the object).
    pub fn camera(&self, view: &Viewpoint) -> Result<Camera> {
        let (lo, hi) = self.scene.bounds();
        view.camera(self.settings.intrinsics(), lo, hi, self.scene.length())
    }

    /// Ray-casts and shades one view into a plan.
    pub fn plan(
        &self,
        view: &Viewpoint,
        light: &Lighting,
        backdrop: &Backdrop,
    ) -> Result<RenderPlan> {
        let cam = self.camera(view)?;
        Ok(self.plan_rays(&cam, &|x, y| cam.ray_dir(x, y), light, backdrop))
    }

    /// Ray-casts and shades one view seen by `camera`, with the ray through each image point
    /// given by `ray` (unit directions; a camera with lens distortion); the image size is the
    /// camera's. The view is cast and shaded [`BAND_ROWS`] rows at a time and the bands are
    /// stacked: the same plan as at once, without a G-buffer of the whole view in memory (64 MB
    /// at 512² and 4 samples, a fresh mapping of pages on every view).
    pub fn plan_rays(
        &self,
        camera: &Camera,
        ray: &(dyn Fn(f32, f32) -> glam::Vec3 + Sync),
        light: &Lighting,
        backdrop: &Backdrop,
    ) -> RenderPlan {
        let h = camera.intrinsics.height;
        let bands: Vec<RenderPlan> = (0..h.div_ceil(BAND_ROWS).max(1))
            .into_par_iter()
            .map(|b| {
                let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(h);
                let g = gbuffer::GBuffer::cast_rows(
                    &self.scene,
                    &self.accel,
                    camera,
                    self.settings.samples,
                    backdrop.ground.is_some(),
                    ray,
                    rows,
                );
                shade::plan(
                    &self.scene,
                    &self.accel,
                    &g,
                    light,
                    backdrop,
                    self.settings.atlas_res,
                )
            })
            .collect();
        RenderPlan::stack(bands)
    }
}
