//! `cac detect IMAGE... --model centernet|nanodet|frcnn-*|onnx:MODEL.onnx`: run a COCO detector on images, print
//! the detections (text or one JSON object per line), optionally dump raw tensors (the TFJS
//! reference runner's schema; Faster R-CNN: proposals, class logits, box regression,
//! detections) and draw the boxes. Faster R-CNN models need `--weights` (a torchvision
//! state_dict, `.pth` or `.safetensors`).

use anyhow::{bail, Result};
use cac::detect::{self, Detection};
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct DetectArgs {
    /// Input images (PNG or JPEG).
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// A catalogue name, or your ONNX detector as onnx:MODEL.onnx[:CONFIG.toml].
    #[arg(long, default_value = "centernet", value_parser = crate::cli::values::MODEL_NAME)]
    pub model: String,
    /// NanoDet only: @vladmandic/human's pre-/post-processing (RGB/255 input, argmax boxes),
    /// for parity checks; the default is the model's real BGR mean/std input and DFL decoding.
    #[arg(long)]
    pub human: bool,
    /// One JSON object per detection: {image, label, class_id, score, box:[x1,y1,x2,y2]}.
    #[arg(long)]
    pub json: bool,
    /// Write the network input and raw outputs (reference runner schema) to this file
    /// (with several images, the image name is appended to the file name).
    #[arg(long)]
    pub raw: Option<PathBuf>,
    /// Write the image with the detection boxes drawn to this PNG.
    #[arg(long)]
    pub draw: Option<PathBuf>,
    /// Folder holding the model files (default: the cache, fetched on first use).
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Faster R-CNN only: the torchvision state_dict (`torch.save` .pth or .safetensors).
    #[arg(long)]
    pub weights: Option<PathBuf>,
}

/// `out.ext` → `out-<image stem>.ext` when there are several images.
fn per_image(path: &Path, image: &Path, many: bool) -> PathBuf {
    if !many {
        return path.to_path_buf();
    }
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    let img = image.file_stem().unwrap_or_default().to_string_lossy();
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    path.with_file_name(format!("{stem}-{img}{ext}"))
}

pub fn run(a: DetectArgs) -> Result<()> {
    if a.human && a.model != "nanodet" {
        bail!("--human only applies to --model nanodet");
    }
    let device = super::device::inference();
    // A bare name: the weights come from --weights (spec_with_weights says when one is missing);
    // an ONNX detector names its own file.
    let info = match detect::check_spec(&a.model) {
        Ok(i) => i,
        Err(e) => detect::model_info(&a.model).ok_or(e)?,
    };
    let spec = match info.weights {
        detect::Weights::Onnx if a.weights.is_some() => {
            bail!("--weights does not apply to an ONNX detector (its weights are in the file)")
        }
        detect::Weights::Onnx => a.model.clone(),
        _ => detect::spec_with_weights(info, a.weights.as_deref(), a.human)?,
    };
    let det = detect::load_all(&[spec], a.models.as_deref(), &device)?.remove(0);
    let many = a.images.len() > 1;
    for path in &a.images {
        let img = cac::io::load_rgb(path)?;
        let x = detect::preprocess::image_to_tensor(&img, &device);
        let dets = det.detect(x.clone())?.remove(0);
        print_detections(path, &dets, a.json);
        if let Some(raw) = &a.raw {
            let mut dump = det.raw(x)?;
            dump.image.path = Some(path.display().to_string());
            dump.write(&per_image(raw, path, many))?;
        }
        if let Some(out) = &a.draw {
            cac::io::save_png_atomic(
                &per_image(out, path, many),
                &detect::draw::class_boxes(img, &dets),
            )?;
        }
    }
    Ok(())
}

fn print_detections(image: &Path, dets: &[Detection], json: bool) {
    let image = image.display().to_string();
    for d in dets {
        println!("{}", d.line(&image, json));
    }
    if dets.is_empty() && !json {
        println!("{image}: no detections");
    }
}
