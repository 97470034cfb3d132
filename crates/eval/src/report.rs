//! The evaluation's report: Markdown and CSV tables shaped like the paper's, a JSON file with
//! every figure, plots (P@0.5 against distance ratio and elevation with error bars, polar against
//! azimuth) and one self-contained HTML page with example views (boxes drawn). Returns named
//! files; the caller writes them (atomically).

use super::run::{level_name, set_name, Example, ImageRecord, ViewPlan};
use super::summary::{self, breakdown, Factor, Metric, Select};
use super::Protocol;
use anyhow::Result;
use cac_core::report::{draw, plot, Html, Plot, Series, Table};
use cac_render::RenderSettings;
use serde::Serialize;

/// What was evaluated and how (stated in every report).
#[derive(Clone, Debug, Serialize)]
pub struct EvalInfo {
    pub object: String,
    pub protocol: Protocol,
    pub plan: ViewPlan,
    pub render: RenderSettings,
    /// How the views are lit when not by the sun and ambient (the HDRI protocol), else empty.
    pub light: String,
    /// The printer every texture was judged as printed by (`; as printed by ...`), else empty.
    pub printed: String,
    /// Row names, in order; `reference` is the one drops are taken against.
    pub textures: Vec<String>,
    pub reference: String,
    pub models: Vec<String>,
    /// Views without a visible object, per texture (excluded).
    pub skipped: Vec<usize>,
    /// Textures whose records came from the cache of an earlier run.
    pub reused: Vec<String>,
    pub seconds: f64,
}

fn class_names(p: &Protocol, ids: &[usize]) -> String {
    if ids.is_empty() {
        return "none".into();
    }
    ids.iter()
        .map(|&c| p.label(c))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The protocol statement.
pub(crate) fn protocol_text(i: &EvalInfo) -> String {
    let p = &i.protocol;
    let sets: Vec<&str> = i.plan.sets.iter().map(|&s| set_name(s)).collect();
    format!(
        "object: {obj}; textures: {tex}{printed}; models: {models}\n\
         views: {sets} (FV: free viewpoint; RV: side views, restricted viewpoint alpha = 120 deg), \
         bright L_b and dark L_d, {n} views per brightness level and set ({per} images per texture), \
         seed {seed}, each at a random condition of the virtual scene (distance, elevation, sun, sky or \
         colour background, ground, photometric and print error){light}\n\
         render: {w}x{h}, {spp} samples per pixel, vertical FOV {fov} deg, atlas {atlas}^2\n\
         hit: a true-class ({tc}) detection with IoU >= {iou} against the ground-truth box (object mask) \
         and confidence >= {conf}; P@0.5 = hits / images\n\
         Drop = P@0.5({reference}) - P@0.5(texture); {targeted}; mean best true-class confidence \
         over detections with IoU >= {iou}\n\
         error bars: binomial standard error sqrt(p (1 - p) / n); breakdowns pool all sets and levels",
        obj = i.object,
        light = i.light,
        printed = i.printed,
        tex = i.textures.join(", "),
        models = i.models.join(", "),
        sets = sets.join(" and "),
        n = i.plan.views_per_level,
        per = i.plan.views_per_level * i.plan.sets.len() * i.plan.levels.len(),
        seed = i.plan.seed,
        w = i.render.width,
        h = i.render.height,
        spp = i.render.samples,
        fov = i.render.vfov_deg,
        atlas = i.render.atlas_res,
        tc = class_names(p, &p.true_classes),
        iou = p.iou,
        conf = p.confidence,
        reference = i.reference,
        targeted = match p.target {
            Some(t) => format!(
                "targeted success: a {} detection with IoU >= {} and confidence >= {}",
                p.label(t), p.iou, p.confidence
            ),
            None => "targeted success: not measured (no target class given)".into(),
        },
    )
}

/// The paper-shaped tables, by file stem and title.
pub fn tables(i: &EvalInfo, records: &[ImageRecord]) -> Vec<(String, String, Table)> {
    let (t, m, r) = (&i.textures, &i.models, i.reference.as_str());
    let mut out = vec![];
    for &s in &i.plan.sets {
        out.push((
            format!("p05_{}", set_name(s).to_lowercase()),
            format!("P@0.5, {} (drop against {r})", set_name(s)),
            summary::level_table(records, t, m, s, r, Metric::P05),
        ));
    }
    if i.plan.sets.len() == 2 {
        out.push((
            "p05_rv_fv".into(),
            format!("P@0.5, RV against FV, both levels (drop against {r})"),
            summary::set_table(records, t, m, r, Metric::P05),
        ));
    }
    if i.protocol.target.is_some() {
        for &s in &i.plan.sets {
            out.push((
                format!("targeted_{}", set_name(s).to_lowercase()),
                format!("Targeted success, {}", set_name(s)),
                summary::level_table(records, t, m, s, r, Metric::TargetedSuccess),
            ));
        }
    }
    for &s in &i.plan.sets {
        out.push((
            format!("conf_{}", set_name(s).to_lowercase()),
            format!("Mean best true-class confidence, {}", set_name(s)),
            summary::level_table(records, t, m, s, r, Metric::MeanBestTrueConf),
        ));
    }
    out
}

fn records_table(records: &[ImageRecord]) -> Table {
    let mut t = Table::new([
        "texture",
        "model",
        "set",
        "level",
        "view",
        "azimuth_deg",
        "elevation_deg",
        "distance_ratio",
        "gt_x1",
        "gt_y1",
        "gt_x2",
        "gt_y2",
        "hit",
        "targeted",
        "best_true_conf",
    ]);
    for r in records {
        let mut row = vec![
            r.texture.clone(),
            r.model.clone(),
            set_name(r.set).into(),
            level_name(r.brightness).into(),
            r.view.to_string(),
            format!("{:.2}", r.azimuth_deg),
            format!("{:.2}", r.elevation_deg),
            format!("{:.3}", r.distance_ratio),
        ];
        row.extend(r.gt.iter().map(|v| format!("{v:.1}")));
        row.extend([
            (r.score.hit as u8).to_string(),
            (r.score.targeted as u8).to_string(),
            format!("{:.4}", r.score.best_true_conf),
        ]);
        t.row(row);
    }
    t
}

/// Per model: P@0.5 ± s.e. against a factor, one series per texture.
pub(crate) fn factor_plot(
    i: &EvalInfo,
    records: &[ImageRecord],
    model: &str,
    f: Factor,
) -> Result<image::RgbImage> {
    let series: Vec<Series> = i
        .textures
        .iter()
        .map(|t| {
            let sel = Select {
                texture: Some(t),
                model: Some(model),
                ..Default::default()
            };
            let bins = breakdown(records.iter().filter(|r| sel.matches(r)), f);
            let pts = bins.iter().map(|b| (b.mid(), b.figures.p_at_05)).collect();
            Series::new(t, pts).err(bins.iter().map(|b| b.figures.p_stderr).collect())
        })
        .collect();
    if f == Factor::Azimuth {
        let closed: Vec<Series> = series
            .into_iter()
            .map(|mut s| {
                s.err.clear();
                if s.points.len() > 2 && s.points.len() == 12 {
                    s.points.push(s.points[0]);
                }
                s
            })
            .collect();
        return plot::polar(
            &Plot::new(
                &format!("{model}: P@0.5 against azimuth"),
                "azimuth (deg)",
                "P@0.5 (radius)",
            )
            .size(480, 480)
            .y_range(0.0, 1.0),
            &closed,
        );
    }
    let x = match f {
        Factor::DistanceRatio => "distance ratio (object lengths)",
        _ => "elevation (deg)",
    };
    plot::xy(
        &Plot::new(
            &format!("{model}: P@0.5 ± s.e. against {}", f.name()),
            x,
            "P@0.5",
        )
        .y_range(-0.02, 1.02),
        &series,
    )
}

/// An example view, scaled to at most `max_side` pixels, with the ground truth (white) and one
/// model's detections (label and confidence) drawn.
pub(crate) fn example_image(e: &Example, model: usize, max_side: u32) -> image::RgbImage {
    let (w, h) = e.image.dimensions();
    let k = (max_side as f32 / w.max(h) as f32).min(1.0);
    let mut img = if k < 1.0 {
        image::imageops::resize(
            &e.image,
            ((w as f32 * k).round() as u32).max(1),
            ((h as f32 * k).round() as u32).max(1),
            image::imageops::FilterType::Triangle,
        )
    } else {
        e.image.clone()
    };
    let s = |b: [f32; 4]| b.map(|v| v * k);
    draw::labelled_box(&mut img, s(e.gt), [255, 255, 255], 1, "");
    for d in &e.detections[model] {
        let label = format!("{} {:.2}", d.label, d.score);
        draw::labelled_box(
            &mut img,
            s(d.bbox),
            draw::class_colour(d.class_id),
            2,
            &label,
        );
    }
    img
}

#[derive(Serialize)]
struct Json<'a> {
    info: &'a EvalInfo,
    protocol_text: String,
    summaries: Vec<serde_json::Value>,
    breakdowns: Vec<serde_json::Value>,
    records: &'a [ImageRecord],
}

fn table_json(t: &Table) -> Vec<serde_json::Value> {
    t.rows
        .iter()
        .map(|r| {
            let m: serde_json::Map<String, serde_json::Value> = t
                .header
                .iter()
                .zip(r)
                .map(|(h, c)| {
                    let v = c
                        .parse::<f64>()
                        .map_or_else(|_| c.clone().into(), Into::into);
                    (h.clone(), v)
                })
                .collect();
            m.into()
        })
        .collect()
}

/// Every file of the report: `(file name, bytes)`. `examples` holds each texture's examples;
/// `extra` are further captioned figures for the HTML page (e.g. the top-n study's plot).
pub fn files(
    i: &EvalInfo,
    records: &[ImageRecord],
    examples: &[Vec<Example>],
    extra: &[(String, image::RgbImage)],
) -> Result<Vec<(String, Vec<u8>)>> {
    let mut out: Vec<(String, Vec<u8>)> = vec![];
    let proto = protocol_text(i);
    let tabs = tables(i, records);
    let summ = summary::summary_rows(records, &i.textures, &i.models, &i.plan.sets, &i.reference);
    let brk = summary::breakdown_rows(records, &i.textures, &i.models);

    for (stem, _, t) in &tabs {
        out.push((format!("{stem}.csv"), t.csv().into_bytes()));
    }
    out.push(("report.md".into(), markdown(i, &proto, &tabs).into_bytes()));
    out.push(("summary.csv".into(), summ.csv().into_bytes()));
    out.push(("breakdown.csv".into(), brk.csv().into_bytes()));
    out.push((
        "records.csv".into(),
        records_table(records).csv().into_bytes(),
    ));
    let json = Json {
        info: i,
        protocol_text: proto.clone(),
        summaries: table_json(&summ),
        breakdowns: table_json(&brk),
        records,
    };
    out.push(("results.json".into(), serde_json::to_vec_pretty(&json)?));

    let mut h = Html::new(&format!("Evaluation: {}", i.object));
    h.heading(2, "Protocol").pre(&proto);
    for (_, title, t) in &tabs {
        h.heading(2, title).table(t);
    }
    breakdown_plots(i, records, &mut h, &mut out)?;
    if !extra.is_empty() {
        h.heading(2, "Further figures");
        for (cap, img) in extra {
            h.image(img, cap)?;
        }
    }
    example_views(i, examples, &mut h)?;
    out.push(("report.html".into(), h.finish().into_bytes()));
    Ok(out)
}

/// `report.md`: the protocol, the tables and where the rest is.
fn markdown(i: &EvalInfo, proto: &str, tabs: &[(String, String, Table)]) -> String {
    let mut md = format!(
        "# Evaluation: {}\n\n## Protocol\n\n```\n{proto}\n```\n",
        i.object
    );
    for (_, title, t) in tabs {
        md += &format!("\n## {title}\n\n{}", t.markdown());
    }
    let reused = if i.reused.is_empty() {
        String::new()
    } else {
        format!(" ({} reused from the cache)", i.reused.join(", "))
    };
    md += &format!(
        "\nEvaluated in {:.0} s{reused}. Per-image records: records.csv; every figure: results.json.\n",
        i.seconds
    );
    md
}

/// The HTML page's breakdowns: per model, P@0.5 against distance ratio, elevation and azimuth;
/// each plot also goes into `out` as `plot_FACTOR_MODEL.png`.
fn breakdown_plots(
    i: &EvalInfo,
    records: &[ImageRecord],
    h: &mut Html,
    out: &mut Vec<(String, Vec<u8>)>,
) -> Result<()> {
    h.heading(2, "Breakdowns");
    for (k, model) in i.models.iter().enumerate() {
        let mut imgs = vec![];
        for f in [Factor::DistanceRatio, Factor::Elevation, Factor::Azimuth] {
            let img = factor_plot(i, records, model, f)?;
            let name = format!("plot_{}_{}.png", f.name(), model);
            let mut png = vec![];
            img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
            out.push((name, png));
            imgs.push(img);
        }
        let caps = [
            "against distance ratio",
            "against elevation",
            "against azimuth (polar)",
        ];
        let figs: Vec<(&image::RgbImage, &str)> = imgs.iter().zip(caps).collect();
        h.heading(3, &format!("{model} (model {})", k + 1))
            .figures(&figs, 0)?;
    }
    Ok(())
}

/// The HTML page's example views: per texture and model, each example with the ground truth
/// and the model's detections drawn.
fn example_views(i: &EvalInfo, examples: &[Vec<Example>], h: &mut Html) -> Result<()> {
    h.heading(2, "Example views");
    h.paragraph(
        "White: ground-truth box. Coloured: the model's detections (label and confidence).",
    );
    for (t, ex) in i.textures.iter().zip(examples) {
        for (k, model) in i.models.iter().enumerate() {
            let imgs: Vec<(image::RgbImage, String)> = ex
                .iter()
                .map(|e| {
                    (
                        example_image(e, k, 320),
                        format!(
                            "{} {} view {}",
                            set_name(e.set),
                            level_name(e.brightness),
                            e.view
                        ),
                    )
                })
                .collect();
            if imgs.is_empty() {
                continue;
            }
            let figs: Vec<(&image::RgbImage, &str)> =
                imgs.iter().map(|(a, b)| (a, b.as_str())).collect();
            h.heading(3, &format!("{t} — {model}")).photos(&figs, 240)?;
        }
    }
    Ok(())
}
