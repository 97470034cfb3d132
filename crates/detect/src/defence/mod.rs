//! Input defences: the image transforms a detector's owner puts in front of the detector, so
//! that a camouflage can be judged (and trained) against them.
//!
//! A [`Defence`] is one transform with its parameter (`jpeg:75`, `blur:1`, `median:3`,
//! `bits:5`, `resize-pad:0.9`, `tv:0.03`, `lgs:2.3`); a [`Chain`] is several applied in turn
//! (`jpeg:75+blur:1`, or `none`). [`Defended`] puts a set of chains in front of a detector and is
//! itself a [`Detector`], so the evaluation, the scoring of sessions and videos and the attack
//! take it unchanged: with one chain it is that defence (its name is `nanodet+jpeg:75`), with
//! several it draws one chain per image (expectation over transformations, for an adaptive
//! attack). [`defend`] makes the evaluation's column groups: each detector undefended and under
//! each chain.
//!
//! Every random choice (the resize-and-pad's scale and offset, the TV solver's pixel dropout,
//! the chain drawn) is seeded by a hash of the image's own values, so a defence is a fixed
//! function of its input: a view scores the same in a whole evaluation and in any shard, and a
//! rerun reproduces it. Gradients: Gaussian blur and resize-and-pad are tensor operations and
//! pass the exact gradient; local gradient smoothing multiplies by a mask and passes the gradient
//! through the product with the mask held fixed; the others (JPEG's rounding, the median,
//! bit-depth reduction, the TV solver) pass the identity (BPDA, straight-through).

mod chain;
mod defended;
mod filters;
mod jpeg;
mod lgs;
mod tv;

pub use chain::{parse_chains, Affine, Chain, Defence, ACCEPTED};
pub use defended::{defend, image_seed, through, Defended};
pub use filters::{bit_depth, median};
pub use jpeg::jpeg;
pub use lgs::{lgs_mask, local_gradient_smoothing};
pub use tv::{tv_minimise, tv_objective, TvSettings};

/// One image's planes, channel-major (`[3, H, W]` as a flat slice), with its size.
#[derive(Clone, Copy, Debug)]
pub struct Planes<'a> {
    pub data: &'a [f32],
    pub height: usize,
    pub width: usize,
}

impl Planes<'_> {
    /// The value at channel `c`, row `y`, column `x`, the edges repeated outside the image.
    pub(crate) fn at_clamped(&self, c: usize, y: isize, x: isize) -> f32 {
        let y = y.clamp(0, self.height as isize - 1) as usize;
        let x = x.clamp(0, self.width as isize - 1) as usize;
        self.data[(c * self.height + y) * self.width + x]
    }
}

/// A 64-bit hash of an image's values (FNV-1a over the bits of every value): the seed of every
/// random choice a defence makes for that image.
pub fn image_hash(data: &[f32]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in data {
        h ^= v.to_bits() as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

#[cfg(test)]
mod tests;
