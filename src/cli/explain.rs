//! `cac explain`: a Grad-CAM attention map of a detector's class score for an image, written as
//! an overlay PNG (the paper's Figure 7); `--list-layers` prints the layers one can pick.

use super::{device, train};
use anyhow::{Context, Result};
use cac::detect::{labels, preprocess};
use cac::eval::gradcam;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Input image (PNG/JPEG).
    pub image: PathBuf,
    /// Detector: centernet, nanodet, or onnx:MODEL.onnx (a head whose sigmoid cac taps).
    #[arg(long, default_value = "nanodet")]
    pub model: String,
    /// The class whose score is explained, by name (one of the model's classes; COCO-80 labels
    /// for the built-in detectors).
    #[arg(long, default_value = "car")]
    pub class: String,
    /// Graph node (feature map) to explain at (default: the model's late feature map).
    #[arg(long)]
    pub layer: Option<String>,
    /// Print the feature maps of the graph (name, op, shape) instead.
    #[arg(long)]
    pub list_layers: bool,
    /// Weight of the map in the overlay (0 to 1).
    #[arg(long, default_value_t = 0.6)]
    pub alpha: f32,
    /// Output overlay PNG.
    #[arg(long, default_value = "gradcam.png")]
    pub out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let det = train::load_detectors(std::slice::from_ref(&a.model))?.remove(0);
    let class = labels::resolve(&a.class, det.classes(), det.name()).context("--class")?;
    let img = cac::io::load_rgb(&a.image)?;
    let x = preprocess::image_to_tensor(&img, &device::inference());
    if a.list_layers {
        println!("{:<60} {:<28} shape (NHWC)", "layer", "op");
        for l in gradcam::layers(det.as_ref(), x)? {
            println!("{:<60} {:<28} {:?}", l.name, l.op, l.shape);
        }
        return Ok(());
    }
    let cam = gradcam::grad_cam(det.as_ref(), x, class, a.layer.as_deref())?;
    cac::io::save_png_atomic(&a.out, &cam.overlay(&img, a.alpha.clamp(0.0, 1.0)))?;
    let (px, py) = cam.peak(img.width(), img.height());
    println!(
        "{}: Grad-CAM of {:?} (logit {:.3}) at layer {} ({}x{}); peak at pixel ({px}, {py}); wrote {}",
        a.model,
        a.class,
        cam.score,
        cam.layer,
        cam.grid.1,
        cam.grid.0,
        a.out.display()
    );
    Ok(())
}
