//! A detector behind defences: itself a [`Detector`], so everything that takes one takes it.

use super::chain::{host, mix, seed_of, Affine, Chain};
use super::image_hash;
use crate::detector::{CamIo, Candidates, Detection, Detector};
use crate::raw;
use anyhow::Result;
use burn::tensor::Tensor;
use std::cell::RefCell;
use std::rc::Rc;

/// The last image a chain defended without gradients (its hash, the result, where its points
/// went), shared by the detectors behind that chain: the evaluation scores each image with every
/// model in turn, so the defence runs once per image, not once per model.
type Last = Rc<RefCell<Option<(u64, Tensor<4>, Affine)>>>;

/// `inner` with `chains` in front: one chain, that defence; several, one drawn per image by
/// the image's hash (expectation over transformations, for training through them); none, the
/// detector itself. Boxes come back in the input image's pixels.
pub struct Defended {
    inner: Rc<dyn Detector>,
    chains: Vec<Chain>,
    name: String,
    last: Last,
}

impl Defended {
    pub fn new(inner: Rc<dyn Detector>, chains: Vec<Chain>) -> Defended {
        let name = match chains.is_empty() {
            true => inner.name().to_string(),
            false => {
                let names: Vec<String> = chains.iter().map(Chain::name).collect();
                format!("{}+{}", inner.name(), names.join("|"))
            }
        };
        Defended {
            inner,
            chains,
            name,
            last: Last::default(),
        }
    }

    /// The batch through the defences, image by image, and where each image's points went.
    /// Gradients pass (exactly or straight through) when `images` is an autodiff tensor.
    pub fn defend(&self, images: Tensor<4>) -> (Tensor<4>, Vec<Affine>) {
        if self.chains.is_empty() {
            return (images.clone(), vec![Affine::IDENTITY; images.dims()[0]]);
        }
        let grad = images.is_autodiff();
        let mut out = vec![];
        let mut moved = vec![];
        for i in 0..images.dims()[0] {
            let x = images.clone().narrow(0, i, 1);
            let seed = seed_of(&x);
            let chain = &self.chains[(mix(seed, 0xc4a1) % self.chains.len() as u64) as usize];
            let (y, m) = match (grad, &*self.last.borrow()) {
                (false, Some((h, y, m))) if *h == seed => (y.clone(), *m),
                _ => chain.apply(x, seed, grad),
            };
            if !grad {
                *self.last.borrow_mut() = Some((seed, y.clone(), m));
            }
            out.push(y);
            moved.push(m);
        }
        (Tensor::cat(out, 0), moved)
    }
}

impl Detector for Defended {
    fn name(&self) -> &str {
        &self.name
    }
    fn classes(&self) -> &[&'static str] {
        self.inner.classes()
    }
    fn input_size(&self) -> (usize, usize) {
        self.inner.input_size()
    }
    fn candidates(&self, images: Tensor<4>) -> Result<Candidates> {
        let (x, moved) = self.defend(images);
        let mut c = self.inner.candidates(x)?;
        if moved.iter().any(|m| *m != Affine::IDENTITY) {
            let rows = moved
                .iter()
                .enumerate()
                .map(|(i, m)| m.boxes_back(c.boxes.clone().narrow(0, i, 1)))
                .collect();
            c.boxes = Tensor::cat(rows, 0);
        }
        Ok(c)
    }
    fn detect(&self, images: Tensor<4>) -> Result<Vec<Vec<Detection>>> {
        let (x, moved) = self.defend(images);
        let mut out = self.inner.detect(x)?;
        for (dets, m) in out.iter_mut().zip(&moved) {
            for d in dets {
                d.bbox = m.box_back(d.bbox);
            }
        }
        Ok(out)
    }
    fn raw(&self, image: Tensor<4>) -> Result<raw::RawDump> {
        self.inner.raw(self.defend(image).0)
    }
    fn cam_io(&self, images: Tensor<4>) -> Result<Option<CamIo<'_>>> {
        self.inner.cam_io(self.defend(images).0)
    }
}

/// The evaluation's column groups: each detector as it is, then behind each chain (`none`
/// adds nothing: the detector as it is comes first anyway).
pub fn defend(detectors: Vec<Box<dyn Detector>>, chains: &[Chain]) -> Vec<Box<dyn Detector>> {
    let chains: Vec<&Chain> = chains.iter().filter(|c| !c.0.is_empty()).collect();
    let lasts: Vec<Last> = chains.iter().map(|_| Last::default()).collect();
    let mut out: Vec<Box<dyn Detector>> = vec![];
    for d in detectors {
        let d: Rc<dyn Detector> = Rc::from(d);
        out.push(Box::new(Defended::new(d.clone(), vec![])));
        for (c, last) in chains.iter().zip(&lasts) {
            let mut behind = Defended::new(d.clone(), vec![(*c).clone()]);
            behind.last = last.clone();
            out.push(Box::new(behind));
        }
    }
    out
}

/// The training's detectors: each behind all of `chains` at once, one drawn per image
/// (unchanged when `chains` is empty).
pub fn through(detectors: Vec<Box<dyn Detector>>, chains: &[Chain]) -> Vec<Box<dyn Detector>> {
    if chains.is_empty() {
        return detectors;
    }
    detectors
        .into_iter()
        .map(|d| Box::new(Defended::new(Rc::from(d), chains.to_vec())) as Box<dyn Detector>)
        .collect()
}

/// The hash of a batch's first image, as the defences see it (for tests and logs).
pub fn image_seed(images: &Tensor<4>) -> u64 {
    image_hash(&host(&images.clone().narrow(0, 0, 1)))
}
