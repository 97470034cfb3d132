//! The differentiable renderer, as four small primitives in the spirit of nvdiffrast:
//!
//! 1. [`accel`]: BVH ray casting (obvhs CWBVH) — closest and any-hit queries;
//! 2. [`gbuffer`]: primary rays through a pinhole [`camera`] → per-sample triangle, barycentrics,
//!    UV, normal, depth, object mask (anti-aliasing by N samples per pixel);
//! 3. [`shade`]: lighting, shadows, ground and background → a [`RenderPlan`] (constant image +
//!    texel taps of the paintable atlas);
//! 4. [`composite`]: plan + atlas tensor → image tensor, differentiable with respect to the atlas.
//!
//! Geometry is fixed during an attack, so steps 1–3 run once per view on the CPU and only step 4
//! is in the autodiff graph. Ray casting is measured by `cac-bench` (`cac bench render`).
//!
//! Crate `cac-render`: this module (`cac::render`), with [`environment`] (the sampled viewing and
//! lighting conditions, the one image-formation call) and [`config`] (the scene config and presets)
//! beside it.

pub mod config;
pub mod environment;

pub mod accel;
pub mod camera;
pub mod composite;
pub mod gbuffer;
pub mod ibl;
pub mod light;
mod renderer;
pub mod shade;
mod sheet;
pub mod skyline;

pub use camera::{Camera, Intrinsics, Viewpoint};
pub use composite::{atlas_tensor, atlas_texture, composite, to_images};
pub use light::{Backdrop, Background, Ground, Lighting};
pub use renderer::{RenderSettings, Renderer, BAND_ROWS};
pub use shade::RenderPlan;
pub use sheet::contact_sheet;
