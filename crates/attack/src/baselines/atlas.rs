//! Putting a 2D patch on "all sides of the vehicle", as the seed paper does for its 2D baselines:
//! the patch is tiled over the whole atlas and written into every paintable texel.
//!
//! The default objects pack their paintable faces into the atlas with area proportional to
//! metres, so one tile has the same physical size on every face: with `tiles` tiles across the
//! atlas, every side of the vehicle carries copies of the patch at one scale. Texels that no
//! paintable triangle covers keep the base texture. Not here: training the patch
//! ([`super::patch`]).

use cac_scene::Texture;

/// The paintable-texel mask and the painting of a whole-atlas texture live in the scene stage
/// (`scene::paint`), where the evaluation's benchmarks use them too.
pub use cac_scene::paint::{paint, paintable_texels};

/// `base` with `patch` tiled `tiles × tiles` times over the atlas, written into the texels where
/// `mask` is true (all others keep `base`).
pub(crate) fn paste_tiled(base: &Texture, patch: &Texture, mask: &[bool], tiles: usize) -> Texture {
    let res = base.width;
    assert_eq!(base.height, res, "the atlas must be square");
    assert_eq!(mask.len(), res * res, "mask size");
    let tile = (res / tiles.max(1)).max(1);
    let p = patch.resized(tile, tile);
    let mut out = base.clone();
    for y in 0..res {
        for x in 0..res {
            if mask[y * res + x] {
                out.texels[y * res + x] = p.texels[(y % tile) * tile + x % tile];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_jeep_mask_covers_part_of_the_atlas_and_tiling_respects_it() {
        let mut s = cac_scene::generate::jeep();
        s.normalise(0.0, None);
        let m = paintable_texels(&s, 64);
        let n = m.iter().filter(|&&b| b).count();
        assert!(n > 64 * 64 / 4 && n < 64 * 64, "{n} paintable texels");
        let base = Texture::solid(64, 64, [0.2, 0.3, 0.4]);
        let patch = Texture::solid(8, 8, [1.0, 0.0, 0.0]);
        let out = paste_tiled(&base, &patch, &m, 4);
        for (i, t) in out.texels.iter().enumerate() {
            assert_eq!(t == &[1.0, 0.0, 0.0], m[i]);
        }
    }
}
