//! The textures of an evaluation, from short specs: `original` (the object's own atlas),
//! `natural`, `naive`, `random` (the simple baselines, generated from the seed at the atlas
//! resolution), or `NAME=PATH` where PATH is an atlas PNG/JPEG or a run folder (its `atlas.png`).

use anyhow::{bail, Context, Result};
use cac_core::printer::{Printer, Profile};
use cac_scene::textures::{self, Kind};
use cac_scene::{Scene, Texture};
use std::path::Path;

/// A named texture of the evaluation.
pub struct NamedTexture {
    /// Row name in the tables (Original, Natural, Naive, Random, or the given NAME).
    pub name: String,
    /// Where it came from (for the report and the resume check).
    pub source: String,
    pub atlas: Texture,
}

/// Resolves one spec (see the module doc) for `scene` at atlas side `res`.
pub fn resolve(spec: &str, scene: &Scene, res: usize, seed: u64) -> Result<NamedTexture> {
    if let Some((name, path)) = spec.split_once('=') {
        if name.trim().is_empty() {
            bail!("texture spec {spec:?}: the name before '=' is empty");
        }
        let p = Path::new(path);
        let file = if p.is_dir() {
            p.join("atlas.png")
        } else {
            p.to_path_buf()
        };
        let img = cac_core::io::load_rgb(&file)
            .with_context(|| format!("texture {name:?} (spec {spec:?})"))?;
        let mut atlas = Texture::from_rgb8(&img);
        if atlas.width != res || atlas.height != res {
            atlas = atlas.resized(res, res);
        }
        return Ok(NamedTexture {
            name: name.trim().to_string(),
            source: file.display().to_string(),
            atlas,
        });
    }
    let (name, atlas) = match spec.to_ascii_lowercase().as_str() {
        "original" => ("Original", scene.initial_atlas(res)),
        "natural" => ("Natural", textures::generate(Kind::Natural, res, seed)?),
        "naive" => ("Naive", textures::generate(Kind::Naive, res, seed)?),
        "random" => ("Random", textures::generate(Kind::Random, res, seed)?),
        _ => bail!(
            "unknown texture {spec:?}: use original, natural, naive, random or NAME=PATH \
             (an atlas image or a run folder with atlas.png)"
        ),
    };
    Ok(NamedTexture {
        name: name.into(),
        source: format!("{} (seed {seed})", spec.to_ascii_lowercase()),
        atlas,
    })
}

/// Resolves every spec; names must be unique.
pub(crate) fn resolve_all(
    specs: &[String],
    scene: &Scene,
    res: usize,
    seed: u64,
) -> Result<Vec<NamedTexture>> {
    let out = specs
        .iter()
        .map(|s| resolve(s, scene, res, seed))
        .collect::<Result<Vec<_>>>()?;
    for (k, t) in out.iter().enumerate() {
        if out[..k].iter().any(|u| u.name == t.name) {
            bail!("texture name {:?} is given twice", t.name);
        }
    }
    if out.is_empty() {
        bail!("no textures to evaluate");
    }
    Ok(out)
}

/// Puts every texture through the printer of the profile at `path`: each texel becomes what the
/// printer makes of it ([`Printer::as_printed`]: the nearest filament by ΔE2000, or the fitted
/// response). A texture trained through the same FDM printer is unchanged.
pub(crate) fn print_all(texs: &mut [NamedTexture], path: &Path) -> Result<()> {
    let profile = Profile::load(path)?;
    let printer = profile.printer()?;
    for t in texs.iter_mut() {
        as_printed(&mut t.atlas, &printer);
        t.source = format!("{} as printed by {}", t.source, path.display());
    }
    Ok(())
}

/// A texture as `printer` makes it, texel by texel.
pub fn as_printed(atlas: &mut Texture, printer: &Printer) {
    atlas
        .texels
        .iter_mut()
        .for_each(|c| *c = printer.as_printed(*c));
}
