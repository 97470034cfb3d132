//! The differentiable step: render plans + camouflage atlas → image batch, as burn tensor ops.
//!
//! `image[v, p] = base[v, p] + Σ_k weight_k · atlas[v, texel_k]` over the taps of pixel `p` (a
//! weight per channel when the light is coloured, [`RenderPlan::tap_colour`]): one
//! gather from the atlas, one multiply, one scatter-add into the pixels. Geometry is fixed, so this
//! is the exact image as a function of the atlas, and autodiff gives exact gradients with respect
//! to every texel; no soft rasteriser is needed.

use super::shade::RenderPlan;
use burn::tensor::{IndexingUpdateOp, Int, Tensor, TensorData};

/// Composites `plans` (all of one size and atlas resolution) with `atlas`, shaped
/// `[1 or V, R, R, 3]` (one atlas for all views, or one per view, e.g. after print error).
/// Returns `[V, 3, H, W]` in the atlas's dtype and device.
pub fn composite(plans: &[RenderPlan], atlas: Tensor<4>) -> Tensor<4> {
    assert!(!plans.is_empty(), "composite needs at least one view");
    let (w, h, r) = (plans[0].width, plans[0].height, plans[0].atlas_res);
    assert!(
        plans
            .iter()
            .all(|p| p.width == w && p.height == h && p.atlas_res == r),
        "plans differ in size"
    );
    let [va, ra, rb, c] = atlas.dims();
    assert!(
        ra == r && rb == r && c == 3,
        "atlas must be [V,{r},{r},3], got {:?}",
        atlas.dims()
    );
    assert!(
        va == 1 || va == plans.len(),
        "atlas count must be 1 or the number of views"
    );
    let device = atlas.device();
    let dtype = atlas.dtype();
    let v = plans.len();
    let px = w * h;
    let mut base: Vec<f32> = Vec::with_capacity(v * px * 3);
    let taps: usize = plans.iter().map(|p| p.tap_pixel.len()).sum();
    // One weight per tap, or three when any plan's light is coloured.
    let ch = if plans.iter().any(|p| !p.tap_colour.is_empty()) {
        3
    } else {
        1
    };
    let (mut ip, mut it, mut wt): (Vec<i64>, Vec<i64>, Vec<f32>) = (
        Vec::with_capacity(taps),
        Vec::with_capacity(taps),
        Vec::with_capacity(taps * ch),
    );
    for (k, p) in plans.iter().enumerate() {
        base.extend(p.base.iter().flatten());
        let atlas_off = if va == 1 { 0 } else { k * r * r };
        ip.extend(p.tap_pixel.iter().map(|&i| (i as usize + k * px) as i64));
        it.extend(p.tap_texel.iter().map(|&i| (i as usize + atlas_off) as i64));
        if ch == 1 {
            wt.extend(&p.tap_weight);
        } else {
            wt.extend((0..p.tap_weight.len()).flat_map(|t| (0..3).map(move |c| p.weight(t, c))));
        }
    }
    let base = Tensor::<2>::from_data(TensorData::new(base, [v * px, 3]), (&device, dtype));
    let img = if taps == 0 {
        // Nothing paintable is visible: the image does not depend on the atlas, but keep it in
        // the graph (with zero gradient) so callers can always ask for a gradient.
        base + atlas.sum().reshape([1, 1]) * 0.0
    } else {
        let ip = Tensor::<1, Int>::from_data(TensorData::new(ip, [taps]), &device);
        let it = Tensor::<1, Int>::from_data(TensorData::new(it, [taps]), &device);
        let wt = Tensor::<2>::from_data(TensorData::new(wt, [taps, ch]), (&device, dtype));
        let flat = atlas.reshape([va * r * r, 3]);
        let gathered = flat.select(0, it) * wt;
        base.select_assign(0, ip, gathered, IndexingUpdateOp::Add)
    };
    img.reshape([v, h, w, 3]).permute([0, 3, 1, 2])
}

/// `[R, R, 3]` texels of a [`cac_scene::Texture`] as a `[1, R, R, 3]` tensor.
pub fn atlas_tensor(tex: &cac_scene::Texture, device: &burn::tensor::Device) -> Tensor<4> {
    let data: Vec<f32> = tex.texels.iter().flatten().copied().collect();
    Tensor::from_data(TensorData::new(data, [1, tex.height, tex.width, 3]), device)
}

/// A `[1, R, R, 3]` atlas tensor back to a texture (values clamped to [0, 1]).
pub fn atlas_texture(t: &Tensor<4>) -> cac_scene::Texture {
    let [_, h, w, _] = t.dims();
    let v: Vec<f32> = t
        .clone()
        .narrow(0, 0, 1)
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("atlas data");
    cac_scene::Texture {
        width: w,
        height: h,
        texels: v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    }
}

/// A `[V, 3, H, W]` image batch to 8-bit RGB images (clamped).
pub fn to_images(t: &Tensor<4>) -> Vec<image::RgbImage> {
    let [v, _, h, w] = t.dims();
    let data: Vec<f32> = t
        .clone()
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("image data");
    (0..v)
        .map(|k| {
            image::RgbImage::from_fn(w as u32, h as u32, |x, y| {
                let at = |c: usize| data[((k * 3 + c) * h + y as usize) * w + x as usize];
                image::Rgb([0, 1, 2].map(|c| (at(c).clamp(0.0, 1.0) * 255.0).round() as u8))
            })
        })
        .collect()
}
