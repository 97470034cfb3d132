//! Renderer agreement (`cac bench agreement`, and the end of `cac bench realism` with two
//! renderers): the same views scored in cac's image and in a second renderer's (Cycles), pooled
//! per mesh, texture and viewpoint set over the lights and over any number of runs (one per
//! seed, from their per-view CSV files). For each detector's P@0.5 and targeted success: the rate
//! in both renderers, the gap, and the views on which they disagree — in cac's image only (`b`)
//! and in the other's only (`c`), with McNemar's `z = (b − c) / √(b + c)`, which says whether a
//! gap is the renderers or the sample (two rates over the same views differ only through the
//! views that disagree).

use anyhow::{bail, Context, Result};
use cac_core::report::Table;
use serde::Deserialize;
use std::collections::BTreeMap;

/// The columns read of a per-view row; the header must have every one of
/// [`super::realism::PER_VIEW_COLUMNS`].
#[derive(Debug, Deserialize)]
struct ViewRow {
    mesh: String,
    renderer: String,
    texture: String,
    set: String,
    light: String,
    view: usize,
    nanodet_hit: u8,
    nanodet_targeted: u8,
    centernet_hit: u8,
    centernet_targeted: u8,
}

/// The four outcomes compared, in the per-view CSV's column order.
pub const FIGURES: [&str; 4] = [
    "nanodet P@0.5",
    "nanodet targeted",
    "centernet P@0.5",
    "centernet targeted",
];

/// One view's four outcomes (see [`FIGURES`]) in one renderer.
type Outcomes = [bool; 4];

/// A view: the run it came from, mesh, texture, set, light, index.
type ViewKey = (usize, String, String, String, String, usize);

/// Per-view outcomes of one or more runs, by renderer.
#[derive(Default)]
pub struct Views {
    by_renderer: BTreeMap<String, BTreeMap<ViewKey, Outcomes>>,
    runs: usize,
}

impl Views {
    /// Adds one run's per-view CSV; `source` names it in errors. A file without the per-view
    /// columns, with an outcome other than 0 or 1, or listing a view twice for one renderer is
    /// refused, and then nothing of it is added.
    pub fn add_csv(&mut self, text: &str, source: &str) -> Result<()> {
        if text.trim().is_empty() {
            bail!("{source}: empty file: no per-view rows");
        }
        let mut rd = csv::Reader::from_reader(text.as_bytes());
        let head = rd
            .headers()
            .with_context(|| format!("{source}: cannot read the header line"))?
            .clone();
        for col in super::realism::PER_VIEW_COLUMNS {
            if !head.iter().any(|h| h == col) {
                bail!("{source}: not a per-view table of `cac bench realism --per-view`: no column '{col}'");
            }
        }
        let run = self.runs;
        let mut added: BTreeMap<String, BTreeMap<ViewKey, Outcomes>> = BTreeMap::new();
        for (i, rec) in rd.deserialize::<ViewRow>().enumerate() {
            // Line 1 is the header.
            let line = i + 2;
            let r = rec.with_context(|| format!("{source}: line {line}: not a per-view row"))?;
            let flags = [
                r.nanodet_hit,
                r.nanodet_targeted,
                r.centernet_hit,
                r.centernet_targeted,
            ];
            if let Some(bad) = flags.iter().find(|&&f| f > 1) {
                bail!("{source}: line {line}: an outcome must be 0 or 1, got {bad}");
            }
            let key = (run, r.mesh, r.texture, r.set, r.light, r.view);
            let seen = added.entry(r.renderer.clone()).or_default();
            if seen.insert(key, flags.map(|f| f == 1)).is_some() {
                bail!(
                    "{source}: line {line}: view {} of renderer {} is listed twice (two textures with the same file name in one run? rename one)",
                    r.view,
                    r.renderer
                );
            }
        }
        if added.is_empty() {
            bail!("{source}: no per-view rows");
        }
        for (renderer, views) in added {
            self.by_renderer.entry(renderer).or_default().extend(views);
        }
        self.runs += 1;
        Ok(())
    }

    /// The agreement of cac's renderer with every other one in these runs, one row per mesh,
    /// texture, set, other renderer and figure; views seen by only one renderer are left out
    /// (counted in [`Agreement::unpaired`]).
    pub fn agreement(&self) -> Result<Agreement> {
        let Some(cac) = self.by_renderer.get("cac") else {
            bail!("no view rendered by cac's renderer: nothing to compare against");
        };
        let mut rows = Vec::new();
        let mut unpaired = 0;
        for (name, other) in self.by_renderer.iter().filter(|(n, _)| *n != "cac") {
            // (mesh, texture, set) → per figure [views, in cac, in other, cac only, other only].
            let mut groups: BTreeMap<(String, String, String), [[usize; 5]; 4]> = BTreeMap::new();
            for (k, o) in other {
                let Some(a) = cac.get(k) else {
                    unpaired += 1;
                    continue;
                };
                let g = groups
                    .entry((k.1.clone(), k.2.clone(), k.3.clone()))
                    .or_default();
                for f in 0..4 {
                    let (x, y) = (a[f], o[f]);
                    let c = &mut g[f];
                    c[0] += 1;
                    c[1] += x as usize;
                    c[2] += y as usize;
                    c[3] += (x && !y) as usize;
                    c[4] += (y && !x) as usize;
                }
            }
            unpaired += cac.keys().filter(|k| !other.contains_key(*k)).count();
            for ((mesh, texture, set), g) in groups {
                for (f, c) in g.iter().enumerate() {
                    rows.push(Pair {
                        mesh: mesh.clone(),
                        texture: texture.clone(),
                        set: set.clone(),
                        renderer: name.clone(),
                        figure: FIGURES[f],
                        views: c[0],
                        in_cac: c[1],
                        in_other: c[2],
                        cac_only: c[3],
                        other_only: c[4],
                    });
                }
            }
        }
        if rows.is_empty() {
            bail!("no view was scored by both cac's renderer and another one (same run, mesh, texture, set, light and view)");
        }
        Ok(Agreement {
            rows,
            unpaired,
            runs: self.runs,
        })
    }
}

/// One figure of one mesh, texture and set, in cac's renderer and another.
#[derive(Clone, Debug, PartialEq)]
pub struct Pair {
    pub mesh: String,
    pub texture: String,
    pub set: String,
    /// The other renderer's label.
    pub renderer: String,
    pub figure: &'static str,
    pub views: usize,
    /// Views with the outcome in cac's image, in the other's.
    pub in_cac: usize,
    pub in_other: usize,
    /// Views with it in cac's image only (McNemar's `b`), in the other's only (`c`).
    pub cac_only: usize,
    pub other_only: usize,
}

impl Pair {
    /// The rate in cac's image.
    pub fn cac_rate(&self) -> f64 {
        self.in_cac as f64 / self.views as f64
    }

    /// The rate in the other renderer's image.
    pub fn other_rate(&self) -> f64 {
        self.in_other as f64 / self.views as f64
    }

    /// The other renderer's rate minus cac's (exactly `(c − b) / views`).
    pub fn gap(&self) -> f64 {
        (self.in_other as f64 - self.in_cac as f64) / self.views as f64
    }

    /// Whether the gap is within `tolerance` (a rate difference; a hair of slack for the
    /// rounding of `gap`).
    pub fn within(&self, tolerance: f64) -> bool {
        self.gap().abs() <= tolerance + 1e-12
    }

    /// McNemar's statistic `(b − c) / √(b + c)` (0 when no view disagrees): beyond about ±2 the
    /// gap is unlikely to be the sample alone.
    pub fn mcnemar_z(&self) -> f64 {
        let (b, c) = (self.cac_only as f64, self.other_only as f64);
        if b + c == 0.0 {
            0.0
        } else {
            (b - c) / (b + c).sqrt()
        }
    }
}

/// The comparison's rows and how many views had no partner.
pub struct Agreement {
    pub rows: Vec<Pair>,
    pub unpaired: usize,
    pub runs: usize,
}

impl Agreement {
    /// Whether every gap is within `tolerance`.
    pub fn all_within(&self, tolerance: f64) -> bool {
        self.rows.iter().all(|p| p.within(tolerance))
    }

    /// The rows as a table (also its CSV); `within` marks each gap against `tolerance`.
    pub fn table(&self, tolerance: f64) -> Table {
        let mut t = Table::new([
            "mesh",
            "texture",
            "set",
            "renderer",
            "figure",
            "views",
            "cac",
            "other",
            "gap",
            "cac_only",
            "other_only",
            "mcnemar_z",
            "within",
        ]);
        for p in &self.rows {
            t.row([
                p.mesh.clone(),
                p.texture.clone(),
                p.set.clone(),
                p.renderer.clone(),
                p.figure.to_string(),
                p.views.to_string(),
                format!("{:.3}", p.cac_rate()),
                format!("{:.3}", p.other_rate()),
                format!("{:+.3}", p.gap()),
                p.cac_only.to_string(),
                p.other_only.to_string(),
                format!("{:+.2}", p.mcnemar_z()),
                if p.within(tolerance) { "yes" } else { "no" }.to_string(),
            ]);
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str = "mesh,renderer,texture,set,light,view,azimuth,elevation,distance_ratio,nanodet_hit,nanodet_conf,nanodet_targeted,centernet_hit,centernet_conf,centernet_targeted\n";

    fn row(renderer: &str, light: &str, view: usize, f: [u8; 4]) -> String {
        format!(
            "pickup,{renderer},atlas,free,{light},{view},10.0,5.0,2.00,{},0.500,{},{},0.400,{}\n",
            f[0], f[1], f[2], f[3]
        )
    }

    #[test]
    fn counts_disagreeing_views_and_pools_runs() {
        // Run 1: view 0 targeted in cac only, view 1 in both, view 2 in Cycles only, view 3 in
        // neither; run 2 repeats the view indices (another seed) with view 0 in cac only.
        let mut r1 = HEAD.to_string();
        let mut r2 = HEAD.to_string();
        for (v, c, b) in [(0, 1, 0), (1, 1, 1), (2, 0, 1), (3, 0, 0)] {
            r1 += &row("cac", "hdri:night", v, [0, c, 1, 0]);
            r1 += &row("blender", "hdri:night", v, [0, b, 1, 0]);
        }
        r2 += &row("cac", "bright", 0, [1, 1, 0, 0]);
        r2 += &row("blender", "bright", 0, [0, 0, 0, 0]);
        let mut v = Views::default();
        v.add_csv(&r1, "r1.csv").unwrap();
        v.add_csv(&r2, "r2.csv").unwrap();
        let a = v.agreement().unwrap();
        assert_eq!((a.runs, a.unpaired), (2, 0));
        assert_eq!(a.rows.len(), 4);
        let t = &a.rows[1];
        assert_eq!(
            (t.figure, t.renderer.as_str(), t.views),
            ("nanodet targeted", "blender", 5)
        );
        assert_eq!(
            (t.in_cac, t.in_other, t.cac_only, t.other_only),
            (3, 2, 2, 1)
        );
        assert!((t.gap() + 0.2).abs() < 1e-12);
        assert!((t.mcnemar_z() - 1.0 / 3f64.sqrt()).abs() < 1e-12);
        let p = &a.rows[0];
        assert_eq!(
            (p.in_cac, p.in_other, p.cac_only, p.other_only),
            (1, 0, 1, 0)
        );
        // CenterNet P@0.5 agrees on every view: gap 0, z 0.
        let c = &a.rows[2];
        assert_eq!(
            (c.in_cac, c.in_other, c.gap(), c.mcnemar_z()),
            (4, 4, 0.0, 0.0)
        );
        assert!(!a.all_within(0.1));
        assert!(a.all_within(0.2));
        let csv = a.table(0.05).csv();
        assert!(
            csv.contains(
                "pickup,atlas,free,blender,nanodet targeted,5,0.600,0.400,-0.200,2,1,+0.58,no"
            ),
            "{csv}"
        );
    }

    #[test]
    fn views_of_one_renderer_only_are_counted_apart() {
        let mut r = HEAD.to_string();
        r += &row("cac", "bright", 0, [1, 0, 0, 0]);
        r += &row("blender", "bright", 0, [1, 0, 0, 0]);
        r += &row("cac", "bright", 1, [1, 0, 0, 0]);
        let mut v = Views::default();
        v.add_csv(&r, "r.csv").unwrap();
        let a = v.agreement().unwrap();
        assert_eq!((a.unpaired, a.rows[0].views), (1, 1));
    }

    #[test]
    fn bad_input_is_refused_naming_the_file_and_line() {
        let mut v = Views::default();
        let e = v
            .add_csv("mesh,renderer\npickup,cac\n", "a.csv")
            .unwrap_err();
        let want =
            "a.csv: not a per-view table of `cac bench realism --per-view`: no column 'texture'";
        assert!(format!("{e:#}").contains(want), "{e:#}");
        for empty in ["", HEAD] {
            let e = v.add_csv(empty, "empty.csv").unwrap_err();
            let e = format!("{e:#}");
            assert!(
                e.starts_with("empty.csv: ") && e.ends_with("no per-view rows"),
                "{e}"
            );
        }
        // A row that does not parse, after a good one: refused naming its line, nothing added.
        let half = format!(
            "{HEAD}{}pickup,cac,atlas,free,bright,x\n",
            row("cac", "bright", 0, [1, 0, 0, 0])
        );
        let e = v.add_csv(&half, "f.csv").unwrap_err();
        assert!(
            format!("{e:#}").contains("f.csv: line 3: not a per-view row"),
            "{e:#}"
        );
        assert_eq!((v.runs, v.by_renderer.len()), (0, 0));
        let twice = format!(
            "{HEAD}{}{}",
            row("cac", "bright", 0, [1, 0, 0, 0]),
            row("cac", "bright", 0, [1, 0, 0, 0])
        );
        let e = Views::default().add_csv(&twice, "b.csv").unwrap_err();
        assert!(format!("{e:#}").contains("b.csv: line 3: view 0 of renderer cac is listed twice"));
        let e = Views::default()
            .add_csv(
                &format!("{HEAD}{}", row("cac", "bright", 0, [2, 0, 0, 0])),
                "c.csv",
            )
            .unwrap_err();
        assert!(format!("{e:#}").contains("c.csv: line 2: an outcome must be 0 or 1"));
        // Only one renderer: nothing to compare.
        let mut v = Views::default();
        v.add_csv(
            &format!("{HEAD}{}", row("cac", "bright", 0, [1, 0, 0, 0])),
            "d.csv",
        )
        .unwrap();
        assert!(v.agreement().is_err());
        let mut v = Views::default();
        v.add_csv(
            &format!("{HEAD}{}", row("blender", "bright", 0, [1, 0, 0, 0])),
            "e.csv",
        )
        .unwrap();
        assert!(format!("{:#}", v.agreement().err().unwrap()).contains("no view rendered by cac"));
    }
}
