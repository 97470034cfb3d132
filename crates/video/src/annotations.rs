//! Ground truth from annotation files: a CSV of boxes per frame or per time range, or COCO JSON.
//!
//! CSV (header required, columns in any order, `#` comments): either `frame,x1,y1,x2,y2` (0-based
//! frame index in presentation order) or `t_start,t_end,x1,y1,x2,y2` (seconds, the range is
//! `t_start <= t < t_end`), each with an optional `segment` column naming the frame's segment.
//! Boxes are pixels of the displayed (rotated) frame, `x2, y2` exclusive.
//!
//! COCO JSON: `images[]` (`id`, `file_name`, optional `width`/`height`/`frame_index`) and
//! `annotations[]` (`image_id`, `bbox: [x, y, w, h]`). An image's frame is its `frame_index`, or the
//! trailing number of its file name (`frame_000123.png` → 123, 0-based). With several boxes in one
//! image the largest is the object under test. Frames without a box are not scored.

use anyhow::{bail, Context, Result};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

/// The ground truth of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct GtBox {
    /// `x1, y1, x2, y2` in display pixels.
    pub bbox: [f32; 4],
    /// The segment the frame belongs to, when the source names one.
    pub segment: Option<String>,
    /// The turntable angle (degrees, unwrapped), when the source knows it.
    pub angle_deg: Option<f64>,
}

/// Where the ground-truth box of a frame comes from.
pub trait GroundTruth {
    /// The box of frame `index` at `pts` seconds; `None` when the frame is not annotated.
    fn at(&self, index: u64, pts: f64) -> Result<Option<GtBox>>;
    /// One line for reports.
    fn describe(&self) -> String;
    /// The frame size the annotations were made on, when the file says.
    fn frame_size(&self) -> Option<(u32, u32)> {
        None
    }
}

/// Boxes read from a CSV or COCO file.
#[derive(Clone, Debug, Default)]
pub struct Annotations {
    by_frame: BTreeMap<u64, GtBox>,
    /// Sorted, non-overlapping `[t_start, t_end)` ranges.
    ranges: Vec<(f64, f64, GtBox)>,
    size: Option<(u32, u32)>,
    source: String,
}

impl Annotations {
    /// Reads a `.csv` or `.json` (COCO) file.
    pub fn load(path: &Path) -> Result<Annotations> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read annotations {}", path.display()))?;
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let mut a = match ext.as_deref() {
            Some("json") => Self::from_coco(&text),
            Some("csv") | Some("txt") => Self::from_csv(&text),
            _ => bail!("expected a .csv or COCO .json file"),
        }
        .with_context(|| format!("annotations {}", path.display()))?;
        a.source = path.display().to_string();
        Ok(a)
    }

    /// Parses the CSV form.
    pub fn from_csv(text: &str) -> Result<Annotations> {
        let table = super::csv::Table::parse(text)?;
        let header = table.header;
        let col = |n: &str| table.col(&[n]);
        let need =
            |n: &str| col(n).with_context(|| format!("header {header:?} has no {n:?} column"));
        let [x1, y1, x2, y2] = [need("x1")?, need("y1")?, need("x2")?, need("y2")?];
        let seg = col("segment");
        let key = match (col("frame"), col("t_start"), col("t_end")) {
            (Some(f), None, None) => Ok(f),
            (None, Some(a), Some(b)) => Err((a, b)),
            _ => bail!("header {header:?} needs either a frame column or t_start and t_end"),
        };
        let mut out = Annotations::default();
        for row in table.rows() {
            let ln = row.line;
            let get = |i: usize| row.num(i);
            let bbox = [get(x1)?, get(y1)?, get(x2)?, get(y2)?].map(|v| v as f32);
            check_box(&bbox).with_context(|| format!("line {ln}"))?;
            let segment = seg
                .and_then(|i| row.field(i))
                .filter(|s| !s.is_empty())
                .map(|s| s.to_string());
            let gt = GtBox {
                bbox,
                segment,
                angle_deg: None,
            };
            match key {
                Ok(fc) => {
                    let v = get(fc)?;
                    if v < 0.0 || v.fract() != 0.0 {
                        bail!("line {ln}: frame {v} is not a frame index (0, 1, 2, ...)");
                    }
                    if out.by_frame.insert(v as u64, gt).is_some() {
                        bail!("line {ln}: frame {v} is annotated twice");
                    }
                }
                Err((a, b)) => {
                    let (t0, t1) = (get(a)?, get(b)?);
                    if t1 <= t0 {
                        bail!("line {ln}: t_end {t1} is not after t_start {t0}");
                    }
                    out.ranges.push((t0, t1, gt));
                }
            }
        }
        out.ranges.sort_by(|a, b| a.0.total_cmp(&b.0));
        for w in out.ranges.windows(2) {
            if w[1].0 < w[0].1 {
                bail!(
                    "time ranges [{}, {}) and [{}, {}) overlap",
                    w[0].0,
                    w[0].1,
                    w[1].0,
                    w[1].1
                );
            }
        }
        if out.by_frame.is_empty() && out.ranges.is_empty() {
            bail!("no annotations after the header");
        }
        Ok(out)
    }

    /// Parses the COCO form.
    pub(crate) fn from_coco(text: &str) -> Result<Annotations> {
        #[derive(Deserialize)]
        struct Coco {
            images: Vec<Image>,
            annotations: Vec<Ann>,
        }
        #[derive(Deserialize)]
        struct Image {
            id: u64,
            #[serde(default)]
            file_name: String,
            width: Option<u32>,
            height: Option<u32>,
            frame_index: Option<u64>,
        }
        #[derive(Deserialize)]
        struct Ann {
            image_id: u64,
            bbox: [f64; 4],
        }
        let c: Coco = serde_json::from_str(text).context("not a COCO JSON file")?;
        let mut frame_of = BTreeMap::new();
        let mut out = Annotations::default();
        for im in &c.images {
            let f = match im.frame_index {
                Some(f) => f,
                None => trailing_number(&im.file_name).with_context(|| {
                    format!(
                        "image {}: no frame_index and no frame number in file name {:?}",
                        im.id, im.file_name
                    )
                })?,
            };
            frame_of.insert(im.id, f);
            if let (Some(w), Some(h)) = (im.width, im.height) {
                match out.size {
                    Some(s) if s != (w, h) => bail!("images differ in size: {s:?} and {w}x{h}"),
                    _ => out.size = Some((w, h)),
                }
            }
        }
        for (k, a) in c.annotations.iter().enumerate() {
            let f = *frame_of.get(&a.image_id).with_context(|| {
                format!("annotation {k}: image_id {} is not in images", a.image_id)
            })?;
            let [x, y, w, h] = a.bbox;
            let bbox = [x, y, x + w, y + h].map(|v| v as f32);
            check_box(&bbox).with_context(|| format!("annotation {k}"))?;
            let area = |b: &[f32; 4]| (b[2] - b[0]) * (b[3] - b[1]);
            let keep = out
                .by_frame
                .get(&f)
                .is_none_or(|old| area(&bbox) > area(&old.bbox));
            if keep {
                out.by_frame.insert(
                    f,
                    GtBox {
                        bbox,
                        segment: None,
                        angle_deg: None,
                    },
                );
            }
        }
        if out.by_frame.is_empty() {
            bail!("no annotations");
        }
        Ok(out)
    }

    /// Number of annotated frames plus time ranges.
    pub fn len(&self) -> usize {
        self.by_frame.len() + self.ranges.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

fn check_box(b: &[f32; 4]) -> Result<()> {
    if !b.iter().all(|v| v.is_finite()) || b[2] <= b[0] || b[3] <= b[1] {
        bail!("box {b:?} is empty or not finite (need x2 > x1, y2 > y1)");
    }
    Ok(())
}

/// The last run of digits in a file name's stem.
fn trailing_number(name: &str) -> Option<u64> {
    let stem = Path::new(name).file_stem()?.to_str()?;
    let end = stem.rfind(|c: char| c.is_ascii_digit())? + 1;
    let start = stem[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    stem[start..end].parse().ok()
}

impl GroundTruth for Annotations {
    fn at(&self, index: u64, pts: f64) -> Result<Option<GtBox>> {
        if let Some(b) = self.by_frame.get(&index) {
            return Ok(Some(b.clone()));
        }
        let i = self.ranges.partition_point(|r| r.0 <= pts);
        Ok(i.checked_sub(1)
            .map(|i| &self.ranges[i])
            .filter(|r| pts < r.1)
            .map(|r| r.2.clone()))
    }
    fn describe(&self) -> String {
        format!(
            "annotations {} ({} frames, {} time ranges)",
            self.source,
            self.by_frame.len(),
            self.ranges.len()
        )
    }
    fn frame_size(&self) -> Option<(u32, u32)> {
        self.size
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_frames_and_ranges() {
        let a = Annotations::from_csv(
            "# boxes\nframe,x1,y1,x2,y2,segment\n0,1,2,30,40,a\n3,5,5,9,9,\n",
        )
        .unwrap();
        assert_eq!(a.at(0, 9.0).unwrap().unwrap().bbox, [1.0, 2.0, 30.0, 40.0]);
        assert_eq!(a.at(0, 0.0).unwrap().unwrap().segment.as_deref(), Some("a"));
        assert_eq!(a.at(3, 0.0).unwrap().unwrap().segment, None);
        assert!(a.at(1, 0.0).unwrap().is_none());
        let r =
            Annotations::from_csv("t_start,t_end,x1,y1,x2,y2\n1.0,2.0,0,0,5,5\n2.0,3,1,1,6,6\n")
                .unwrap();
        assert!(r.at(0, 0.99).unwrap().is_none());
        assert_eq!(r.at(0, 1.0).unwrap().unwrap().bbox[0], 0.0);
        assert_eq!(
            r.at(0, 2.0).unwrap().unwrap().bbox[0],
            1.0,
            "half-open ranges"
        );
        assert!(r.at(0, 3.0).unwrap().is_none());
    }

    #[test]
    fn csv_errors_say_what_is_wrong() {
        let e = |t: &str| format!("{:#}", Annotations::from_csv(t).unwrap_err());
        assert!(e("frame,x1,y1,x2\n0,1,2,3\n").contains("\"y2\""));
        assert!(e("frame,x1,y1,x2,y2\n0,5,2,3,9\n").contains("line 2"));
        assert!(e("frame,x1,y1,x2,y2\n0,1,2,3,x\n").contains("not a number"));
        assert!(e("frame,x1,y1,x2,y2\n0,1,1,3,3\n0,1,1,3,3\n").contains("twice"));
        assert!(e("t_start,t_end,x1,y1,x2,y2\n0,2,1,1,3,3\n1,3,1,1,3,3\n").contains("overlap"));
        assert!(e("x1,y1,x2,y2\n1,1,3,3\n").contains("frame column"));
    }

    #[test]
    fn coco_largest_box_per_frame() {
        let j = r#"{"images":[{"id":7,"file_name":"frame_000012.PNG","width":160,"height":120},
            {"id":8,"file_name":"x.png","frame_index":3}],
            "annotations":[{"image_id":7,"bbox":[10,10,5,5]},{"image_id":7,"bbox":[0,0,50,40]},
            {"image_id":8,"bbox":[1,2,3,4]}],"categories":[]}"#;
        let a = Annotations::from_coco(j).unwrap();
        assert_eq!(a.at(12, 0.0).unwrap().unwrap().bbox, [0.0, 0.0, 50.0, 40.0]);
        assert_eq!(a.at(3, 0.0).unwrap().unwrap().bbox, [1.0, 2.0, 4.0, 6.0]);
        assert_eq!(a.frame_size(), Some((160, 120)));
        let bad = r#"{"images":[{"id":1,"file_name":"x.png"}],"annotations":[]}"#;
        assert!(format!("{:#}", Annotations::from_coco(bad).unwrap_err()).contains("frame number"));
    }
}
