//! The calibration's test bench: a simulated printer prints the chart, and the rig's digital twin
//! ([`crate::twin::DigitalTwin`], the camera of `cac capture --simulate`) photographs the page
//! — a textured quad standing on the turntable, turned away from the camera and looked down on,
//! lit by the rig's lamp and ambient, through the calibrated webcam's lens distortion, with its
//! exposure, blur and sensor noise. A real ColorChecker lies on the chart's squares: they show
//! the card's published colours, not the printer's. White balance is left off: the lamp's colour
//! ([`Shot::tint`]) tints the page.

use super::chart::{Chart, Ink, Role};
use crate::calib::CameraModel;
use crate::rig::{CameraMount, RailMount, Rig, RigConfig, TurntableMount, TwinSettings};
use crate::twin::{DigitalTwin, Pose};
use anyhow::{Context, Result};
use cac_core::colour;
use cac_render::config::ObjectConfig;
use cac_render::{RenderSettings, Renderer};
use cac_scene::{Material, Scene, Texture, Triangle};
use glam::{Vec2, Vec3};
use image::RgbImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::sync::Arc;

/// The rig's webcam (`calib/camera_opencv.yaml`: 640×480, strong barrel distortion).
pub fn rig_lens() -> CameraModel {
    CameraModel::parse(include_str!("../../../../calib/camera_opencv.yaml"))
        .expect("calib/camera_opencv.yaml parses")
}

/// A printer that is not a root-polynomial: per requested colour, in linear light, a tone curve
/// per channel (`l^gamma`), crosstalk between the inks, a gamut compression (each colour pulled
/// towards its grey by `1 / (1 + compression · (max − min))`, so saturated colours lose most),
/// then the paper's white and the ink's black; each printed patch varies by seeded noise
/// (relative `noise`, plus a fifth of it absolute).
#[derive(Clone, Debug, PartialEq)]
pub struct SimulatedPrinter {
    pub gamma: [f32; 3],
    pub crosstalk: [[f32; 3]; 3],
    pub compression: f32,
    /// Linear colour of the bare paper (white requested).
    pub white: [f32; 3],
    /// Linear level of full ink (black requested).
    pub black: f32,
    pub noise: f32,
}

impl Default for SimulatedPrinter {
    fn default() -> Self {
        SimulatedPrinter {
            gamma: [1.06, 0.96, 1.03],
            crosstalk: [[0.90, 0.07, 0.03], [0.05, 0.88, 0.07], [0.02, 0.08, 0.90]],
            compression: 0.5,
            white: [0.92, 0.91, 0.88],
            black: 0.004,
            noise: 0.01,
        }
    }
}

impl SimulatedPrinter {
    /// A printer with stronger tone curves (dot gain) and a greyer black: what the
    /// root-polynomial response cannot follow along the grey axis.
    pub fn dot_gain() -> Self {
        SimulatedPrinter {
            gamma: [1.15, 0.88, 1.08],
            black: 0.02,
            ..Default::default()
        }
    }

    fn linear(&self, srgb: [f32; 3]) -> [f32; 3] {
        let l: [f32; 3] =
            std::array::from_fn(|c| colour::decode(srgb[c].clamp(0.0, 1.0)).powf(self.gamma[c]));
        let x = self
            .crosstalk
            .map(|m| m[0] * l[0] + m[1] * l[1] + m[2] * l[2]);
        let y = 0.2126 * x[0] + 0.7152 * x[1] + 0.0722 * x[2];
        let spread =
            x.iter().fold(f32::MIN, |a, &b| a.max(b)) - x.iter().fold(f32::MAX, |a, &b| a.min(b));
        let k = 1.0 / (1.0 + self.compression * spread);
        std::array::from_fn(|c| {
            let v = y + (x[c] - y) * k;
            self.black + (self.white[c] - self.black) * v
        })
    }

    /// The printed colour (sRGB display value) of a requested one, without the noise.
    pub fn print(&self, srgb: [f32; 3]) -> [f32; 3] {
        self.linear(srgb).map(|v| colour::encode(v.clamp(0.0, 1.0)))
    }

    /// One printed patch: [`Self::print`] with its noise.
    pub fn print_patch(&self, srgb: [f32; 3], rng: &mut ChaCha8Rng) -> [f32; 3] {
        let unit = Normal::new(0.0f32, 1.0).expect("valid normal");
        self.linear(srgb).map(|v| {
            let v = v * (1.0 + self.noise * unit.sample(rng)) + 0.2 * self.noise * unit.sample(rng);
            colour::encode(v.clamp(0.0, 1.0))
        })
    }

    /// The chart as this printer prints it, `width` × `height` pixels, with a real ColorChecker
    /// (and for FDM, real filament swatches in their nominal colours) laid on their squares.
    pub fn printed_page(&self, chart: &Chart, width: u32, height: u32, seed: u64) -> RgbImage {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0070_7269_6e74_6572);
        let patches: Vec<[u8; 3]> = chart
            .patches
            .iter()
            .enumerate()
            .map(|(i, p)| match p.role {
                Role::Printed => colour::to_rgb8(self.print_patch(chart.srgb(i), &mut rng)),
                Role::Checker | Role::Filament => colour::to_rgb8(chart.srgb(i)),
            })
            .collect();
        let paper = colour::to_rgb8(self.print([1.0; 3]));
        let ink = colour::to_rgb8(self.print([0.0; 3]));
        chart.draw(width, height, &|what| match what {
            Ink::Paper => paper,
            Ink::Black => ink,
            Ink::CheckerFrame => CARD_BORDER,
            Ink::Patch(i) => patches[i],
        })
    }
}

/// The black border round a ColorChecker's patches.
const CARD_BORDER: [u8; 3] = [26, 26, 26];

/// How the twin photographs the page.
#[derive(Clone, Debug)]
pub struct Shot {
    /// The page turned about the vertical axis away from facing the camera, degrees.
    pub angle_deg: f64,
    /// The camera looks down on the page's centre by this much, degrees.
    pub elevation_deg: f64,
    /// Share of the photo's width the page's nearer half would span twice over.
    pub fill: f64,
    /// The twin's exposure gain (1: as rendered; white paper near 0.85).
    pub exposure: f32,
    /// The lamp's colour (multiplies the page's display values; white balance is off).
    pub tint: [f32; 3],
    pub lens: CameraModel,
    /// Samples per pixel.
    pub samples: usize,
    /// Side of the square texture the page is drawn into.
    pub atlas: usize,
    /// The sensor noise's seed.
    pub seed: u64,
}

impl Default for Shot {
    fn default() -> Self {
        Shot {
            angle_deg: 30.0,
            elevation_deg: 10.0,
            fill: 0.75,
            exposure: 1.0,
            tint: [1.0, 0.95, 0.85],
            lens: rig_lens(),
            samples: 4,
            atlas: 1024,
            seed: 1,
        }
    }
}

/// Photographs a page (`page`, drawn at any size; see [`SimulatedPrinter::printed_page`]) of
/// `chart`'s size with the rig's digital twin.
pub fn photograph(page: &RgbImage, chart: &Chart, shot: &Shot) -> Result<RgbImage> {
    let [w, h] = chart.page_mm.map(|v| v / 1000.0);
    let centre_y = h / 2.0 + 0.05;
    let lens = &shot.lens;
    let d = camera_distance(w, h, shot);
    let settings = RenderSettings {
        width: lens.width,
        height: lens.height,
        samples: shot.samples,
        vfov_deg: 45.0, // unused: the lens gives the rays
        atlas_res: shot.atlas,
    };
    let rig = Rig {
        renderer: Renderer::new(page_scene(w, h, centre_y), settings)
            .context("the chart's twin")?,
        config: twin_config(shot, centre_y, d),
        lens: lens.clone(),
        room: None,
    };
    let atlas = lit_atlas(page, shot);
    let pose = Pose {
        angle_deg: shot.angle_deg,
        horizontal_m: d,
    };
    let twin = DigitalTwin::new(Arc::new(rig), &atlas, Box::new(move || Ok(pose)), shot.seed);
    Ok(twin.render(pose, 0)?.image)
}

/// The camera's horizontal distance from the turntable's axis, m: the nearer half of the page
/// (`w` × `h` m), foreshortened, spans `fill` of half the width; its height fits in 90 % of the
/// frame.
fn camera_distance(w: f32, h: f32, shot: &Shot) -> f64 {
    let lens = &shot.lens;
    let theta = shot.angle_deg.to_radians();
    let half_w = f64::from(w) / 2.0;
    let near = half_w * theta.sin().abs();
    (lens.fx * half_w * theta.cos() / (shot.fill * lens.width as f64 / 2.0) + near)
        .max(lens.fy * f64::from(h) / 2.0 / (0.45 * lens.height as f64) + near)
}

/// The page (`w` × `h` m) as a textured quad standing on the turntable's axis facing +X (the
/// camera at angle 0), its centre `centre_y` m up.
fn page_scene(w: f32, h: f32, centre_y: f32) -> Scene {
    // Top-left first.
    let corners = [
        Vec3::new(0.0, centre_y + h / 2.0, w / 2.0),
        Vec3::new(0.0, centre_y + h / 2.0, -w / 2.0),
        Vec3::new(0.0, centre_y - h / 2.0, -w / 2.0),
        Vec3::new(0.0, centre_y - h / 2.0, w / 2.0),
    ];
    Scene {
        name: "print chart".into(),
        positions: corners.to_vec(),
        normals: vec![],
        uvs: vec![
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 0.0),
        ],
        triangles: [[0, 3, 2], [0, 2, 1]]
            .map(|p| Triangle {
                p,
                uv: Some(p),
                n: None,
                material: 0,
            })
            .to_vec(),
        materials: vec![Material {
            name: "paper".into(),
            base_color: [1.0; 3],
            texture: None,
            specular: 0.0,
            shininess: 1.0,
        }],
        textures: vec![],
        paintable: vec![true],
    }
}

/// The twin rig's settings: the camera `d` m from the axis, looking down on the page's centre
/// (`centre_y` m up) by the shot's elevation; no rail; the shot's samples and exposure.
fn twin_config(shot: &Shot, centre_y: f32, d: f64) -> RigConfig {
    RigConfig {
        camera: CameraMount {
            intrinsics: Default::default(),
            resolution: None,
            height_m: f64::from(centre_y) + d * shot.elevation_deg.to_radians().tan(),
            elevation_deg: shot.elevation_deg,
            fps: None,
            exposure: None,
            white_balance_k: None,
            focus: None,
        },
        turntable: TurntableMount {
            axis_m: [0.0, 0.0],
            settle_ms: 0,
            speed_deg_s: None,
        },
        rail: RailMount {
            present: false,
            near_m: 0.0,
            length_m: 0.0,
        },
        object: ObjectConfig::default(),
        ratios: vec![1.0],
        twin: TwinSettings {
            samples: shot.samples,
            background: [0.3, 0.3, 0.32],
            ground: None,
            exposure: shot.exposure,
            ..Default::default()
        },
    }
}

/// The page as the quad's texture, resized to the shot's atlas and tinted by the lamp.
fn lit_atlas(page: &RgbImage, shot: &Shot) -> Texture {
    let mut atlas = Texture::from_rgb8(page);
    if atlas.width != shot.atlas || atlas.height != shot.atlas {
        atlas = atlas.resized(shot.atlas, shot.atlas);
    }
    for t in &mut atlas.texels {
        for (v, k) in t.iter_mut().zip(shot.tint) {
            *v *= k;
        }
    }
    atlas
}
