//! Colour, once: the sRGB transfer function (display value ↔ linear light), CIELAB (D65) and
//! the CIEDE2000 colour difference, on the `palette` crate (a maintained implementation of the
//! standards, checked against colour-science in `tests/printer.rs`) rather than formulas of our
//! own. The renderer, the bake, the sheets, the twin and the printer models all use these.

use palette::color_difference::Ciede2000;
use palette::encoding::{FromLinear, IntoLinear};
use palette::{FromColor, Lab, LinSrgb, Srgb};

/// Display value → linear light (the sRGB transfer function; not clamped: values above 1 stay
/// above 1, so light levels survive; values below 0 follow the linear toe).
pub fn decode(x: f32) -> f32 {
    <palette::encoding::Srgb as IntoLinear<f32, f32>>::into_linear(x)
}

/// Linear light → display value (inverse of [`decode`]).
pub fn encode(x: f32) -> f32 {
    <palette::encoding::Srgb as FromLinear<f32, f32>>::from_linear(x)
}

/// sRGB display value (each 0..1) → CIELAB (D65), `[L*, a*, b*]`. Values are clamped to the
/// display range first.
pub fn srgb_to_lab(c: [f32; 3]) -> [f32; 3] {
    let [r, g, b] = c.map(|v| v.clamp(0.0, 1.0));
    let lab: Lab = Lab::from_color(Srgb::new(r, g, b).into_linear::<f32>());
    [lab.l, lab.a, lab.b]
}

/// CIELAB (D65) → sRGB display value, clamped to 0..1 (colours outside the sRGB gamut clip).
pub fn lab_to_srgb(lab: [f32; 3]) -> [f32; 3] {
    let lin: LinSrgb = LinSrgb::from_color(Lab::new(lab[0], lab[1], lab[2]));
    let s = Srgb::<f32>::from_linear(LinSrgb::new(
        lin.red.clamp(0.0, 1.0),
        lin.green.clamp(0.0, 1.0),
        lin.blue.clamp(0.0, 1.0),
    ));
    [s.red, s.green, s.blue]
}

/// CIEDE2000 colour difference ΔE00 between two CIELAB colours.
pub fn delta_e2000(a: [f32; 3], b: [f32; 3]) -> f32 {
    Lab::<palette::white_point::D65, f32>::new(a[0], a[1], a[2])
        .difference(Lab::new(b[0], b[1], b[2]))
}

/// CIEDE2000 between two sRGB display colours.
pub fn delta_e2000_srgb(a: [f32; 3], b: [f32; 3]) -> f32 {
    delta_e2000(srgb_to_lab(a), srgb_to_lab(b))
}

/// CIE76 colour difference (Euclidean in CIELAB) between two sRGB colours: the distance that
/// k-means in Lab (a slicer's colour quantiser) works with.
pub fn delta_e76_srgb(a: [f32; 3], b: [f32; 3]) -> f32 {
    let (p, q) = (srgb_to_lab(a), srgb_to_lab(b));
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

/// An sRGB colour as 8 bits per channel (rounded, clamped).
pub fn to_rgb8(c: [f32; 3]) -> [u8; 3] {
    c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// `#RRGGBB` of an sRGB colour.
pub fn to_hex(c: [f32; 3]) -> String {
    let [r, g, b] = to_rgb8(c);
    format!("#{r:02X}{g:02X}{b:02X}")
}

/// An sRGB colour from `#RRGGBB` (or `RRGGBB`).
pub fn from_hex(s: &str) -> Option<[f32; 3]> {
    let h = s.trim().trim_start_matches('#');
    if h.len() != 6 || !h.is_ascii() {
        return None;
    }
    let c = |i: usize| u8::from_str_radix(&h[i..i + 2], 16).ok();
    Some([c(0)?, c(2)?, c(4)?].map(|v| v as f32 / 255.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decode_inverts_encode_across_and_above_the_display_range() {
        for k in 0..=400 {
            let x = k as f32 / 200.0;
            assert!((decode(encode(x)) - x).abs() < 1e-5 * (1.0 + x), "{x}");
        }
        assert!((encode(0.5) - 0.735_356_7).abs() < 1e-5);
        assert!((decode(0.02) - 0.02 / 12.92).abs() < 1e-7, "the linear toe");
    }

    #[test]
    fn white_is_lab_100_and_the_sharma_pair_has_its_published_difference() {
        let w = srgb_to_lab([1.0; 3]);
        assert!((w[0] - 100.0).abs() < 1e-3 && w[1].abs() < 1e-2 && w[2].abs() < 1e-2);
        // Sharma, Wu & Dalal (2005), test pair 1: ΔE00 = 2.0425.
        let d = delta_e2000([50.0, 2.6772, -79.7751], [50.0, 0.0, -82.7485]);
        assert!((d - 2.0425).abs() < 1e-3, "{d}");
        assert!((delta_e2000_srgb([0.2, 0.4, 0.6], [0.2, 0.4, 0.6])).abs() < 1e-6);
    }

    #[test]
    fn hex_round_trips() {
        assert_eq!(from_hex("#FF8000"), Some([1.0, 128.0 / 255.0, 0.0]));
        assert_eq!(to_hex([1.0, 128.0 / 255.0, 0.0]), "#FF8000");
        assert_eq!(from_hex("#FF80"), None);
        assert_eq!(from_hex("#GG0000"), None);
    }
}
