//! JPEG re-compression: the image rounded to 8 bits, encoded at a quality and decoded again.

use super::Planes;
use image::codecs::jpeg::JpegEncoder;
use image::{ImageFormat, RgbImage};

/// The image through a JPEG encoder at `quality` (1-100) and back, in [0, 1].
pub fn jpeg(p: Planes, quality: u8) -> Vec<f32> {
    let (h, w) = (p.height, p.width);
    let mut img = RgbImage::new(w as u32, h as u32);
    for (x, y, px) in img.enumerate_pixels_mut() {
        for c in 0..3 {
            let v = p.data[(c * h + y as usize) * w + x as usize];
            px.0[c] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        }
    }
    let mut bytes = vec![];
    JpegEncoder::new_with_quality(&mut bytes, quality)
        .encode_image(&img)
        .expect("an in-memory RGB image encodes");
    let back = image::load_from_memory_with_format(&bytes, ImageFormat::Jpeg)
        .expect("the encoder's own JPEG decodes")
        .to_rgb8();
    let mut out = vec![0f32; 3 * h * w];
    for (x, y, px) in back.enumerate_pixels() {
        for c in 0..3 {
            out[(c * h + y as usize) * w + x as usize] = px.0[c] as f32 / 255.0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A seeded test image: smooth gradients, a few hard edges and some sensor noise.
    fn scene(h: usize, w: usize, seed: u64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut v = vec![0f32; 3 * h * w];
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    let smooth =
                        0.3 + 0.4 * ((x as f32 / 9.0 + c as f32).sin() * (y as f32 / 13.0).cos());
                    let edge = if (x / 16 + y / 16) % 2 == 0 { 0.2 } else { 0.0 };
                    let noise = rng.random_range(-0.02..0.02);
                    v[(c * h + y) * w + x] = (smooth + edge + noise).clamp(0.0, 1.0);
                }
            }
        }
        v
    }

    fn psnr(a: &[f32], b: &[f32]) -> f32 {
        let mse: f32 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f32>() / a.len() as f32;
        10.0 * (1.0 / mse).log10()
    }

    /// Measured on this image (any CPU: the codec is integer arithmetic): quality 100 changes
    /// it by about 8-bit rounding (PSNR ≈ 45 dB), quality 10 by a lot (≈ 27 dB), and the
    /// figures fall in order of quality.
    #[test]
    fn jpeg_at_quality_100_barely_changes_the_image_and_at_10_changes_it_much() {
        let (h, w) = (64, 96);
        let v = scene(h, w, 7);
        let p = Planes {
            data: &v,
            height: h,
            width: w,
        };
        let q: Vec<f32> = [100u8, 75, 30, 10]
            .iter()
            .map(|&q| psnr(&v, &jpeg(p, q)))
            .collect();
        eprintln!("PSNR at quality 100, 75, 30, 10: {q:?} dB");
        assert!(q[0] > 40.0, "quality 100: {} dB", q[0]);
        assert!(q[3] < 32.0, "quality 10: {} dB", q[3]);
        assert!(
            q.windows(2).all(|p| p[0] > p[1]),
            "not in order of quality: {q:?}"
        );
    }
}
