//! Loading what `cac export` is given — the object (checked for paintable UVs) and the
//! camouflage texture (within the memory budget) — and [`prepare`], which turns both into a
//! [`PrintMesh`] in millimetres, +Z up, welded and checked.

use crate::mesh::{Paint, PrintMesh, PrintTri, Scale};
use crate::printcheck;
use anyhow::{bail, ensure, Context, Result};
use cac_core::memory::MemoryBudget;
use cac_scene::{LoadOptions, PaintRule, Scene, Texture};
use glam::Vec3;
use std::path::Path;

/// Largest accepted texture side, in texels (larger ones are refused before decoding).
pub(crate) const MAX_TEXTURE_SIDE: u32 = 16384;

/// Loads the mesh (a file, or a default object name: pickup, jeep, barrel, container) and checks that
/// every part the paint rule selects has UVs.
pub fn load_mesh(path: &Path, opts: &LoadOptions) -> Result<Scene> {
    if !path.exists() {
        if let Some(mut s) = cac_scene::generate::by_name(&path.to_string_lossy()) {
            s.normalise(opts.yaw_deg, opts.length_m);
            return Ok(s);
        }
        bail!("mesh file {} does not exist", path.display());
    }
    let scene = Scene::load(path, opts)?;
    check_paint_uvs(&scene, &opts.paint).with_context(|| format!("mesh {}", path.display()))?;
    Ok(scene)
}

/// Every material that the paint rule selects must have UVs on all its triangles, and at least
/// one part must be paintable.
pub(crate) fn check_paint_uvs(scene: &Scene, rule: &PaintRule) -> Result<()> {
    for (mi, m) in scene.materials.iter().enumerate() {
        if !rule.is_paintable(&m.name) {
            continue;
        }
        let tris = scene.triangles.iter().filter(|t| t.material as usize == mi);
        let (n, missing) = tris.fold((0, 0), |(n, k), t| (n + 1, k + t.uv.is_none() as usize));
        if missing > 0 {
            bail!(
                "part '{}' is to be painted but {missing} of its {n} triangles have no texture \
                 coordinates (UVs); unwrap it in a 3D editor or exclude it from the paint rule",
                m.name
            );
        }
    }
    if !scene.paintable.iter().any(|&p| p) {
        bail!("no part of the mesh is paintable (no material matches the paint rule)");
    }
    Ok(())
}

/// Memory per texel while a texture is decoded and held (8-bit decode, `f32` RGB texels).
const BYTES_PER_TEXEL: u64 = 4 + 3 * 4;

/// Loads the camouflage texture, refusing huge images before decoding them.
pub fn load_texture(path: &Path, budget: &MemoryBudget) -> Result<Texture> {
    let (w, h) = image::ImageReader::open(path)
        .with_context(|| format!("cannot open texture {}", path.display()))?
        .with_guessed_format()
        .with_context(|| format!("cannot read texture {}", path.display()))?
        .into_dimensions()
        .with_context(|| format!("{} is not a readable PNG/JPEG image", path.display()))?;
    if w > MAX_TEXTURE_SIDE || h > MAX_TEXTURE_SIDE {
        bail!(
            "texture {} is {w}x{h} texels; the largest accepted side is {MAX_TEXTURE_SIDE} \
             (downscale it first)",
            path.display()
        );
    }
    if w == 0 || h == 0 {
        bail!("texture {} is empty ({w}x{h})", path.display());
    }
    budget
        .check(
            &format!("texture {} ({w}x{h} texels)", path.display()),
            w as u64 * h as u64 * BYTES_PER_TEXEL,
            "downscale it",
        )
        .map_err(anyhow::Error::from)?;
    Ok(Texture::from_rgb8(&cac_core::io::load_rgb(path)?))
}

/// Scene (metres, +Y up) to print frame (mm, +Z up): `(x, y, z) -> (x, -z, y) * s`, a rotation
/// (orientation preserved).
fn to_print_frame(p: Vec3, mm_per_m: f32) -> Vec3 {
    Vec3::new(p.x, -p.z, p.y) * mm_per_m
}

/// Builds the print mesh: scales to mm, applies the camouflage to the paintable parts, welds
/// the positions (glTF splits vertices at UV seams) and runs the print-readiness check.
pub fn prepare(scene: &Scene, camo: &Texture, scale: Scale) -> Result<PrintMesh> {
    ensure!(
        scale.denominator.is_finite() && scale.denominator > 0.0,
        "scale 1:{} has no size",
        scale.denominator
    );
    let s = scale.mm_per_m() as f32;
    let raw: Vec<Vec3> = scene
        .positions
        .iter()
        .map(|&p| to_print_frame(p, s))
        .collect();
    let mut textures = vec![camo.clone()];
    // Other parts' textures, multiplied by their base colour, deduplicated.
    let mut tex_map: Vec<((usize, [u32; 3]), u32)> = vec![];
    let mut tris = Vec::with_capacity(scene.triangles.len());
    for t in &scene.triangles {
        let m = &scene.materials[t.material as usize];
        let uv = t.uv.map(|u| u.map(|i| scene.uvs[i as usize]));
        let paint = match (scene.is_paintable(t), uv, m.texture) {
            (true, Some(uv), _) => Paint::Texture { tex: 0, uv },
            (false, Some(uv), Some(ti)) => {
                let key = (ti, m.base_color.map(f32::to_bits));
                let tex = match tex_map.iter().find(|(k, _)| *k == key) {
                    Some(&(_, i)) => i,
                    None => {
                        let mut tx = scene.textures[ti].clone();
                        for c in &mut tx.texels {
                            for (ck, bk) in c.iter_mut().zip(m.base_color) {
                                *ck *= bk;
                            }
                        }
                        textures.push(tx);
                        tex_map.push((key, textures.len() as u32 - 1));
                        textures.len() as u32 - 1
                    }
                };
                Paint::Texture { tex, uv }
            }
            _ => Paint::Solid(m.base_color),
        };
        tris.push(PrintTri {
            v: t.p,
            paint,
            part: t.material,
        });
    }
    let (positions, report) = printcheck::weld_and_check(&raw, &mut tris)?;
    Ok(PrintMesh {
        name: scene.name.clone(),
        positions,
        tris,
        textures,
        parts: scene.materials.iter().map(|m| m.name.clone()).collect(),
        painted: scene.paintable.clone(),
        report,
    })
}
