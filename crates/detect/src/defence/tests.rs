//! The defences behind a stand-in detector: names, refusals, geometry, gradients, seeding.

use super::*;
use crate::detector::{Candidates, Detection, Detector};
use crate::raw;
use anyhow::Result;
use burn::backend::FlexDevice;
use burn::tensor::{Device, Tensor, TensorData};
use std::rc::Rc;

/// "Detects" the bounding box of the pixels whose red channel is above 0.5 (as a car, class 2),
/// and as its only candidate that box scored by the image's mean.
struct BrightBox;

impl BrightBox {
    fn find(plane: &[f32], h: usize, w: usize) -> Option<[f32; 4]> {
        let on: Vec<(usize, usize)> = (0..h * w)
            .filter(|i| plane[*i] > 0.5)
            .map(|i| (i % w, i / w))
            .collect();
        let x1 = on.iter().map(|p| p.0).min()? as f32;
        let y1 = on.iter().map(|p| p.1).min()? as f32;
        let x2 = on.iter().map(|p| p.0).max()? as f32 + 1.0;
        let y2 = on.iter().map(|p| p.1).max()? as f32 + 1.0;
        Some([x1, y1, x2, y2])
    }
}

impl Detector for BrightBox {
    fn name(&self) -> &str {
        "bright"
    }
    fn input_size(&self) -> (usize, usize) {
        (160, 128)
    }
    fn candidates(&self, images: Tensor<4>) -> Result<Candidates> {
        let [b, _, _, _] = images.dims();
        let dev = images.device();
        let boxes = Tensor::<3>::from_data(TensorData::new(vec![0f32; b * 4], [b, 1, 4]), &dev);
        let logits = images
            .mean_dim(3)
            .mean_dim(2)
            .mean_dim(1)
            .reshape([b, 1, 1]);
        Ok(Candidates {
            boxes,
            scores: burn::tensor::activation::sigmoid(logits.clone()),
            logits,
        })
    }
    fn detect(&self, images: Tensor<4>) -> Result<Vec<Vec<Detection>>> {
        let [b, _, h, w] = images.dims();
        let v = chain::host(&images);
        Ok((0..b)
            .map(|i| {
                let plane = &v[i * 3 * h * w..i * 3 * h * w + h * w];
                BrightBox::find(plane, h, w)
                    .map(|bbox| Detection {
                        class_id: 2,
                        label: "car",
                        score: 0.9,
                        bbox,
                    })
                    .into_iter()
                    .collect()
            })
            .collect())
    }
    fn raw(&self, _image: Tensor<4>) -> Result<raw::RawDump> {
        anyhow::bail!("no raw outputs")
    }
}

fn flex() -> Device {
    Device::from(FlexDevice)
}

/// A grey `[1, 3, 128, 160]` image with a bright rectangle at `x 40..90, y 30..70`; `salt`
/// changes a corner value so that each image hashes differently.
fn scene(salt: usize, dev: &Device) -> Tensor<4> {
    let (h, w) = (128, 160);
    let mut v = vec![0.3f32; 3 * h * w];
    for y in 30..70 {
        for x in 40..90 {
            v[y * w + x] = 0.9;
        }
    }
    v[0] = 0.3 + salt as f32 * 1e-3;
    Tensor::from_data(TensorData::new(v, [1, 3, h, w]), dev)
}

#[test]
fn names_round_trip_and_bad_ones_are_refused_naming_the_accepted() {
    for text in [
        "jpeg:75",
        "blur:1.5",
        "median:5",
        "bits:4",
        "resize-pad:0.8",
        "tv:0.03",
        "lgs:2.3",
    ] {
        assert_eq!(Defence::parse(text).unwrap().name(), text);
    }
    assert_eq!(
        Defence::parse("jpeg").unwrap(),
        Defence::Jpeg { quality: 75 }
    );
    assert_eq!(
        Chain::parse("jpeg:50+bits:4").unwrap().name(),
        "jpeg:50+bits:4"
    );
    assert_eq!(Chain::parse("none").unwrap(), Chain(vec![]));
    for (bad, says) in [
        ("jpg:75", "unknown defence \"jpg\""),
        ("jpeg:0", "outside 1-100"),
        ("jpeg:75.5", "whole number"),
        ("median:4", "odd"),
        ("blur:x", "is not a number"),
        ("resize-pad:1.2", "outside 0.5-1"),
    ] {
        let e = format!("{:#}", Defence::parse(bad).unwrap_err());
        assert!(e.contains(says), "{bad}: {e}");
    }
    let e = format!("{:#}", Defence::parse("sharpen").unwrap_err());
    assert!(
        e.contains("jpeg[:QUALITY") && e.contains("lgs[:STRENGTH"),
        "{e}"
    );
    let twice = parse_chains(&["jpeg:75,bits:5".into(), "jpeg:75".into()]).unwrap_err();
    assert!(twice.to_string().contains("named twice"), "{twice}");
}

/// Behind resize-and-pad the detector sees the rectangle shrunk and moved (every image a
/// different draw), and the boxes come back where the rectangle is in the input: within the
/// resize's one-pixel blur, divided by the scale.
#[test]
fn resize_and_pad_moves_the_image_and_the_boxes_come_back() {
    let dev = flex();
    let d = Defended::new(
        Rc::new(BrightBox),
        vec![Chain::parse("resize-pad:0.6").unwrap()],
    );
    let mut seen = std::collections::HashSet::new();
    for salt in 0..12 {
        let x = scene(salt, &dev);
        let (y, moved) = d.defend(x.clone());
        let direct = BrightBox.detect(y).unwrap()[0][0].bbox;
        seen.insert(direct.map(|v| v as i32));
        assert!(moved[0].sx >= 0.6 - 1e-3 && moved[0].sx <= 1.0);
        let back = d.detect(x).unwrap()[0][0].bbox;
        let tol = 1.5 / moved[0].sx;
        for (got, want) in back.iter().zip([40.0, 30.0, 90.0, 70.0]) {
            assert!(
                (got - want).abs() <= tol,
                "salt {salt}: {back:?}, moved {moved:?}"
            );
        }
    }
    assert!(seen.len() >= 10, "the draws repeat: {seen:?}");
}

/// The same image gets the same defence whether alone or in a batch (a shard and a whole run
/// agree); two chains are both drawn over a few images.
#[test]
fn a_defence_is_a_function_of_the_image() {
    let dev = flex();
    let chains = vec![
        Chain::parse("resize-pad:0.6").unwrap(),
        Chain::parse("tv:0.05").unwrap(),
    ];
    let d = Defended::new(Rc::new(BrightBox), chains);
    let (a, b) = (scene(1, &dev), scene(2, &dev));
    let pair = d.defend(Tensor::cat(vec![a.clone(), b.clone()], 0)).0;
    let alone = Tensor::cat(vec![d.defend(a).0, d.defend(b).0], 0);
    assert_eq!(pair.into_data(), alone.into_data());
    let moved: Vec<bool> = (0..16)
        .map(|s| d.defend(scene(s, &dev)).1[0] != Affine::IDENTITY)
        .collect();
    assert!(moved.contains(&true) && moved.contains(&false), "{moved:?}");
}

/// Straight-through: behind JPEG the gradient of `Σ w·f(x)` is `w` itself; behind the blur it
/// is the exact adjoint: a weight on one interior pixel spreads as the Gaussian (centre weight
/// `k₀²`, total 1).
#[test]
fn gradients_pass_straight_through_or_exactly() {
    let dev = Device::autodiff(flex());
    let (h, w) = (128, 160);
    let weights: Vec<f32> = (0..3 * h * w)
        .map(|i| ((i * 7) % 13) as f32 / 13.0)
        .collect();
    let wt = Tensor::<4>::from_data(TensorData::new(weights.clone(), [1, 3, h, w]), &dev);
    let x = scene(0, &dev).require_grad();
    let jpeg = Defended::new(Rc::new(BrightBox), vec![Chain::parse("jpeg:30").unwrap()]);
    let (y, _) = jpeg.defend(x.clone());
    let g = x.grad(&(y * wt).sum().backward()).unwrap();
    let g = chain::host(&g);
    assert!(g.iter().zip(&weights).all(|(a, b)| (a - b).abs() <= 1e-6));

    let x = scene(0, &dev).require_grad();
    let blur = Defended::new(Rc::new(BrightBox), vec![Chain::parse("blur:1").unwrap()]);
    let (y, _) = blur.defend(x.clone());
    let mut one = vec![0f32; 3 * h * w];
    let p = (h + 50) * w + 70; // channel 1, row 50, column 70
    one[p] = 1.0;
    let one = Tensor::<4>::from_data(TensorData::new(one, [1, 3, h, w]), &dev);
    let g = x.grad(&(y * one).sum().backward()).unwrap();
    let g = chain::host(&g);
    let taps: Vec<f32> = (-3..=3)
        .map(|i: i32| (-(i * i) as f32 / 2.0).exp())
        .collect();
    let k0 = 1.0 / taps.iter().sum::<f32>();
    assert!((g[p] - k0 * k0).abs() < 1e-5, "{} vs {}", g[p], k0 * k0);
    assert!((g.iter().sum::<f32>() - 1.0).abs() < 1e-4);
}

/// The evaluation's column groups: the detector as it is, then behind each chain; the second
/// model behind a chain reuses the first's defended image and gets what a fresh one would.
#[test]
fn defend_makes_one_column_group_per_chain_sharing_the_defended_image() {
    let dev = flex();
    let chains = parse_chains(&["none,resize-pad:0.6".into(), "tv:0.03".into()]).unwrap();
    let list = defend(vec![Box::new(BrightBox), Box::new(BrightBox)], &chains);
    let names: Vec<&str> = list.iter().map(|d| d.name()).collect();
    assert_eq!(
        names,
        ["bright", "bright+resize-pad:0.6", "bright+tv:0.03"].repeat(2)
    );
    let fresh = Defended::new(Rc::new(BrightBox), vec![chains[1].clone()]);
    for salt in [3, 4, 3] {
        let x = scene(salt, &dev);
        let want = fresh.detect(x.clone()).unwrap();
        assert_eq!(list[1].detect(x.clone()).unwrap(), want);
        assert_eq!(list[4].detect(x).unwrap(), want, "salt {salt}");
    }
}
