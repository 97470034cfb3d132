//! Scores a frame stream (an adapter of the scoring core, `eval::score`): sample frames (every k-th, or the nearest frame to given times), look
//! up each frame's ground-truth box, detect with each model, score with the evaluation protocol
//! (`eval::score::Scorer`), and summarise P@0.5 over all frames and as mean ± std over segments
//! (the ground truth's segments — revolutions, distance ratios, annotated ranges — or fixed time
//! windows).

use super::annotations::{GroundTruth, GtBox};
use super::decode::{FrameStream, VideoFrame};
use anyhow::{bail, Result};
use burn::tensor::Device;
use cac_detect::{nms::iou, preprocess::image_to_tensor, Detection, Detector};
use cac_eval::score::{group_by, mean_std, Figures, ImageScore, Scorer};
use cac_eval::Protocol;
use serde::Serialize;
use std::time::Instant;

/// Which frames are scored.
#[derive(Clone, Debug, PartialEq)]
pub enum Sampling {
    /// Frames 0, k, 2k, ...
    Every(u64),
    /// The frame nearest to each time (seconds); a frame is scored once even if nearest to several.
    At(Vec<f64>),
}

/// How scored frames are grouped when the ground truth names no segment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Segmenting {
    /// The ground truth's segment names; frames without one form the segment `all`.
    FromGroundTruth,
    /// Windows of this many seconds from t = 0 (overrides the ground truth's names).
    Window(f64),
}

/// Options of [`score_stream`].
#[derive(Clone, Debug)]
pub struct ScoreOptions {
    pub sampling: Sampling,
    pub segmenting: Segmenting,
    pub protocol: Protocol,
    /// Stop after this many scored frames.
    pub max_frames: Option<usize>,
}

impl Default for ScoreOptions {
    fn default() -> Self {
        ScoreOptions {
            sampling: Sampling::Every(1),
            segmenting: Segmenting::FromGroundTruth,
            protocol: Protocol::default(),
            max_frames: None,
        }
    }
}

/// One model's outcome on one frame.
#[derive(Clone, Debug, Serialize)]
pub struct ModelFrame {
    pub score: ImageScore,
    pub detections: Vec<Detection>,
    /// The highest-scoring detection with IoU >= the protocol's threshold (any class).
    pub matched: Option<(Detection, f64)>,
    /// Detection time (pre-processing, network, NMS), milliseconds.
    pub ms: f64,
}

/// One scored frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameRecord {
    pub index: u64,
    pub pts: f64,
    pub segment: String,
    pub gt: [f32; 4],
    /// Turntable angle (degrees, unwrapped), with a turntable-log ground truth.
    pub angle_deg: Option<f64>,
    /// Per model, in the order of the detectors.
    pub models: Vec<ModelFrame>,
}

/// P@0.5 of one segment.
#[derive(Clone, Debug, Serialize)]
pub struct SegmentStat {
    pub name: String,
    pub frames: usize,
    pub p_at_05: f64,
    pub t_start: f64,
    pub t_end: f64,
}

/// One model over the whole stream.
#[derive(Clone, Debug, Serialize)]
pub struct ModelSummary {
    pub model: String,
    pub frames: usize,
    /// Hits / scored frames.
    pub p_at_05: f64,
    pub targeted_success: f64,
    pub mean_best_true_conf: f64,
    pub segments: Vec<SegmentStat>,
    /// Mean and sample standard deviation (n − 1) of the segments' P@0.5.
    pub segment_mean: f64,
    pub segment_std: f64,
    pub ms_per_frame: f64,
}

/// Everything [`score_stream`] found.
#[derive(Clone, Debug, Serialize)]
pub struct VideoScores {
    pub source: String,
    pub ground_truth: String,
    pub protocol: Protocol,
    pub frames: Vec<FrameRecord>,
    pub summary: Vec<ModelSummary>,
    /// Frames decoded, frames sampled but without ground truth.
    pub decoded: u64,
    pub unannotated: u64,
    /// Requested times that no frame was near (outside the video).
    pub missed_times: Vec<f64>,
    /// Seconds spent decoding (waiting for frames) and detecting.
    pub decode_s: f64,
    pub detect_s: f64,
}

/// Picks the sampled frames out of a stream, holding at most one frame back.
struct Sampler {
    sampling: Sampling,
    next_time: usize,
    prev: Option<VideoFrame>,
    last_taken: Option<u64>,
    missed: Vec<f64>,
}

impl Sampler {
    fn new(mut sampling: Sampling) -> Result<Sampler> {
        match &mut sampling {
            Sampling::Every(0) => bail!("--every must be at least 1"),
            Sampling::At(t) => {
                if t.is_empty() || t.iter().any(|x| !x.is_finite()) {
                    bail!("sampling times must be finite and at least one");
                }
                t.sort_by(f64::total_cmp);
            }
            _ => {}
        }
        Ok(Sampler {
            sampling,
            next_time: 0,
            prev: None,
            last_taken: None,
            missed: vec![],
        })
    }

    fn offer(&mut self, f: VideoFrame, out: &mut Vec<VideoFrame>) {
        let times = match &self.sampling {
            Sampling::Every(k) => {
                if f.index % k == 0 {
                    out.push(f);
                }
                return;
            }
            Sampling::At(t) => t,
        };
        while let Some(&t) = times.get(self.next_time) {
            if f.pts < t {
                break;
            }
            let pick = match &self.prev {
                Some(p) if (t - p.pts) <= (f.pts - t) => p,
                _ => &f,
            };
            if self.last_taken != Some(pick.index) {
                self.last_taken = Some(pick.index);
                out.push(pick.clone());
            }
            self.next_time += 1;
        }
        self.prev = Some(f);
    }

    /// Times after the last frame: the last frame, if within half a second.
    fn finish(&mut self, out: &mut Vec<VideoFrame>) {
        if let Sampling::At(t) = &self.sampling {
            for &t in &t[self.next_time..] {
                match &self.prev {
                    Some(p) if t - p.pts <= 0.5 => {
                        if self.last_taken != Some(p.index) {
                            self.last_taken = Some(p.index);
                            out.push(p.clone());
                        }
                    }
                    _ => self.missed.push(t),
                }
            }
        }
    }
}

/// The detection a frame is "seen as": highest score with IoU >= the threshold.
fn matched(dets: &[Detection], gt: &[f32; 4], p: &Protocol) -> Option<(Detection, f64)> {
    dets.iter()
        .map(|d| (d, iou(&d.bbox, gt)))
        .filter(|(_, o)| *o >= p.iou)
        .max_by(|a, b| a.0.score.total_cmp(&b.0.score))
        .map(|(d, o)| (d.clone(), o))
}

/// Scores `stream` against `gt` with each detector. `on_frame` sees every scored frame (to draw
/// the annotated output). Memory: one decoded frame (two with time sampling) plus the records.
pub fn score_stream(
    stream: &mut dyn FrameStream,
    gt: &dyn GroundTruth,
    detectors: &[&dyn Detector],
    opts: &ScoreOptions,
    device: &Device,
    on_frame: &mut dyn FnMut(&VideoFrame, &FrameRecord) -> Result<()>,
) -> Result<VideoScores> {
    let (w, h) = check_inputs(stream, gt, detectors, opts)?;
    let mut sampler = Sampler::new(opts.sampling.clone())?;
    let scorer = Scorer::new(detectors, &opts.protocol)?;
    let mut res = VideoScores {
        source: stream.describe(),
        ground_truth: gt.describe(),
        protocol: opts.protocol.clone(),
        frames: vec![],
        summary: vec![],
        decoded: 0,
        unannotated: 0,
        missed_times: vec![],
        decode_s: 0.0,
        detect_s: 0.0,
    };
    let mut picked = Vec::new();
    let mut ended = false;
    while !ended && opts.max_frames.is_none_or(|m| res.frames.len() < m) {
        let t0 = Instant::now();
        let next = stream.next_frame()?;
        res.decode_s += t0.elapsed().as_secs_f64();
        match next {
            Some(f) => {
                res.decoded += 1;
                sampler.offer(f, &mut picked);
            }
            None => {
                sampler.finish(&mut picked);
                ended = true;
            }
        }
        for f in picked.drain(..) {
            if opts.max_frames.is_some_and(|m| res.frames.len() >= m) {
                break;
            }
            let Some(g) = gt.at(f.index, f.pts)? else {
                res.unannotated += 1;
                continue;
            };
            let rec = score_frame(&f, &g, (w, h), &scorer, opts, device, &mut res.detect_s)?;
            on_frame(&f, &rec)?;
            res.frames.push(rec);
        }
    }
    res.missed_times = std::mem::take(&mut sampler.missed);
    res.summary = detectors
        .iter()
        .enumerate()
        .map(|(m, d)| summarise(&res.frames, m, d.name()))
        .collect();
    Ok(res)
}

/// Refuses what cannot be scored (no detectors, ground truth made on frames of another size, a
/// segment window that is not a positive number of seconds); the stream's frame size.
fn check_inputs(
    stream: &dyn FrameStream,
    gt: &dyn GroundTruth,
    detectors: &[&dyn Detector],
    opts: &ScoreOptions,
) -> Result<(u32, u32)> {
    if detectors.is_empty() {
        bail!("no detectors to score with");
    }
    let (w, h) = stream.size();
    if let Some(s) = gt.frame_size() {
        if s != (w, h) {
            bail!(
                "the ground truth is for {}x{} frames but {} gives {w}x{h} frames (rotation?)",
                s.0,
                s.1,
                stream.describe()
            );
        }
    }
    if let Segmenting::Window(s) = opts.segmenting {
        if !(s.is_finite() && s > 0.0) {
            bail!("segment window must be a positive number of seconds, got {s}");
        }
    }
    Ok((w, h))
}

/// Detects on one annotated frame with every model and scores it against its ground truth `g`
/// (refused when the box lies outside the `w`×`h` frame); adds the detection time to
/// `detect_s`.
fn score_frame(
    f: &VideoFrame,
    g: &GtBox,
    (w, h): (u32, u32),
    scorer: &Scorer,
    opts: &ScoreOptions,
    device: &Device,
    detect_s: &mut f64,
) -> Result<FrameRecord> {
    let b = g.bbox;
    if b[0] < -1.0 || b[1] < -1.0 || b[2] > w as f32 + 1.0 || b[3] > h as f32 + 1.0 {
        bail!(
            "frame {} (t = {:.3} s): ground-truth box {b:?} lies outside the {w}x{h} frame \
             (rotation or scale of the annotations?)",
            f.index,
            f.pts
        );
    }
    let segment = match opts.segmenting {
        Segmenting::Window(s) => {
            let k = (f.pts / s).floor();
            format!("{:.2}-{:.2} s", k * s, (k + 1.0) * s)
        }
        Segmenting::FromGroundTruth => g.segment.clone().unwrap_or_else(|| "all".into()),
    };
    let x = image_to_tensor(&f.image, device);
    let label = || format!("frame {}", f.index);
    let models: Vec<ModelFrame> = scorer
        .frame(x, &b, Some(&label))?
        .into_iter()
        .map(|o| {
            *detect_s += o.ms / 1e3;
            ModelFrame {
                matched: matched(&o.detections, &b, &opts.protocol),
                score: o.score,
                detections: o.detections,
                ms: o.ms,
            }
        })
        .collect();
    Ok(FrameRecord {
        index: f.index,
        pts: f.pts,
        segment,
        gt: b,
        angle_deg: g.angle_deg,
        models,
    })
}

/// One model's summary over the records.
pub fn summarise(frames: &[FrameRecord], m: usize, name: &str) -> ModelSummary {
    let s = Figures::of_scores(frames.iter().map(|f| &f.models[m].score));
    let segs: Vec<SegmentStat> = group_by(frames, |f| f.segment.clone())
        .into_iter()
        .map(|(name, fs)| SegmentStat {
            name,
            frames: fs.len(),
            p_at_05: Figures::of_scores(fs.iter().map(|f| &f.models[m].score)).p_at_05,
            t_start: fs.iter().map(|f| f.pts).fold(f64::INFINITY, f64::min),
            t_end: fs.iter().map(|f| f.pts).fold(f64::NEG_INFINITY, f64::max),
        })
        .collect();
    let (segment_mean, segment_std) = mean_std(&segs.iter().map(|s| s.p_at_05).collect::<Vec<_>>());
    let n = frames.len().max(1) as f64;
    ModelSummary {
        model: name.to_string(),
        frames: frames.len(),
        p_at_05: s.p_at_05,
        targeted_success: s.targeted_success,
        mean_best_true_conf: s.mean_best_true_conf,
        segments: segs,
        segment_mean,
        segment_std,
        ms_per_frame: frames.iter().map(|f| f.models[m].ms).sum::<f64>() / n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(index: u64, pts: f64) -> VideoFrame {
        VideoFrame {
            index,
            pts,
            image: image::RgbImage::new(1, 1),
        }
    }

    fn run(s: Sampling, pts: &[f64]) -> (Vec<u64>, Vec<f64>) {
        let mut sm = Sampler::new(s).unwrap();
        let mut out = vec![];
        for (i, &t) in pts.iter().enumerate() {
            sm.offer(frame(i as u64, t), &mut out);
        }
        sm.finish(&mut out);
        (out.iter().map(|f| f.index).collect(), sm.missed)
    }

    fn rec(pts: f64, segment: &str, hit: bool, targeted: bool) -> FrameRecord {
        FrameRecord {
            index: (pts * 10.0) as u64,
            pts,
            segment: segment.into(),
            gt: [0.0; 4],
            angle_deg: None,
            models: vec![ModelFrame {
                score: ImageScore {
                    hit,
                    targeted,
                    best_true_conf: if hit { 0.8 } else { 0.2 },
                },
                detections: vec![],
                matched: None,
                ms: 10.0 * pts,
            }],
        }
    }

    #[test]
    fn segments_in_order_of_appearance_with_their_time_span() {
        let frames = [
            rec(0.4, "ratio 2", true, false),
            rec(0.1, "ratio 2", false, true),
            rec(0.2, "ratio 3", true, false),
            rec(0.9, "ratio 2", true, false),
        ];
        let s = summarise(&frames, 0, "m");
        let segs: Vec<(&str, usize, f64, f64, f64)> = s
            .segments
            .iter()
            .map(|g| (g.name.as_str(), g.frames, g.p_at_05, g.t_start, g.t_end))
            .collect();
        assert_eq!(
            segs,
            vec![
                ("ratio 2", 3, 2.0 / 3.0, 0.1, 0.9),
                ("ratio 3", 1, 1.0, 0.2, 0.2)
            ]
        );
        assert_eq!((s.frames, s.p_at_05, s.targeted_success), (4, 0.75, 0.25));
        assert!((s.mean_best_true_conf - 0.65).abs() < 1e-6);
        assert!((s.segment_mean - 5.0 / 6.0).abs() < 1e-12);
        assert!((s.segment_std - (1.0f64 / 18.0).sqrt()).abs() < 1e-12);
        assert!((s.ms_per_frame - 4.0).abs() < 1e-12);
    }

    #[test]
    fn every_kth_and_nearest_to_times() {
        let pts = [0.0, 0.1, 0.2, 0.5, 0.6, 1.0];
        assert_eq!(run(Sampling::Every(2), &pts).0, vec![0, 2, 4]);
        // 0.14 → 0.1 (frame 1); 0.16 → 0.2; 0.34 → 0.2 again (scored once); 0.75 → 0.6;
        // 1.2 → the last frame (within 0.5 s); 9 → missed.
        let (got, missed) = run(Sampling::At(vec![0.16, 0.14, 0.34, 0.75, 1.2, 9.0]), &pts);
        assert_eq!(got, vec![1, 2, 4, 5]);
        assert_eq!(missed, vec![9.0]);
        assert!(Sampler::new(Sampling::Every(0)).is_err());
    }
}
