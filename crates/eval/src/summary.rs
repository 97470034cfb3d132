//! Aggregates per-image records into the protocol's figures: summaries per texture, model,
//! viewpoint set and brightness level; breakdowns against azimuth, elevation and distance ratio;
//! and the paper-shaped tables (textures as rows, models as column groups).

use super::run::{level_name, set_name, ImageRecord};
use super::score::group_by;
pub use super::score::Figures;
use cac_core::report::Table;
use cac_render::environment::{Brightness, ViewpointSet};
use serde::{Deserialize, Serialize};

/// Which records: `None` in a field matches any value.
#[derive(Clone, Copy, Debug, Default)]
pub struct Select<'a> {
    pub texture: Option<&'a str>,
    pub model: Option<&'a str>,
    pub set: Option<ViewpointSet>,
    pub brightness: Option<Brightness>,
}

impl Select<'_> {
    pub fn matches(&self, r: &ImageRecord) -> bool {
        self.texture.is_none_or(|t| t == r.texture)
            && self.model.is_none_or(|m| m == r.model)
            && self.set.is_none_or(|s| s == r.set)
            && self.brightness.is_none_or(|b| b == r.brightness)
    }
}

/// The selection of one texture and model, optionally one set and level.
pub fn sel<'a>(
    texture: &'a str,
    model: &'a str,
    set: Option<ViewpointSet>,
    brightness: Option<Brightness>,
) -> Select<'a> {
    Select {
        texture: Some(texture),
        model: Some(model),
        set,
        brightness,
    }
}

pub fn figures(records: &[ImageRecord], s: Select) -> Figures {
    Figures::of_scores(records.iter().filter(|r| s.matches(r)).map(|r| &r.score))
}

/// A viewing factor a breakdown is taken against.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Factor {
    Azimuth,
    Elevation,
    DistanceRatio,
}

impl Factor {
    pub const ALL: [Factor; 3] = [Factor::Azimuth, Factor::Elevation, Factor::DistanceRatio];
    pub fn name(self) -> &'static str {
        match self {
            Factor::Azimuth => "azimuth_deg",
            Factor::Elevation => "elevation_deg",
            Factor::DistanceRatio => "distance_ratio",
        }
    }
    pub fn value(self, r: &ImageRecord) -> f64 {
        match self {
            Factor::Azimuth => r.azimuth_deg as f64,
            Factor::Elevation => r.elevation_deg as f64,
            Factor::DistanceRatio => r.distance_ratio as f64,
        }
    }
    /// Bin width: 30° of azimuth, 10° of elevation, 0.5 object lengths.
    pub fn width(self) -> f64 {
        match self {
            Factor::Azimuth => 30.0,
            Factor::Elevation => 10.0,
            Factor::DistanceRatio => 0.5,
        }
    }
}

/// One bin of a breakdown, `[lo, hi)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bin {
    pub lo: f64,
    pub hi: f64,
    #[serde(flatten)]
    pub figures: Figures,
}

impl Bin {
    pub fn mid(&self) -> f64 {
        0.5 * (self.lo + self.hi)
    }
}

/// The figures of `records` in bins of `factor` (fixed-width bins aligned to multiples of the
/// width; empty bins are left out), in increasing order.
pub fn breakdown<'a>(
    records: impl IntoIterator<Item = &'a ImageRecord>,
    factor: Factor,
) -> Vec<Bin> {
    let w = factor.width();
    let mut bins = group_by(records, |r| (factor.value(r) / w).floor() as i64);
    bins.sort_by_key(|(k, _)| *k);
    bins.into_iter()
        .map(|(k, rs)| Bin {
            lo: k as f64 * w,
            hi: (k + 1) as f64 * w,
            figures: Figures::of_scores(rs.into_iter().map(|r| &r.score)),
        })
        .collect()
}

/// What a paper-shaped table shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Metric {
    /// P@0.5, with the drop against the reference texture in the Avg column.
    P05,
    TargetedSuccess,
    MeanBestTrueConf,
}

impl Metric {
    fn of(self, f: &Figures) -> f64 {
        match self {
            Metric::P05 => f.p_at_05,
            Metric::TargetedSuccess => f.targeted_success,
            Metric::MeanBestTrueConf => f.mean_best_true_conf,
        }
    }
}

fn avg_cell(m: Metric, v: f64, reference: Option<f64>) -> String {
    match (m, reference) {
        (Metric::P05, Some(r)) => format!("{v:.3} ({:.3})", r - v),
        (Metric::P05, None) => format!("{v:.3} (–)"),
        _ => format!("{v:.3}"),
    }
}

/// The paper's main table for one viewpoint set: textures as rows; per model L_b, L_d and Avg
/// (with the drop against `reference`, the first texture named there, for P@0.5).
pub(crate) fn level_table(
    records: &[ImageRecord],
    textures: &[String],
    models: &[String],
    set: ViewpointSet,
    reference: &str,
    m: Metric,
) -> Table {
    let avg = if m == Metric::P05 {
        "Avg (Drop)"
    } else {
        "Avg"
    };
    let mut header = vec!["Texture".to_string()];
    for _ in models {
        header.extend(["L_b".into(), "L_d".into(), avg.to_string()]);
    }
    let mut t = Table::new(header)
        .grouped(std::iter::once((String::new(), 1)).chain(models.iter().map(|m| (m.clone(), 3))));
    for tex in textures {
        let mut row = vec![tex.clone()];
        for model in models {
            let s = Some(set);
            for b in [Brightness::Bright, Brightness::Dark] {
                let f = figures(records, sel(tex, model, s, Some(b)));
                row.push(format!("{:.3}", m.of(&f)));
            }
            let v = m.of(&figures(records, sel(tex, model, s, None)));
            let r =
                (tex != reference).then(|| m.of(&figures(records, sel(reference, model, s, None))));
            row.push(avg_cell(m, v, r));
        }
        t.row(row);
    }
    t
}

/// RV against FV: textures as rows; per model the metric in each viewpoint set (both levels).
pub(crate) fn set_table(
    records: &[ImageRecord],
    textures: &[String],
    models: &[String],
    reference: &str,
    m: Metric,
) -> Table {
    let sets = [ViewpointSet::Restricted, ViewpointSet::Free];
    let mut header = vec!["Texture".to_string()];
    for _ in models {
        header.extend(sets.iter().map(|&s| set_name(s).to_string()));
    }
    let mut t = Table::new(header)
        .grouped(std::iter::once((String::new(), 1)).chain(models.iter().map(|m| (m.clone(), 2))));
    for tex in textures {
        let mut row = vec![tex.clone()];
        for model in models {
            for s in sets {
                let v = m.of(&figures(records, sel(tex, model, Some(s), None)));
                let r = (tex != reference)
                    .then(|| m.of(&figures(records, sel(reference, model, Some(s), None))));
                row.push(avg_cell(m, v, r));
            }
        }
        t.row(row);
    }
    t
}

/// Every summary as a long table: texture, model, set, level (`all` = both), figures, drop.
pub(crate) fn summary_rows(
    records: &[ImageRecord],
    textures: &[String],
    models: &[String],
    sets: &[ViewpointSet],
    reference: &str,
) -> Table {
    let mut t = Table::new([
        "texture",
        "model",
        "set",
        "level",
        "images",
        "p_at_05",
        "p_stderr",
        "drop",
        "targeted_success",
        "mean_best_true_conf",
    ]);
    for tex in textures {
        for model in models {
            for &s in sets {
                for b in [Some(Brightness::Bright), Some(Brightness::Dark), None] {
                    let f = figures(records, sel(tex, model, Some(s), b));
                    let r = figures(records, sel(reference, model, Some(s), b));
                    let drop = r.p_at_05 - f.p_at_05;
                    t.row([
                        tex.clone(),
                        model.clone(),
                        set_name(s).into(),
                        b.map_or("all", level_name).into(),
                        f.images.to_string(),
                        format!("{:.4}", f.p_at_05),
                        format!("{:.4}", f.p_stderr),
                        format!("{drop:.4}"),
                        format!("{:.4}", f.targeted_success),
                        format!("{:.4}", f.mean_best_true_conf),
                    ]);
                }
            }
        }
    }
    t
}

/// Every breakdown as a long table: texture, model, factor, bin, figures (all groups pooled).
pub(crate) fn breakdown_rows(
    records: &[ImageRecord],
    textures: &[String],
    models: &[String],
) -> Table {
    let mut t = Table::new([
        "texture",
        "model",
        "factor",
        "lo",
        "hi",
        "images",
        "p_at_05",
        "p_stderr",
        "targeted_success",
        "mean_best_true_conf",
    ]);
    for tex in textures {
        for model in models {
            let sel = Select {
                texture: Some(tex),
                model: Some(model),
                ..Default::default()
            };
            for f in Factor::ALL {
                for b in breakdown(records.iter().filter(|r| sel.matches(r)), f) {
                    t.row([
                        tex.clone(),
                        model.clone(),
                        f.name().into(),
                        format!("{}", b.lo),
                        format!("{}", b.hi),
                        b.figures.images.to_string(),
                        format!("{:.4}", b.figures.p_at_05),
                        format!("{:.4}", b.figures.p_stderr),
                        format!("{:.4}", b.figures.targeted_success),
                        format!("{:.4}", b.figures.mean_best_true_conf),
                    ]);
                }
            }
        }
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ImageScore;

    fn rec(tex: &str, set: ViewpointSet, b: Brightness, az: f32, hit: bool) -> ImageRecord {
        ImageRecord {
            texture: tex.into(),
            model: "m".into(),
            set,
            brightness: b,
            view: 0,
            azimuth_deg: az,
            elevation_deg: 5.0,
            distance_ratio: 1.2,
            gt: [0.0; 4],
            score: ImageScore {
                hit,
                targeted: !hit,
                best_true_conf: if hit { 0.8 } else { 0.1 },
            },
        }
    }

    #[test]
    fn tables_drops_and_breakdowns_count_the_right_images() {
        use Brightness::*;
        use ViewpointSet::*;
        let mut r = vec![];
        // Original: all hits in FV bright, half in FV dark; CAC: a quarter of FV bright, none dark.
        for k in 0..4 {
            r.push(rec("Original", Free, Bright, 10.0 + 90.0 * k as f32, true));
            r.push(rec("Original", Free, Dark, 10.0, k < 2));
            r.push(rec("CAC", Free, Bright, 10.0 + 90.0 * k as f32, k == 0));
            r.push(rec("CAC", Free, Dark, 10.0, false));
        }
        let tex = vec!["Original".to_string(), "CAC".to_string()];
        let t = level_table(&r, &tex, &["m".into()], Free, "Original", Metric::P05);
        assert_eq!(t.rows[0], ["Original", "1.000", "0.500", "0.750 (–)"]);
        assert_eq!(t.rows[1], ["CAC", "0.250", "0.000", "0.125 (0.625)"]);
        assert_eq!(t.flat_header()[3], "m Avg (Drop)");
        let f = figures(&r, sel("CAC", "m", Some(Free), Some(Bright)));
        assert!((f.p_stderr - (0.25f64 * 0.75 / 4.0).sqrt()).abs() < 1e-12);
        assert!((f.targeted_success - 0.75).abs() < 1e-12);
        let bins = breakdown(
            r.iter().filter(|x| x.texture == "Original"),
            Factor::Azimuth,
        );
        assert_eq!(
            bins.len(),
            4,
            "azimuths 10, 100, 190, 280 fall in four 30° bins"
        );
        assert_eq!(
            (bins[0].lo, bins[0].hi, bins[0].figures.images),
            (0.0, 30.0, 5)
        );
        assert!((bins[0].figures.p_at_05 - 0.6).abs() < 1e-12, "3 of 5 hits");
        let s = summary_rows(&r, &tex, &["m".into()], &[Free], "Original");
        assert_eq!(s.rows.len(), 2 * 3);
        assert_eq!(s.rows[5][7], "0.6250", "CAC drop over both levels");
    }
}
