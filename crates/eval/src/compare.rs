//! One texture against another on the same views (the demo's before and after): per model and
//! viewpoint set, P@0.5 and targeted success of each and the drop ([`before_after`]); both
//! atlases and, per model, a contact sheet of each texture's example views with that model's
//! detections drawn ([`write_sheets`]).

use super::run::{level_name, set_name, TextureResult};
use super::summary::{figures, sel};
use anyhow::Result;
use cac_render::environment::ViewpointSet;
use cac_scene::Texture;
use serde::Serialize;
use std::path::Path;

/// One model in one viewpoint set, before and after.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub(crate) struct BeforeAfter {
    pub model: String,
    /// What the model is to the attack (white-box, transfer).
    pub role: String,
    pub set: String,
    pub views: usize,
    pub p_at_05_before: f64,
    pub p_at_05_after: f64,
    pub drop: f64,
    /// Targeted success (the demo's target is a person).
    #[serde(rename = "person_before")]
    pub targeted_before: f64,
    #[serde(rename = "person_after")]
    pub targeted_after: f64,
}

/// Per `(model, role)` and viewpoint set (FV, RV): texture `before_name` in `before` against
/// `after_name` in `after`.
pub(crate) fn before_after(
    (before_name, before): (&str, &TextureResult),
    (after_name, after): (&str, &TextureResult),
    models: &[(&str, &str)],
) -> Vec<BeforeAfter> {
    let mut rows = vec![];
    for &(m, role) in models {
        for set in [ViewpointSet::Free, ViewpointSet::Restricted] {
            let b = figures(&before.records, sel(before_name, m, Some(set), None));
            let f = figures(&after.records, sel(after_name, m, Some(set), None));
            rows.push(BeforeAfter {
                model: m.to_string(),
                role: role.to_string(),
                set: set_name(set).to_string(),
                views: b.images,
                p_at_05_before: b.p_at_05,
                p_at_05_after: f.p_at_05,
                drop: b.p_at_05 - f.p_at_05,
                targeted_before: b.targeted_success,
                targeted_after: f.targeted_success,
            });
        }
    }
    rows
}

/// Writes both atlases (`atlas_original.png`, `atlas_learned.png`) and per model the view sheets
/// `views_{original,learned}_{model}.png` (examples scaled to 320 px, the model's boxes drawn);
/// returns the sheets' names and the views they show. `models` are in the detectors' order.
pub fn write_sheets(
    out: &Path,
    (original, before): (&Texture, &TextureResult),
    (learned, after): (&Texture, &TextureResult),
    models: &[&str],
) -> Result<(Vec<String>, Vec<String>)> {
    std::fs::create_dir_all(out)?;
    cac_core::io::save_png_atomic(&out.join("atlas_original.png"), &original.to_rgb8())?;
    cac_core::io::save_png_atomic(&out.join("atlas_learned.png"), &learned.to_rgb8())?;
    let mut sheets = vec![];
    for (m, model) in models.iter().enumerate() {
        for (tex, r) in [("original", before), ("learned", after)] {
            let imgs: Vec<_> = r
                .examples
                .iter()
                .map(|e| super::report::example_image(e, m, 320))
                .collect();
            let name = format!("views_{tex}_{model}.png");
            cac_core::io::save_png_atomic(&out.join(&name), &cac_render::contact_sheet(&imgs))?;
            sheets.push(name);
        }
    }
    let sheet_views: Vec<String> = before
        .examples
        .iter()
        .map(|e| {
            format!(
                "{} {} #{}",
                set_name(e.set),
                level_name(e.brightness),
                e.view
            )
        })
        .collect();
    Ok((sheets, sheet_views))
}
