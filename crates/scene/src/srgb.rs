//! The sRGB transfer function, once: display values (what textures, colours and images hold)
//! to linear light and back. Not clamped: light levels above 1 stay above 1.

/// Linear light → display value.
pub fn encode(x: f32) -> f32 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Display value → linear light.
pub fn decode(x: f32) -> f32 {
    if x <= 0.04045 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn decode_inverts_encode_across_and_above_the_display_range() {
        for k in 0..=400 {
            let x = k as f32 / 200.0;
            assert!(
                (super::decode(super::encode(x)) - x).abs() < 1e-5 * (1.0 + x),
                "{x}"
            );
        }
        assert!((super::encode(0.5) - 0.735_356_7).abs() < 1e-5);
    }
}
