//! The calibrated rig as a [`Projector`]: the object's silhouette projected through the rig
//! file's lens (distortion included) at the logged table angle and distance ratio, exactly as the
//! capture scorer does (`physical::truth::ground_truth_box`). The lens must be calibrated (or
//! scaled with `camera.resolution`) at the video's display size.

use super::log::Projector;
use crate::physical::rig::Rig;
use crate::physical::truth::ground_truth_box;
use anyhow::{bail, Result};

/// Ground-truth boxes from a rig file.
pub struct RigProjector {
    pub rig: Rig,
}

impl RigProjector {
    /// Checks the lens size against the video's display size.
    pub fn new(rig: Rig, display: (u32, u32)) -> Result<Self> {
        let (w, h) = (rig.lens.width as u32, rig.lens.height as u32);
        if (w, h) != display {
            bail!(
                "the rig's lens is calibrated at {w}x{h} but the video's frames are {}x{} \
                 (set camera.resolution in the rig file, or check the rotation)",
                display.0,
                display.1
            );
        }
        Ok(RigProjector { rig })
    }
}

impl Projector for RigProjector {
    fn project(&self, angle_deg: f64, ratio: f64) -> Result<Option<[f32; 4]>> {
        ground_truth_box(&self.rig, angle_deg, self.rig.horizontal_distance(ratio)?)
    }
    fn describe(&self) -> String {
        let l = &self.rig.lens;
        format!(
            "the calibrated rig ({}x{} lens, fx {:.1}, camera {} m high, {}° down)",
            l.width,
            l.height,
            l.fx,
            self.rig.config.camera.height_m,
            self.rig.config.camera.elevation_deg
        )
    }
}
