//! The one bilinear texture sampler: what the renderer trains on (its differentiable atlas
//! sampling takes these [`taps`]), what the bake prints and what a resize resamples are sampled by
//! the same code. Texel centres at half-integers, UV origin lower-left (`v = 1` is row 0), and
//! repeat addressing (glTF's and 3MF's `wrap`) or clamp-to-edge (resampling).

use crate::texture::Texture;
use glam::Vec2;

/// How a texture is read outside its edges.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wrap {
    /// Tiled: `u = 1.25` reads `u = 0.25`.
    Repeat,
    /// The edge texel continues outward.
    Clamp,
}

/// The four bilinear taps (texel index, weight) of `uv` in a `w x h` texture.
#[inline]
pub fn taps(uv: Vec2, w: usize, h: usize, wrap: Wrap) -> [(u32, f32); 4] {
    let mut x = uv.x * w as f32 - 0.5;
    let mut y = (1.0 - uv.y) * h as f32 - 0.5;
    if wrap == Wrap::Clamp {
        x = x.clamp(0.0, (w - 1) as f32);
        y = y.clamp(0.0, (h - 1) as f32);
    }
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let index = |i: f32, n: usize| match wrap {
        Wrap::Repeat => (i as i64).rem_euclid(n as i64) as u32,
        Wrap::Clamp => (i as i64).min(n as i64 - 1) as u32,
    };
    let (xa, xb, ya, yb) = (
        index(x0, w),
        index(x0 + 1.0, w),
        index(y0, h),
        index(y0 + 1.0, h),
    );
    let w_ = w as u32;
    [
        (ya * w_ + xa, (1.0 - fx) * (1.0 - fy)),
        (ya * w_ + xb, fx * (1.0 - fy)),
        (yb * w_ + xa, (1.0 - fx) * fy),
        (yb * w_ + xb, fx * fy),
    ]
}

impl Texture {
    /// Bilinear resampling to a new size (texel centres aligned, clamp at the border).
    pub fn resized(&self, width: usize, height: usize) -> Self {
        let mut texels = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let u = (x as f32 + 0.5) / width as f32;
                let v = 1.0 - (y as f32 + 0.5) / height as f32;
                texels.push(self.sample_wrapped(Vec2::new(u, v), Wrap::Clamp));
            }
        }
        Texture {
            width,
            height,
            texels,
        }
    }

    /// Bilinear sample at `uv` with repeat addressing.
    pub fn sample(&self, uv: Vec2) -> [f32; 3] {
        self.sample_wrapped(uv, Wrap::Repeat)
    }

    /// Bilinear sample at `uv` with the given addressing.
    pub(crate) fn sample_wrapped(&self, uv: Vec2, wrap: Wrap) -> [f32; 3] {
        let mut out = [0.0; 3];
        for (i, w) in taps(uv, self.width, self.height, wrap) {
            let t = self.texels[i as usize];
            for c in 0..3 {
                out[c] += w * t[c];
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two texels, black then white, in one row.
    fn two() -> Texture {
        Texture {
            width: 2,
            height: 1,
            texels: vec![[0.0; 3], [1.0; 3]],
        }
    }

    #[test]
    fn texel_centres_are_exact_and_between_them_is_linear() {
        let t = two();
        assert_eq!(t.sample(Vec2::new(0.25, 0.5))[0], 0.0);
        assert_eq!(t.sample(Vec2::new(0.75, 0.5))[0], 1.0);
        assert!((t.sample(Vec2::new(0.5, 0.5))[0] - 0.5).abs() < 1e-6);
        let w: f32 = taps(Vec2::new(0.37, 0.81), 7, 5, Wrap::Repeat)
            .iter()
            .map(|t| t.1)
            .sum();
        assert!((w - 1.0).abs() < 1e-6);
    }

    #[test]
    fn repeat_wraps_and_clamp_holds_the_edge() {
        let t = two();
        // Past the right edge: repeat blends back to the black texel, clamp stays white.
        assert!((t.sample(Vec2::new(1.0, 0.5))[0] - 0.5).abs() < 1e-6);
        assert!(t.sample(Vec2::new(1.25, 0.5))[0].abs() < 1e-6);
        assert_eq!(t.sample_wrapped(Vec2::new(1.0, 0.5), Wrap::Clamp)[0], 1.0);
        assert_eq!(t.sample_wrapped(Vec2::new(-3.0, 0.5), Wrap::Clamp)[0], 0.0);
        // Far outside and at negative coordinates the indices stay in range.
        for u in [-1e4f32, -0.3, 7.9, 1e4] {
            for wrap in [Wrap::Repeat, Wrap::Clamp] {
                for (i, _) in taps(Vec2::new(u, u), 2, 1, wrap) {
                    assert!(i < 2, "{u} {wrap:?} {i}");
                }
            }
        }
    }
}
