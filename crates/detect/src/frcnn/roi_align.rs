//! torchvision's `MultiScaleRoIAlign` (7×7 output, `sampling_ratio` samples per bin side or the
//! adaptive `ceil(roi / 7)` when it is <= 0, `aligned=False`) built on gathers.
//!
//! The sampling positions and bilinear weights depend only on the (fixed, detached) boxes, so
//! they are computed on the host exactly as the CPU kernel does (f32, the `-1 / +size` border
//! rule, corner clamping); the features are then gathered (`select`) and weighted on the device,
//! so gradients flow to the features and on to the image. The level of each box comes from
//! torchvision's `LevelMapper` (canonical 224 px at level 4, clamped to the levels present).

use burn::tensor::{Int, Tensor, TensorData};

pub(crate) const OUTPUT: usize = 7;

/// `_infer_scale`: the power of two nearest to `feature / image` (in f32).
pub(crate) fn infer_scale(feature: usize, image: usize) -> f32 {
    let approx = (feature as f64 / image as f64) as f32;
    2f32.powf(approx.log2().round_ties_even())
}

/// `LevelMapper`: the level index (0-based from `k_min`) of each box.
pub(crate) fn map_levels(boxes: &[[f32; 4]], k_min: i64, k_max: i64) -> Vec<usize> {
    boxes
        .iter()
        .map(|b| {
            let s = ((b[2] - b[0]) * (b[3] - b[1])).sqrt();
            let l = (4.0 + (s / 224.0).log2() + 1e-6f32).floor();
            let l = l.clamp(k_min as f32, k_max as f32) as i64;
            (l - k_min) as usize
        })
        .collect()
}

/// Gather entries `(flat pixel, weight)` of every output bin of one box, torchvision's CPU
/// `roi_align` kernel; each bin padded to `per_bin` entries with zero weights.
fn box_entries(
    b: &[f32; 4],
    scale: f32,
    (h, w): (usize, usize),
    sampling_ratio: i64,
    base: usize,
) -> Vec<Vec<(usize, f32)>> {
    let (x1, y1) = (b[0] * scale, b[1] * scale);
    let (x2, y2) = (b[2] * scale, b[3] * scale);
    let rw = (x2 - x1).max(1.0);
    let rh = (y2 - y1).max(1.0);
    let bw = rw / OUTPUT as f32;
    let bh = rh / OUTPUT as f32;
    let gh = if sampling_ratio > 0 {
        sampling_ratio as usize
    } else {
        (rh / OUTPUT as f32).ceil() as usize
    };
    let gw = if sampling_ratio > 0 {
        sampling_ratio as usize
    } else {
        (rw / OUTPUT as f32).ceil() as usize
    };
    let count = (gh * gw).max(1) as f32;
    let (hf, wf) = (h as f32, w as f32);
    let mut bins = Vec::with_capacity(OUTPUT * OUTPUT);
    for ph in 0..OUTPUT {
        for pw in 0..OUTPUT {
            let mut e = Vec::with_capacity(gh * gw * 4);
            for iy in 0..gh {
                let y0 = y1 + ph as f32 * bh + (iy as f32 + 0.5) * bh / gh as f32;
                for ix in 0..gw {
                    let x0 = x1 + pw as f32 * bw + (ix as f32 + 0.5) * bw / gw as f32;
                    if y0 < -1.0 || y0 > hf || x0 < -1.0 || x0 > wf {
                        continue;
                    }
                    let (mut y, mut x) = (y0.max(0.0), x0.max(0.0));
                    let (mut yl, mut xl) = (y as usize, x as usize);
                    let yh = if yl >= h - 1 {
                        yl = h - 1;
                        y = yl as f32;
                        yl
                    } else {
                        yl + 1
                    };
                    let xh = if xl >= w - 1 {
                        xl = w - 1;
                        x = xl as f32;
                        xl
                    } else {
                        xl + 1
                    };
                    let (ly, lx) = (y - yl as f32, x - xl as f32);
                    let (hy, hx) = (1.0 - ly, 1.0 - lx);
                    for (p, wt) in [
                        (yl * w + xl, hy * hx),
                        (yl * w + xh, hy * lx),
                        (yh * w + xl, ly * hx),
                        (yh * w + xh, ly * lx),
                    ] {
                        e.push((base + p, wt / count));
                    }
                }
            }
            bins.push(e);
        }
    }
    bins
}

/// RoIAlign of `boxes` (`(image index, box)`) on one level `[B, C, H, W]`: `[N·49, C]` rows
/// `(box, bin row, bin column)`.
pub(crate) fn roi_align_level(
    features: &Tensor<4>,
    boxes: &[(usize, [f32; 4])],
    scale: f32,
    sampling_ratio: i64,
) -> Tensor<2> {
    let [b, c, h, w] = features.dims();
    let dev = features.device();
    let bins: Vec<Vec<(usize, f32)>> = boxes
        .iter()
        .flat_map(|(i, bx)| box_entries(bx, scale, (h, w), sampling_ratio, i * h * w))
        .collect();
    let m = bins.len();
    let k = bins.iter().map(Vec::len).max().unwrap_or(0);
    let flat = features
        .clone()
        .permute([0, 2, 3, 1])
        .reshape([b * h * w, c]);
    let mut out: Tensor<2> = Tensor::zeros([m, c], &dev);
    for j in 0..k {
        let (idx, wt): (Vec<i64>, Vec<f32>) = bins
            .iter()
            .map(|e| e.get(j).map_or((0, 0.0), |&(p, wt)| (p as i64, wt)))
            .unzip();
        let idx = Tensor::<1, Int>::from_data(TensorData::new(idx, [m]), &dev);
        let wt = Tensor::<2>::from_data(TensorData::new(wt, [m, 1]), &dev);
        out = out + flat.clone().select(0, idx) * wt;
    }
    out
}

/// `MultiScaleRoIAlign` of every box of the batch (`(image index, box)`, in that order) on the
/// FPN `levels` of a batch whose largest resized image is `image` `(h, w)`: `[N, C·7·7]`, the
/// flattening of torchvision's `[N, C, 7, 7]`.
pub(crate) fn multiscale_roi_align(
    levels: &[Tensor<4>],
    boxes: &[(usize, [f32; 4])],
    image: (usize, usize),
    sampling_ratio: i64,
) -> Tensor<2> {
    let scales: Vec<f32> = levels
        .iter()
        .map(|f| infer_scale(f.dims()[2], image.0))
        .collect();
    let k_min = -scales[0].log2() as i64;
    let k_max = -scales[scales.len() - 1].log2() as i64;
    let plain: Vec<[f32; 4]> = boxes.iter().map(|b| b.1).collect();
    let lv = if levels.len() == 1 {
        vec![0; boxes.len()]
    } else {
        map_levels(&plain, k_min, k_max)
    };
    let c = levels[0].dims()[1];
    let mut parts = Vec::new();
    let mut order = Vec::new();
    for (l, f) in levels.iter().enumerate() {
        let sel: Vec<usize> = (0..boxes.len()).filter(|&i| lv[i] == l).collect();
        if sel.is_empty() {
            continue;
        }
        let bx: Vec<(usize, [f32; 4])> = sel.iter().map(|&i| boxes[i]).collect();
        parts.push(roi_align_level(f, &bx, scales[l], sampling_ratio));
        order.extend(sel);
    }
    let n = boxes.len();
    let bins = OUTPUT * OUTPUT;
    let rows = Tensor::cat(parts, 0);
    // Back to the boxes' order: row of box i = position of i in `order`.
    let mut pos = vec![0usize; n];
    for (p, &i) in order.iter().enumerate() {
        pos[i] = p;
    }
    let identity = pos.iter().enumerate().all(|(i, &p)| i == p);
    let rows = if identity {
        rows
    } else {
        let idx: Vec<i64> = pos
            .iter()
            .flat_map(|&p| (0..bins).map(move |j| (p * bins + j) as i64))
            .collect();
        let dev = rows.device();
        rows.select(
            0,
            Tensor::<1, Int>::from_data(TensorData::new(idx, [n * bins]), &dev),
        )
    };
    rows.reshape([n, bins, c])
        .swap_dims(1, 2)
        .reshape([n, c * bins])
}
