//! The bake's colour measures: sRGB to CIELAB and CIE76 ΔE, 8-bit colours. Textures are sampled
//! by the one sampler the renderer trains with ([`cac_scene::bilinear`]).

/// sRGB display value (0..1) to linear light.
fn to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// sRGB (0..1) to CIELAB (D65).
pub(crate) fn srgb_to_lab(c: [f32; 3]) -> [f32; 3] {
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
    fn delta_e_of_black_and_white_is_100() {
        assert!((delta_e([0.0; 3], [1.0; 3]) - 100.0).abs() < 0.5);
        assert!(delta_e([0.3, 0.5, 0.2], [0.3, 0.5, 0.2]) < 1e-4);
    }
}
