//! Scenes: the 3D object to be camouflaged, as one indexed triangle mesh with UVs, materials and
//! the set of paintable parts.
//!
//! Loaders for OBJ (+MTL, textures) and glTF/GLB turn a file into a [`Scene`]; [`Scene::normalise`]
//! puts every object into the same frame (see `docs/conventions.md`): metres, **+Y up**, ground
//! contact at `y = 0`, the object's length along **+X** (its front facing +X), centred on the
//! origin in X and Z. The [`generate`] module builds the project's default meshes, [`textures`] the
//! simple baseline textures (Natural, Naive, Random), [`paint`] the paintable-texel mask and the
//! painting of a whole-atlas texture onto it, [`polygon`] ear clipping (profiles, hole filling).
//!
//! This module does not render and knows nothing about tensors.

pub mod bilinear;
pub mod generate;
mod gltf_load;
pub mod hostile;
mod load;
mod material;
mod mesh;
mod obj_load;
pub mod obj_write;
pub mod paint;
pub mod polygon;
mod texture;
pub mod textures;

pub use material::{Material, PaintRule};
pub use mesh::{LoadOptions, Scene, Triangle, BOX_QUADS};
pub use texture::Texture;
