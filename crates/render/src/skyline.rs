//! A distant skyline on the horizon: a ring of buildings (with rows of windows) and tree crowns,
//! a few degrees high, hazed towards the horizon colour. Street and dash cameras never see an
//! endless plane meeting an empty sky (that is what an airfield looks like); this gives the sky
//! backdrop the street context detectors were trained on. Procedural and deterministic: the ring
//! is a function of the view direction and a phase (so each view can face another part of it).

use cac_scene::generate::value_noise;
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// Where the ring starts and how bright it is lit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Skyline {
    /// Azimuth phase of the ring (degrees).
    pub phase_deg: f32,
    /// Light level (1 = daylight; the dark level dims it like the sky).
    pub light: f32,
}

/// Façade colours (display values): concrete, sandstone, brick, glass-blue, white render.
const FACADES: [[f32; 3]; 5] = [
    [0.55, 0.55, 0.53],
    [0.68, 0.60, 0.48],
    [0.52, 0.33, 0.27],
    [0.40, 0.47, 0.55],
    [0.78, 0.77, 0.74],
];

fn hash(i: i32, seed: u32) -> f32 {
    value_noise(i as f32 + 0.5, 0.5, seed)
}

impl Skyline {
    /// The skyline's colour along `dir` when it covers that direction, else `None` (the sky
    /// shows). `horizon` is the sky's horizon colour, used for distance haze.
    pub fn colour(&self, dir: Vec3, horizon: [f32; 3]) -> Option<[f32; 3]> {
        let el = dir.y.clamp(-1.0, 1.0).asin().to_degrees();
        if !(0.0..10.0).contains(&el) {
            return None;
        }
        let az = dir.z.atan2(dir.x).to_degrees() + self.phase_deg;
        // Buildings: 4° cells, some empty, heights 1.5–8°.
        let cell = (az / 4.0).floor() as i32;
        let h = hash(cell, 31);
        let building_h = if h > 0.35 {
            1.5 + 6.5 * hash(cell, 37)
        } else {
            0.0
        };
        // Tree crowns in front: bumpy, 0.8–3.5°.
        let crown = 0.8 + 2.7 * value_noise(az / 2.5, 0.0, 41) * value_noise(az / 0.6, 3.0, 43);
        let c = if el < crown {
            let n = value_noise(az / 0.15, el / 0.15, 47);
            let k = 0.75 + 0.5 * n;
            [0.16 * k, 0.24 * k, 0.12 * k]
        } else if el < building_h {
            let f = FACADES[(hash(cell, 53) * FACADES.len() as f32) as usize % FACADES.len()];
            // Rows and columns of windows.
            let (wx, wy) = ((az / 0.45).fract().abs(), (el / 0.5).fract());
            let window = (0.25..0.75).contains(&wx) && (0.3..0.8).contains(&wy);
            if window {
                [0.18, 0.20, 0.24]
            } else {
                f
            }
        } else {
            return None;
        };
        // Haze: a third of the way to the horizon colour; lit like the sky.
        Some([0, 1, 2].map(|i| (c[i] * self.light) * 0.65 + horizon[i] * 0.35))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_skyline_sits_on_the_horizon_and_varies_with_azimuth() {
        let s = Skyline {
            phase_deg: 0.0,
            light: 1.0,
        };
        let hz = [0.8, 0.85, 0.9];
        let at = |az: f32, el: f32| {
            let (a, e) = (az.to_radians(), el.to_radians());
            s.colour(Vec3::new(e.cos() * a.cos(), e.sin(), e.cos() * a.sin()), hz)
        };
        // Right above the horizon something always stands (tree crowns are at least 0.8°).
        assert!((0..360).all(|a| at(a as f32, 0.3).is_some()));
        // High up, only sky.
        assert!((0..360).all(|a| at(a as f32, 12.0).is_none()));
        // The outline varies: some azimuths are covered at 4°, others are not.
        let covered = (0..360).filter(|&a| at(a as f32, 4.0).is_some()).count();
        assert!(covered > 36 && covered < 324, "{covered}");
    }
}
