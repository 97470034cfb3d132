//! Which texels of an atlas the paintable surfaces sample ([`paintable_texels`]), and a
//! whole-atlas texture (a simple texture, an image) put on those texels only ([`paint`]), as
//! every attack's atlas is. Used by the 2D baselines (`attack::baselines::atlas`) and by the
//! benchmarks that paint simple textures (`eval::realism`); and the size of a texel on the object
//! ([`texel_size`]), which sets the smallest region a printer can draw.

use crate::mesh::Scene;
use crate::texture::Texture;

/// The mean side of one texel of a `res × res` atlas on the paintable surfaces, in scene units:
/// `√(Σ surface area / (Σ UV area · res²))` over the paintable triangles (`None` when none has
/// UV area). A printer that draws no finer than its nozzle needs regions of that many texels.
pub fn texel_size(scene: &Scene, res: usize) -> Option<f32> {
    let (mut area, mut uv_area) = (0.0f64, 0.0f64);
    for t in scene.triangles.iter().filter(|t| scene.is_paintable(t)) {
        let Some(uv) = t.uv else { continue };
        let [a, b, c] = t.p.map(|i| scene.positions[i as usize]);
        let [u, v, w] = uv.map(|i| scene.uvs[i as usize]);
        area += 0.5 * (b - a).cross(c - a).length() as f64;
        uv_area += 0.5 * ((v - u).perp_dot(w - u)).abs() as f64;
    }
    (uv_area > 0.0 && area > 0.0).then(|| (area / (uv_area * (res * res) as f64)).sqrt() as f32)
}

/// Per texel of a `res × res` atlas: could a paintable surface sample it? Paintable triangles
/// are rasterised in UV space at 4 × 4 samples per texel, then the mask grows by one texel
/// (bilinear sampling reads the neighbours of the texel a point falls in; like the renderer's
/// repeat addressing, the growth wraps around the atlas edges).
pub fn paintable_texels(scene: &Scene, res: usize) -> Vec<bool> {
    let mut hit = vec![false; res * res];
    let rf = res as f32;
    for t in scene.triangles.iter().filter(|t| scene.is_paintable(t)) {
        let Some(uv) = t.uv else { continue };
        // Texel space: x = u·R, y = (1 − v)·R (row 0 at v = 1).
        let q = uv.map(|i| {
            let p = scene.uvs[i as usize];
            (p.x * rf, (1.0 - p.y) * rf)
        });
        let lo_x = q
            .iter()
            .map(|p| p.0)
            .fold(f32::MAX, f32::min)
            .floor()
            .max(0.0) as usize;
        let hi_x = (q
            .iter()
            .map(|p| p.0)
            .fold(f32::MIN, f32::max)
            .ceil()
            .max(0.0) as usize)
            .min(res);
        let lo_y = q
            .iter()
            .map(|p| p.1)
            .fold(f32::MAX, f32::min)
            .floor()
            .max(0.0) as usize;
        let hi_y = (q
            .iter()
            .map(|p| p.1)
            .fold(f32::MIN, f32::max)
            .ceil()
            .max(0.0) as usize)
            .min(res);
        let edge = |a: (f32, f32), b: (f32, f32), p: (f32, f32)| {
            (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0)
        };
        let area = edge(q[0], q[1], q[2]);
        if area.abs() < 1e-12 {
            continue;
        }
        for y in lo_y..hi_y {
            for x in lo_x..hi_x {
                let inside = (0..16).any(|s| {
                    let p = (
                        x as f32 + (s % 4) as f32 * 0.25 + 0.125,
                        y as f32 + (s / 4) as f32 * 0.25 + 0.125,
                    );
                    let w = [
                        edge(q[1], q[2], p),
                        edge(q[2], q[0], p),
                        edge(q[0], q[1], p),
                    ];
                    w.iter().all(|v| v * area.signum() >= -1e-6)
                });
                hit[y * res + x] |= inside;
            }
        }
    }
    let mut out = hit.clone();
    for y in 0..res {
        for x in 0..res {
            if hit[y * res + x] {
                for (dx, dy) in [
                    (-1i64, -1i64),
                    (0, -1),
                    (1, -1),
                    (-1, 0),
                    (1, 0),
                    (-1, 1),
                    (0, 1),
                    (1, 1),
                ] {
                    // The renderer addresses the atlas with repeat: neighbours wrap around.
                    let nx = (x as i64 + dx).rem_euclid(res as i64) as usize;
                    let ny = (y as i64 + dy).rem_euclid(res as i64) as usize;
                    out[ny * res + nx] = true;
                }
            }
        }
    }
    out
}

/// `base` with `texture`'s texels where `mask` is true: a whole-atlas texture (a simple texture,
/// an image) put on the paintable surfaces only, as every attack's atlas is.
pub fn paint(base: &Texture, texture: &Texture, mask: &[bool]) -> Texture {
    assert_eq!(mask.len(), base.texels.len(), "mask size");
    assert_eq!(texture.texels.len(), base.texels.len(), "texture size");
    let mut out = base.clone();
    for (k, m) in mask.iter().enumerate() {
        if *m {
            out.texels[k] = texture.texels[k];
        }
    }
    out
}
