//! Checks the files of a scored capture session (`cac::physical::score::write`) by their content:
//! `scores.json` is the score, `frames.csv` has one row per manifest entry with its pose, box and
//! outcome, `by_ratio.csv` / `by_angle.csv` hold the P@0.5 recomputed here from the frames'
//! hits, `report.html` states the frame counts and holds the same two tables and both plots.

use cac::physical::manifest::Entry;
use cac::physical::score::{FrameScore, SessionScore};
use std::path::Path;

/// A CSV file without quoted cells: its header and its rows.
fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut rows = text.lines().map(|l| {
        assert!(!l.contains('"'), "{}: quoted cell in {l:?}", path.display());
        l.split(',').map(String::from).collect::<Vec<_>>()
    });
    let header = rows
        .next()
        .unwrap_or_else(|| panic!("{} is empty", path.display()));
    (header, rows.collect())
}

fn num(cell: &str) -> f64 {
    cell.parse()
        .unwrap_or_else(|_| panic!("{cell:?} is not a number"))
}

/// Asserts `cell` is `want` as printed with `decimals` decimals.
fn close(cell: &str, want: f64, decimals: i32, what: &str) {
    assert!(
        (num(cell) - want).abs() <= 0.5 * 10f64.powi(-decimals) + 1e-9,
        "{what}: {cell} in the report, {want} from the frames"
    );
}

/// Mean and sample standard deviation (0 with fewer than two values).
fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (m, var.sqrt())
}

/// Distinct values in order of first appearance.
fn distinct<T: PartialEq + Copy>(v: impl Iterator<Item = T>) -> Vec<T> {
    let mut out = Vec::new();
    for x in v {
        if !out.contains(&x) {
            out.push(x);
        }
    }
    out
}

/// Checks every file that `score::write(out, s, session)` wrote against `s` and the session's
/// manifest `entries`.
pub fn check(out: &Path, s: &SessionScore, entries: &[Entry], session: &str) {
    let json: SessionScore =
        serde_json::from_str(&std::fs::read_to_string(out.join("scores.json")).unwrap()).unwrap();
    assert_eq!(&json, s, "scores.json");
    assert_eq!(s.frames.len(), entries.len(), "a score per manifest entry");

    // frames.csv: one row per manifest entry, in order.
    let (header, rows) = csv(&out.join("frames.csv"));
    let mut want = [
        "frame", "ratio", "angle", "repeat", "gt_x1", "gt_y1", "gt_x2", "gt_y2",
    ]
    .map(String::from)
    .to_vec();
    for m in &s.models {
        want.extend([format!("{m}_hit"), format!("{m}_conf")]);
    }
    assert_eq!(header, want, "frames.csv header");
    assert_eq!(rows.len(), entries.len(), "frames.csv rows");
    for ((row, e), f) in rows.iter().zip(entries).zip(&s.frames) {
        assert_eq!(row.len(), want.len(), "{row:?}");
        assert_eq!(
            (&row[0], num(&row[1]), num(&row[2]), &row[3]),
            (&e.frame, e.ratio, e.angle, &e.repeat.to_string()),
            "frames.csv against the manifest"
        );
        assert_eq!(f.frame, e.frame);
        match f.gt {
            Some(b) => (0..4).for_each(|i| close(&row[4 + i], b[i].into(), 2, &e.frame)),
            None => assert!(row[4..8].iter().all(String::is_empty), "{row:?}"),
        }
        for (m, (hit, conf)) in f.hit.iter().zip(&f.best_conf).enumerate() {
            assert_eq!(row[8 + 2 * m], (*hit as u8).to_string(), "{}", e.frame);
            close(&row[9 + 2 * m], (*conf).into(), 4, &e.frame);
        }
    }

    // P@0.5 per ratio (mean and std over repeats) and per angle, from the scored frames' hits.
    let scored: Vec<_> = s.frames.iter().filter(|f| f.gt.is_some()).collect();
    let p = |m: usize, keep: &dyn Fn(&FrameScore) -> bool| {
        let fs: Vec<_> = scored.iter().filter(|f| keep(f)).collect();
        let hits = fs.iter().filter(|f| f.hit[m]).count();
        (!fs.is_empty()).then(|| (hits as f64 / fs.len() as f64, fs.len()))
    };
    let ratios = distinct(entries.iter().map(|e| e.ratio));
    let angles = distinct(entries.iter().map(|e| e.angle));
    let repeats = distinct(entries.iter().map(|e| e.repeat));
    let (header, by_ratio) = csv(&out.join("by_ratio.csv"));
    assert_eq!(
        header,
        [
            "model",
            "distance ratio",
            "P@0.5 mean",
            "P@0.5 std",
            "repeats"
        ]
    );
    assert_eq!(
        by_ratio.len(),
        s.models.len() * ratios.len(),
        "{by_ratio:?}"
    );
    let (header, by_angle) = csv(&out.join("by_angle.csv"));
    assert_eq!(header, ["model", "angle", "P@0.5", "frames"]);
    let mut angle_rows = 0;
    for (m, model) in s.models.iter().enumerate() {
        for &r in &ratios {
            let per_repeat: Vec<f64> = repeats
                .iter()
                .filter_map(|&k| p(m, &|f: &FrameScore| f.ratio == r && f.repeat == k).map(|x| x.0))
                .collect();
            let row = by_ratio
                .iter()
                .find(|row| &row[0] == model && num(&row[1]) == r)
                .unwrap_or_else(|| panic!("by_ratio.csv has no row for {model} at {r}"));
            let (mean, std) = mean_std(&per_repeat);
            close(
                &row[2],
                mean,
                3,
                &format!("{model} P@0.5 mean at ratio {r}"),
            );
            close(&row[3], std, 3, &format!("{model} P@0.5 std at ratio {r}"));
            assert_eq!(row[4], per_repeat.len().to_string(), "repeats at ratio {r}");
        }
        for &a in &angles {
            let Some((pa, n)) = p(m, &|f: &FrameScore| f.angle == a) else {
                continue;
            };
            angle_rows += 1;
            let row = by_angle
                .iter()
                .find(|row| &row[0] == model && num(&row[1]) == a)
                .unwrap_or_else(|| panic!("by_angle.csv has no row for {model} at {a}°"));
            close(&row[2], pa, 3, &format!("{model} P@0.5 at {a}°"));
            assert_eq!(row[3], n.to_string(), "{model}: frames at {a}°");
        }
    }
    assert_eq!(by_angle.len(), angle_rows, "{by_angle:?}");

    // report.html: the counts, the two tables as in the CSV files, both plots.
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let skipped = s.frames.len() - scored.len();
    let counts = format!(
        "Session {session}: {} frames, {skipped} with the object out of view",
        s.frames.len()
    );
    assert!(html.contains(&counts), "report.html lacks {counts:?}");
    let cells: Vec<Vec<String>> = html
        .lines()
        .filter_map(|l| l.strip_prefix("<tr><td>")?.strip_suffix("</td></tr>"))
        .map(|l| l.split("</td><td>").map(String::from).collect())
        .collect();
    let tables: Vec<Vec<String>> = by_ratio.into_iter().chain(by_angle).collect();
    assert_eq!(cells, tables, "report.html's tables against the CSV files");
    assert_eq!(html.matches("<img src=\"data:image/png;base64,").count(), 2);
    for (png, square) in [("p_vs_ratio.png", false), ("polar.png", true)] {
        let img = image::open(out.join(png)).unwrap_or_else(|e| panic!("{png}: {e}"));
        assert!(img.width() > 100 && img.height() > 100, "{png}");
        assert!(!square || img.width() == img.height(), "{png}");
    }
}
