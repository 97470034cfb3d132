//! The studies' figures: the top-n denseness study (the paper's Figure 5: P@0.5 of textures
//! trained with different numbers of fixed proposals n, per evaluation model, against the
//! original texture) and the methods table (every attack of one harness, per model and
//! viewpoint set). The training and the evaluation themselves are `attack::Trainer` and
//! [`crate::job`].

use crate::run::ImageRecord;
use crate::summary::{figures, sel, Figures};
use anyhow::Result;
use cac_core::report::{plot, Plot, Series, Table};
use cac_render::environment::ViewpointSet;

/// The texture (row) name of the run trained with `n` proposals.
pub(crate) fn run_name(n: usize) -> String {
    format!("n{n}")
}

fn role(model: &str, sources: &[String]) -> &'static str {
    if sources.iter().any(|s| s == model) {
        "white-box"
    } else {
        "transfer"
    }
}

fn at(records: &[ImageRecord], texture: &str, model: &str) -> Figures {
    figures(records, sel(texture, model, None, None))
}

/// Rows n; per model P@0.5, its standard error and the drop against `Original` (all views).
pub(crate) fn topn_table(
    records: &[ImageRecord],
    ns: &[usize],
    models: &[String],
    sources: &[String],
) -> Table {
    let mut t = Table::new(
        std::iter::once("n".to_string()).chain(models.iter().flat_map(|m| {
            [
                format!("{m} ({}) P@0.5", role(m, sources)),
                format!("{m} s.e."),
                format!("{m} drop"),
            ]
        })),
    );
    for &n in ns {
        let mut row = vec![n.to_string()];
        for m in models {
            let f = at(records, &run_name(n), m);
            let orig = at(records, "Original", m);
            row.extend([
                format!("{:.3}", f.p_at_05),
                format!("{:.3}", f.p_stderr),
                format!("{:.3}", orig.p_at_05 - f.p_at_05),
            ]);
        }
        t.row(row);
    }
    t
}

/// P@0.5 ± s.e. against n, one curve per model, with the model's P@0.5 on the original texture
/// as a thin flat line of the same colour.
pub(crate) fn topn_plot(
    records: &[ImageRecord],
    ns: &[usize],
    models: &[String],
    sources: &[String],
) -> Result<image::RgbImage> {
    let lo = ns.iter().copied().min().unwrap_or(0) as f64;
    let hi = ns.iter().copied().max().unwrap_or(1) as f64;
    let mut series = vec![];
    for (k, m) in models.iter().enumerate() {
        let c = plot::PALETTE[k % plot::PALETTE.len()];
        let pts: Vec<(f64, Figures)> = ns
            .iter()
            .map(|&n| (n as f64, at(records, &run_name(n), m)))
            .collect();
        series.push(
            Series::new(
                &format!("{m} ({})", role(m, sources)),
                pts.iter().map(|(n, f)| (*n, f.p_at_05)).collect(),
            )
            .err(pts.iter().map(|(_, f)| f.p_stderr).collect())
            .color(c),
        );
        let orig = at(records, "Original", m).p_at_05;
        series.push(
            Series::new(
                &format!("{m}: original texture"),
                vec![(lo, orig), (hi, orig)],
            )
            .color(c)
            .line(1),
        );
    }
    plot::xy(
        &Plot::new(
            "P@0.5 against the number of fixed proposals n",
            "n (fixed proposals per image)",
            "P@0.5",
        )
        .y_range(-0.02, 1.02),
        &series,
    )
}

/// One row per texture (`(name, training seconds)`, `None` for textures not trained); per model
/// P@0.5 and targeted success in each viewpoint set, over both brightness levels.
pub(crate) fn methods_table(
    records: &[ImageRecord],
    rows: &[(String, Option<f64>)],
    models: &[String],
    sources: &[String],
    sets: &[ViewpointSet],
) -> Table {
    let tag = |s: &ViewpointSet| match s {
        ViewpointSet::Free => "FV",
        ViewpointSet::Restricted => "RV",
    };
    let mut head = vec!["texture".to_string(), "train (s)".to_string()];
    for m in models {
        for what in ["P@0.5", "target"] {
            for s in sets {
                head.push(format!("{m} ({}) {what} {}", role(m, sources), tag(s)));
            }
        }
    }
    let mut t = Table::new(head);
    for (name, secs) in rows {
        let mut row = vec![name.clone(), secs.map_or("—".into(), |s| format!("{s:.0}"))];
        for m in models {
            let f: Vec<Figures> = sets
                .iter()
                .map(|&s| figures(records, sel(name, m, Some(s), None)))
                .collect();
            row.extend(f.iter().map(|f| format!("{:.3}", f.p_at_05)));
            row.extend(f.iter().map(|f| format!("{:.3}", f.targeted_success)));
        }
        t.row(row);
    }
    t
}
