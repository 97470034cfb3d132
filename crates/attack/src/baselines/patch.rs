//! The 2D parameterisation of AdvPat and ShapeShifter: a square patch, pasted under random plane
//! transformations onto rendered images of the vehicle (its original texture, the environment's
//! conditions); the camouflage is then the patch tiled over every paintable texel
//! ([`super::atlas`]). The one trainer ([`crate::Trainer`]) optimises it with Adam like
//! any other parameterisation.
//!
//! The backgrounds are rendered with the same environment draw as CAC's iterations (seeded by the
//! run seed and the iteration), and the transforms are seeded by the iteration too, so resuming
//! from a checkpoint continues exactly. Not here: the objectives ([`super::objectives`]) or the
//! transforms themselves ([`super::patch2d`]).

use super::{atlas, patch2d};
use anyhow::Result;
use burn::tensor::{Device, Tensor};
use cac_render::environment::{self, Condition, Environment};
use cac_render::{self as render, Renderer};
use cac_scene::Texture;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Thys et al.'s weight of the total-variation term (AdvPat only).
pub(crate) const TV_WEIGHT: f64 = 2.5;

/// Where a 2D patch goes: the object's texture and its paintable texels.
pub struct Patch {
    /// The object's texture: the backgrounds' vehicle and the atlas outside paintable texels.
    pub base: Texture,
    pub mask: Vec<bool>,
    pub ranges: patch2d::TransformRanges,
    /// Copies of the patch across the atlas side.
    pub tiles: usize,
}

impl Patch {
    /// `base` at the renderer's atlas resolution.
    pub fn new(renderer: &Renderer, base: Texture, tiles: usize) -> Self {
        Patch {
            mask: atlas::paintable_texels(&renderer.scene, base.width),
            base,
            ranges: patch2d::TransformRanges::default(),
            tiles,
        }
    }

    /// The images of iteration `i` of a run seeded `seed`: the backgrounds of `conds` (the
    /// iteration's conditions, rendered on the inner device of `device`) with `patch`
    /// (`[1, P, P, 3]`, on `device`) pasted under the iteration's transforms, and the object
    /// boxes the patch was placed in.
    pub fn images(
        &self,
        r: &Renderer,
        env: &Environment,
        conds: &[Condition],
        (seed, i): (u64, usize),
        patch: Tensor<4>,
        device: &Device,
    ) -> Result<(Tensor<4>, Vec<Option<[f32; 4]>>)> {
        let base = render::atlas_tensor(&self.base, &device.clone().inner());
        let (img, plans) = environment::form(r, env, conds, base)?;
        let (w, h) = (r.settings.width as f32, r.settings.height as f32);
        let boxes: Vec<[f32; 4]> = plans
            .iter()
            .map(|p| {
                p.object_box
                    .unwrap_or([0.25 * w, 0.25 * h, 0.75 * w, 0.75 * h])
            })
            .collect();
        let dims = img.dims();
        let bg = cac_detect::to_vec(&img)?;
        let mut rng = ChaCha8Rng::seed_from_u64(
            seed.wrapping_mul(0xD1B5_4A32_D192_ED03) ^ (i as u64).wrapping_add(0x5EED),
        );
        let ts: Vec<_> = boxes
            .iter()
            .map(|b| self.ranges.sample(*b, &mut rng))
            .collect();
        let images = patch2d::paste(&bg, dims, patch, &ts, device)?;
        Ok((images, boxes.into_iter().map(Some).collect()))
    }

    /// `patch` tiled over every paintable texel of the object's texture.
    pub(crate) fn on_object(&self, patch: &Texture) -> Texture {
        atlas::paste_tiled(&self.base, patch, &self.mask, self.tiles)
    }
}

/// Thys et al.'s total variation: mean absolute difference of horizontal and vertical neighbours
/// of a `[1, P, P, 3]` patch.
pub(crate) fn total_variation(patch: Tensor<4>) -> Tensor<1> {
    let [_, p, _, _] = patch.dims();
    let dx = patch.clone().slice([0..1, 0..p, 1..p, 0..3])
        - patch.clone().slice([0..1, 0..p, 0..p - 1, 0..3]);
    let dy =
        patch.clone().slice([0..1, 1..p, 0..p, 0..3]) - patch.slice([0..1, 0..p - 1, 0..p, 0..3]);
    (dx.abs().sum() + dy.abs().sum()) / (p * p * 3) as f64
}
