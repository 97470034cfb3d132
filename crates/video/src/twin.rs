//! Rendered turntable sequences seen by the viewpoint twin (fixtures for tests, the throughput
//! benchmark). The twin's camera model — turntable angle `θ` to the viewpoint azimuth
//! `azimuth_at_zero + direction · θ` (conventions.md: azimuth 0 looks at the front) at a fixed
//! elevation — is the rig camera model's [`TwinCamera`] (`physical::rig_camera`), which also gives
//! the silhouette boxes of `cac score-video --log`.

use anyhow::Result;
use burn::tensor::Device;
pub use cac_physical::rig_camera::{TwinCalibration, TwinCamera};
use cac_render::environment::{self, Brightness, Condition, Environment};
use cac_render::{self as render, Renderer};
use cac_scene::Texture;

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
