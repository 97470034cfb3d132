//! [`Scene::load`]: a mesh file (OBJ or glTF/GLB, by extension) to a normalised scene.

use crate::mesh::{LoadOptions, Scene};
use crate::{gltf_load, obj_load};
use anyhow::{bail, Context, Result};
use std::path::Path;

impl Scene {
    /// Loads an OBJ or glTF/GLB file (by extension), applies the paint rule and normalises it.
    pub fn load(path: &Path, opts: &LoadOptions) -> Result<Scene> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_lowercase();
        let mut scene = match ext.as_str() {
            "obj" => obj_load::load(path)?,
            "gltf" | "glb" => gltf_load::load(path)?,
            _ => bail!(
                "{}: unsupported mesh format (expected .obj, .gltf or .glb)",
                path.display()
            ),
        };
        scene
            .validate()
            .with_context(|| format!("invalid mesh in {}", path.display()))?;
        scene.apply_paint_rule(&opts.paint);
        scene.normalise(opts.yaw_deg, opts.length_m);
        Ok(scene)
    }
}
