//! Texture sampling for the bake and its error measure: bilinear in sRGB values with repeat
//! addressing (glTF's and 3MF's `wrap`), UV origin lower-left (`v = 1` is row 0), and CIE76 ΔE.

use cac_scene::Texture;
use glam::Vec2;

/// Bilinear sample of `t` at `uv` (texel centres at half-integers, repeat addressing).
pub fn sample(t: &Texture, uv: Vec2) -> [f32; 3] {
    let (w, h) = (t.width as i64, t.height as i64);
    let x = uv.x as f64 * w as f64 - 0.5;
    let y = (1.0 - uv.y as f64) * h as f64 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let at = |xx: i64, yy: i64| t.texels[(yy.rem_euclid(h) * w + xx.rem_euclid(w)) as usize];
    let (a, b, c, d) = (
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    );
    let mut out = [0.0; 3];
    for k in 0..3 {
        let top = a[k] + (b[k] - a[k]) * fx;
        let bot = c[k] + (d[k] - c[k]) * fx;
        out[k] = top + (bot - top) * fy;
    }
    out
}

/// sRGB display value (0..1) to linear light.
fn to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// sRGB (0..1) to CIELAB (D65).
pub fn srgb_to_lab(c: [f32; 3]) -> [f32; 3] {
    let [r, g, b] = c.map(|v| to_linear(v.clamp(0.0, 1.0)));
    let x = (0.4124 * r + 0.3576 * g + 0.1805 * b) / 0.95047;
    let y = 0.2126 * r + 0.7152 * g + 0.0722 * b;
    let z = (0.0193 * r + 0.1192 * g + 0.9505 * b) / 1.08883;
    let f = |t: f32| {
        if t > 0.008856 {
            t.cbrt()
        } else {
            7.787 * t + 16.0 / 116.0
        }
    };
    let (fx, fy, fz) = (f(x), f(y), f(z));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIE76 colour difference between two sRGB colours.
pub fn delta_e(a: [f32; 3], b: [f32; 3]) -> f32 {
    let (p, q) = (srgb_to_lab(a), srgb_to_lab(b));
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

/// `#RRGGBB` of an sRGB colour, 8 bits per channel.
pub fn to_rgb8(c: [f32; 3]) -> [u8; 3] {
    c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_hits_texel_centres_and_wraps() {
        let t = Texture {
            width: 2,
            height: 1,
            texels: vec![[0.0; 3], [1.0; 3]],
        };
        assert_eq!(sample(&t, Vec2::new(0.25, 0.5))[0], 0.0);
        assert_eq!(sample(&t, Vec2::new(0.75, 0.5))[0], 1.0);
        assert!((sample(&t, Vec2::new(0.5, 0.5))[0] - 0.5).abs() < 1e-6);
        // u = 1.0 is halfway between the last texel and the first (wrapped).
        assert!((sample(&t, Vec2::new(1.0, 0.5))[0] - 0.5).abs() < 1e-6);
        assert!((sample(&t, Vec2::new(1.25, 0.5))[0]).abs() < 1e-6);
    }

    #[test]
    fn delta_e_of_black_and_white_is_100() {
        assert!((delta_e([0.0; 3], [1.0; 3]) - 100.0).abs() < 0.5);
        assert!(delta_e([0.3, 0.5, 0.2], [0.3, 0.5, 0.2]) < 1e-4);
    }
}
