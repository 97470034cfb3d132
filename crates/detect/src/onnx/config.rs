//! An ONNX detector's optional TOML configuration ([`OnnxConfig`]: head, input and output
//! names, size, resize, normalisation, score kind, box format, classes, thresholds; every key
//! has a default, unknown keys and bad values are errors naming the file) and the detector spec
//! `onnx:MODEL.onnx[:CONFIG.toml]` ([`parse_spec`]). Not here: reading the model or running it.

use anyhow::{ensure, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The optional TOML configuration of an ONNX detector. Every field has a default.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct OnnxConfig {
    /// `auto` (default: `split` when `boxes` is set, else `yolov8` for an output `[B, A, N]`
    /// with A < N, `yolov5` for `[B, N, K]` with K < N), `yolov8`, `yolov5` (also YOLOv3/v7
    /// exports) or `split` (boxes `[B, N, 4]` in the output `boxes`, class scores `[B, N, C]` in
    /// `output`, as mmdeploy's dense export writes them).
    pub head: String,
    /// The graph output holding the boxes when they are not in `output` (head `split`).
    pub boxes: Option<String>,
    /// The graph input holding the image (default: the first graph input).
    pub input: Option<String>,
    /// The graph output holding the dense predictions (default: the first graph output).
    pub output: Option<String>,
    /// `[width, height]` of the network input (default: the input's fixed shape; required when
    /// the exported height or width is dynamic).
    pub input_size: Option<[usize; 2]>,
    /// `letterbox` (default: aspect kept, padded with `pad_value`, as ultralytics does) or
    /// `stretch`.
    pub resize: String,
    /// The letterbox border, in [0, 1] (default 114/255, ultralytics' grey).
    pub pad_value: f32,
    /// `rgb` (default) or `bgr`.
    pub channels: String,
    /// Per-channel `(x - mean) / std` on values in [0, 1] (defaults 0 and 1: ultralytics
    /// feeds RGB / 255).
    pub mean: [f32; 3],
    pub std: [f32; 3],
    /// How the output holds class scores: `sigmoid` (default: probabilities made by Sigmoid
    /// nodes in the graph, whose inputs are tapped for exact logits), `probabilities` (no
    /// sigmoid to tap: logits as `log(p / (1 - p))`, saturated beyond about ±16), or
    /// `logits` (raw logits in the output).
    pub scores: String,
    /// `cxcywh` (default) or `xyxy`, in network-input pixels.
    pub box_format: String,
    /// `pixels` (default: boxes in network-input pixels) or `normalized` (fractions of the
    /// network input's width and height, as RT-DETR writes them).
    pub box_scale: String,
    /// Class names in output order (default: the model's `names` metadata as ultralytics
    /// writes it, else COCO-80 when there are 80 classes, else `class0`, `class1`, ...).
    pub classes: Option<Vec<String>>,
    /// Final detections: score threshold (default 0.25), NMS IoU (0.45), cap (100).
    pub score_threshold: f64,
    pub iou_threshold: f64,
    pub max_detections: usize,
    /// The keys the file set (the others are defaults, which a head found inside a file that
    /// selects boxes may replace with its exporter's conventions).
    #[serde(skip)]
    pub(crate) given: Vec<String>,
}

impl Default for OnnxConfig {
    fn default() -> Self {
        OnnxConfig {
            head: "auto".into(),
            boxes: None,
            input: None,
            output: None,
            input_size: None,
            resize: "letterbox".into(),
            pad_value: 114.0 / 255.0,
            channels: "rgb".into(),
            mean: [0.0; 3],
            std: [1.0; 3],
            scores: "sigmoid".into(),
            box_format: "cxcywh".into(),
            box_scale: "pixels".into(),
            classes: None,
            score_threshold: 0.25,
            iou_threshold: 0.45,
            max_detections: 100,
            given: Vec::new(),
        }
    }
}

impl OnnxConfig {
    /// Reads a config file; unknown keys and bad values are errors naming the file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let mut c: OnnxConfig = toml::from_str(&text)
            .with_context(|| format!("{}: invalid ONNX detector config", path.display()))?;
        let table: toml::Table = toml::from_str(&text)
            .with_context(|| format!("{}: invalid ONNX detector config", path.display()))?;
        c.given = table.keys().cloned().collect();
        c.check().with_context(|| format!("{}", path.display()))?;
        Ok(c)
    }

    /// Whether the config file set `key`.
    pub(crate) fn given(&self, key: &str) -> bool {
        self.given.iter().any(|k| k == key)
    }

    pub(crate) fn check(&self) -> Result<()> {
        let one_of = |v: &str, key: &str, ok: &[&str]| {
            ensure!(ok.contains(&v), "{key} = {v:?}: expected one of {ok:?}");
            Ok(())
        };
        one_of(&self.head, "head", &["auto", "yolov8", "yolov5", "split"])?;
        ensure!(
            (self.head == "split") <= self.boxes.is_some(),
            "head = \"split\" needs boxes = \"OUTPUT\" (the graph output holding the boxes)"
        );
        one_of(&self.resize, "resize", &["letterbox", "stretch"])?;
        one_of(&self.channels, "channels", &["rgb", "bgr"])?;
        one_of(
            &self.scores,
            "scores",
            &["sigmoid", "probabilities", "logits"],
        )?;
        one_of(&self.box_format, "box_format", &["cxcywh", "xyxy"])?;
        one_of(&self.box_scale, "box_scale", &["pixels", "normalized"])?;
        ensure!(
            self.std.iter().all(|&s| s != 0.0),
            "std {:?} has a zero",
            self.std
        );
        Ok(())
    }
}

/// A spec `onnx:MODEL.onnx[:CONFIG.toml]` split into its paths.
pub fn parse_spec(spec: &str) -> Option<(PathBuf, Option<PathBuf>)> {
    let rest = spec.strip_prefix("onnx:")?;
    if rest.is_empty() {
        return None;
    }
    // The config is the part after the last `:` when it ends in .toml.
    match rest.rsplit_once(':') {
        Some((m, c)) if c.ends_with(".toml") && !m.is_empty() => {
            Some((PathBuf::from(m), Some(PathBuf::from(c))))
        }
        _ => Some((PathBuf::from(rest), None)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_split_into_model_and_config() {
        assert_eq!(parse_spec("onnx:m.onnx"), Some(("m.onnx".into(), None)));
        assert_eq!(
            parse_spec("onnx:/a/m.onnx:/b/c.toml"),
            Some(("/a/m.onnx".into(), Some("/b/c.toml".into())))
        );
        assert_eq!(parse_spec("onnx:"), None);
        assert_eq!(parse_spec("nanodet"), None);
    }

    #[test]
    fn config_rejects_unknown_keys_and_values() {
        let bad: std::result::Result<OnnxConfig, _> = toml::from_str("heads = \"yolov8\"");
        assert!(bad.is_err());
        let c: OnnxConfig = toml::from_str("head = \"yolov9\"").unwrap();
        let e = c.check().unwrap_err().to_string();
        assert!(e.contains("head") && e.contains("yolov9"), "{e}");
    }
}
