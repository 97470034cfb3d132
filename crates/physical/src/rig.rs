//! The rig file (`rig.toml`): where the turntable axis, the camera and the object are, the
//! distance ratios, the rail (or the operator) that sets the camera distance, the settle time,
//! and the digital twin's look. [`Rig`] resolves it (loads the intrinsics and the object) and
//! gives the camera pose for a turntable angle and a camera distance.
//!
//! Frames: the rig frame has the turntable axis on the vertical line `x = z = 0` and the table
//! top at `y = 0`; the camera sits on +X looking towards the axis. The object stands on the table
//! with the point `turntable.axis_m` of its own frame (`conventions.md`) on the axis. Turning the
//! table to angle θ shows the object from azimuth θ.

use super::calib::CameraModel;
use anyhow::{bail, Context, Result};
use cac_render::config::ObjectConfig;
use cac_render::ibl::{self, EnvironmentMap};
use cac_render::{Camera, RenderSettings, Renderer};
use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The `[camera]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraMount {
    /// OpenCV or ROS calibration YAML, relative to the rig file.
    pub intrinsics: PathBuf,
    /// Capture at this resolution (the calibration scaled); default: the calibrated size.
    #[serde(default)]
    pub resolution: Option<[usize; 2]>,
    /// Height of the optical centre above the table top (m).
    pub height_m: f64,
    /// Elevation: the optical axis points this many degrees below the horizontal.
    pub elevation_deg: f64,
    /// Frame rate to ask a V4L2 camera for (default: the camera's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fps: Option<f64>,
    /// Exposure to lock a V4L2 camera at, in its units (100 µs on UVC); default: where auto
    /// exposure settles during the warm-up.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure: Option<i32>,
    /// White balance to lock (kelvin); default: where auto white balance settles.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_balance_k: Option<i32>,
    /// Focus position to lock; default: where autofocus settles.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focus: Option<i32>,
}

/// The `[turntable]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TurntableMount {
    /// The point of the object's frame (x, z metres) that sits on the turntable axis.
    #[serde(default)]
    pub axis_m: [f64; 2],
    /// Wait after a move before capturing (vibrations die down), milliseconds.
    pub settle_ms: u64,
    /// Turning speed (°/s); default: the firmware's.
    #[serde(default)]
    pub speed_deg_s: Option<f64>,
}

/// The `[rail]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RailMount {
    /// Whether a motorised rail sets the camera distance (else the operator moves the camera).
    pub present: bool,
    /// Horizontal camera-to-axis distance at rail position 0 (m).
    #[serde(default)]
    pub near_m: f64,
    /// Rail travel (m), for the simulated rail.
    #[serde(default)]
    pub length_m: f64,
}

/// The `[twin]` table: how the digital twin renders and degrades frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TwinSettings {
    /// Samples per pixel.
    pub samples: usize,
    /// Backdrop colour (sRGB, 0–1).
    pub background: [f32; 3],
    /// Colour of the table top and floor (none: no ground plane).
    pub ground: Option<[f32; 3]>,
    /// Ambient light.
    pub ambient: f32,
    /// Key lamp strength and direction in the rig frame (azimuth, elevation in degrees).
    pub lamp: f32,
    pub lamp_dir_deg: [f32; 2],
    /// Exposure gain (1 = as rendered).
    pub exposure: f32,
    /// Gaussian blur σ (pixels; 0 = none).
    pub blur_px: f32,
    /// Read noise σ and shot-noise σ at full white (0–1 units).
    pub read_noise: f32,
    pub shot_noise: f32,
    /// The room as a photographed HDR environment (one of Blender's eight by name, e.g.
    /// "interior", or an equirectangular .exr/.hdr file): it lights the object and the table
    /// (image-based lighting, `cac_render::ibl`) and is seen behind them, instead of `ambient`,
    /// `lamp` and `background`. Fixed in the rig frame: the object turns in it.
    pub hdri: Option<String>,
    /// The room map's turn about the vertical axis (degrees, Blender's mapping rotation).
    pub hdri_rotation_deg: f32,
    /// The room's exposure in stops (its radiance × 2^stops).
    pub hdri_exposure_stops: f32,
    /// How finely the room's light is evaluated (`[twin.ibl]`: `sh_order`, `occlusion_rays`,
    /// `prefilter_levels`; the training config's `[environment.ibl]` knobs, with their
    /// defaults); used only with `hdri`.
    pub ibl: cac_render::ibl::IblSettings,
}

impl Default for TwinSettings {
    fn default() -> Self {
        TwinSettings {
            samples: 4,
            background: [0.82, 0.82, 0.80],
            ground: Some([0.35, 0.35, 0.37]),
            ambient: 0.45,
            lamp: 0.65,
            lamp_dir_deg: [30.0, 50.0],
            exposure: 1.0,
            blur_px: 0.5,
            read_noise: 0.01,
            shot_noise: 0.02,
            hdri: None,
            hdri_rotation_deg: 0.0,
            hdri_exposure_stops: 0.0,
            ibl: Default::default(),
        }
    }
}

/// A whole rig file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigConfig {
    pub camera: CameraMount,
    pub turntable: TurntableMount,
    pub rail: RailMount,
    /// The printed object; `length_m` (the model's real length) is required.
    pub object: ObjectConfig,
    /// Distance ratios (camera-to-centre distance / object length) captured by default.
    pub ratios: Vec<f64>,
    #[serde(default)]
    pub twin: TwinSettings,
}

impl RigConfig {
    /// Reads and checks a rig file; errors name the file and the field.
    pub fn load(path: &Path) -> Result<(RigConfig, CameraModel)> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read rig file {}", path.display()))?;
        let mut cfg: RigConfig = toml::from_str(&text)
            .with_context(|| format!("malformed rig file {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        if cfg.camera.intrinsics.is_relative() {
            cfg.camera.intrinsics = base.join(&cfg.camera.intrinsics);
        }
        if !Path::new(&cfg.object.mesh).is_absolute()
            && cac_scene::generate::by_name(&cfg.object.mesh).is_none()
        {
            cfg.object.mesh = base.join(&cfg.object.mesh).display().to_string();
        }
        cfg.check()
            .with_context(|| format!("in rig file {}", path.display()))?;
        let model = CameraModel::load(&cfg.camera.intrinsics)
            .with_context(|| format!("camera.intrinsics of rig file {}", path.display()))?;
        let model = match cfg.camera.resolution {
            Some([w, h]) => model.scaled(w, h),
            None => model,
        };
        Ok((cfg, model))
    }

    fn check(&self) -> Result<()> {
        match self.object.length_m {
            Some(l) if l > 0.0 && l.is_finite() => {}
            _ => bail!(
                "object.length_m: the printed object's length (m) is required and must be positive"
            ),
        }
        if let Some([w, h]) = self.camera.resolution {
            if w == 0 || h == 0 || w > 8192 || h > 8192 {
                bail!("camera.resolution: {w}x{h} is out of range (1..=8192)");
            }
        }
        if !(self.camera.height_m.is_finite() && self.camera.elevation_deg.abs() < 89.0) {
            bail!("camera.elevation_deg must be within (-89, 89) degrees");
        }
        if self.ratios.is_empty() || self.ratios.iter().any(|r| !(*r > 0.0 && r.is_finite())) {
            bail!("ratios: need at least one positive distance ratio");
        }
        if self.rail.present && !(self.rail.near_m > 0.0 && self.rail.length_m > 0.0) {
            bail!("rail: near_m and length_m must be positive when present = true");
        }
        if self.twin.samples == 0 || self.twin.samples > 256 {
            bail!("twin.samples must be 1..=256");
        }
        if self.twin.exposure <= 0.0
            || self.twin.blur_px < 0.0
            || self.twin.read_noise < 0.0
            || self.twin.shot_noise < 0.0
        {
            bail!("twin: exposure must be positive, blur and noise not negative");
        }
        let t = &self.twin;
        if !(t.hdri_rotation_deg.abs() <= 720.0 && t.hdri_exposure_stops.abs() <= 20.0) {
            bail!("twin: hdri_rotation_deg must be within ±720 and hdri_exposure_stops within ±20");
        }
        t.ibl.check().context("twin.ibl")?;
        Ok(())
    }
}

/// A resolved rig: the config, the lens, the object ready to render.
pub struct Rig {
    pub config: RigConfig,
    pub lens: CameraModel,
    pub renderer: Renderer,
    /// The room's environment map (`twin.hdri`), read once.
    pub room: Option<Arc<EnvironmentMap>>,
}

impl Rig {
    /// Loads the object and builds its renderer at the lens's resolution.
    pub fn new(config: RigConfig, lens: CameraModel) -> Result<Rig> {
        let scene = config
            .object
            .load()
            .with_context(|| format!("object.mesh {:?}", config.object.mesh))?;
        let settings = RenderSettings {
            width: lens.width,
            height: lens.height,
            samples: config.twin.samples,
            vfov_deg: 45.0, // unused: the lens gives the rays
            atlas_res: 512,
        };
        let room = match &config.twin.hdri {
            Some(name) => Some(ibl::load(name).context("twin.hdri")?),
            None => None,
        };
        Ok(Rig {
            renderer: Renderer::new(scene, settings)?,
            config,
            lens,
            room,
        })
    }

    /// Reads a rig file and resolves it.
    pub fn load(path: &Path) -> Result<Rig> {
        let (c, l) = RigConfig::load(path)?;
        Rig::new(c, l).with_context(|| format!("in rig file {}", path.display()))
    }

    /// The object's length (m).
    pub(crate) fn object_length(&self) -> f64 {
        f64::from(self.renderer.scene.length())
    }

    /// Height of the object's centre above the table (m).
    fn centre_height(&self) -> f64 {
        let (lo, hi) = self.renderer.scene.bounds();
        f64::from(lo.y + hi.y) * 0.5
    }

    /// Horizontal camera-to-axis distance (m) for a distance ratio: the camera-to-centre distance
    /// is `ratio × length`, measured to the axis point at the object's centre height.
    pub fn horizontal_distance(&self, ratio: f64) -> Result<f64> {
        let d = ratio * self.object_length();
        let dh = self.config.camera.height_m - self.centre_height();
        if d <= dh.abs() {
            bail!("distance ratio {ratio}: the camera is {:.3} m above the object's centre, more than the distance {d:.3} m", dh);
        }
        Ok((d * d - dh * dh).sqrt())
    }

    /// The rail position (µm) that puts the camera at `ratio`.
    pub fn rail_target(&self, ratio: f64) -> Result<i32> {
        let r = &self.config.rail;
        let p = self.horizontal_distance(ratio)? - r.near_m;
        if !(0.0..=r.length_m).contains(&p) {
            bail!(
                "distance ratio {ratio} needs the camera {:.3} m from the axis, outside the rail ({:.3}–{:.3} m)",
                p + r.near_m,
                r.near_m,
                r.near_m + r.length_m
            );
        }
        Ok((p * 1e6).round() as i32)
    }

    /// The camera pose in the object's frame with the table at `angle_deg` and the camera
    /// `horizontal_m` from the axis (its intrinsics are the lens's pinhole part).
    pub(crate) fn camera_at(&self, angle_deg: f64, horizontal_m: f64) -> Result<Camera> {
        let e = self.config.camera.elevation_deg.to_radians() as f32;
        let eye = Vec3::new(horizontal_m as f32, self.config.camera.height_m as f32, 0.0);
        let world = Camera::look_at(
            self.lens.intrinsics(),
            eye,
            eye + Vec3::new(-e.cos(), -e.sin(), 0.0),
        )?;
        Ok(self.to_object_frame(world, angle_deg))
    }

    fn to_object_frame(&self, world: Camera, angle_deg: f64) -> Camera {
        let back = Mat3::from_rotation_y(-(angle_deg.to_radians() as f32));
        let [ax, az] = self.config.turntable.axis_m;
        let a = Vec3::new(ax as f32, 0.0, az as f32);
        Camera {
            intrinsics: world.intrinsics,
            eye: back * world.eye + a,
            rotation: back * world.rotation,
        }
    }

    /// The key lamp's direction (towards the lamp) in the object's frame at `angle_deg`.
    pub(crate) fn lamp_dir(&self, angle_deg: f64) -> Vec3 {
        let [az, el] = self.config.twin.lamp_dir_deg.map(f32::to_radians);
        let world = Vec3::new(el.cos() * az.cos(), el.sin(), el.cos() * az.sin());
        Mat3::from_rotation_y(-(angle_deg.to_radians() as f32)) * world
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_is_the_view_azimuth() {
        let (cfg, lens) = RigConfig::load(Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../calib/rig.toml"
        )))
        .unwrap();
        let rig = Rig::new(cfg, lens).unwrap();
        let d = rig.horizontal_distance(2.0).unwrap();
        for a in [0.0f64, 90.0, 200.0] {
            let cam = rig.camera_at(a, d).unwrap();
            let az = f64::from(cam.eye.z.atan2(cam.eye.x))
                .to_degrees()
                .rem_euclid(360.0);
            assert!((az - a).abs() < 1e-3, "{a} -> {az}");
            let dist =
                f64::from((cam.eye - Vec3::new(0.0, rig.centre_height() as f32, 0.0)).length());
            assert!((dist - 2.0 * rig.object_length()).abs() < 1e-4);
        }
    }
}
