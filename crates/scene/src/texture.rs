//! [`Texture`]: an RGB image in display values, the camouflage atlas and the parts' own maps.

/// An RGB texture in display (sRGB-encoded) values, row-major, row 0 at the top (`v = 1`).
#[derive(Clone, Debug)]
pub struct Texture {
    pub width: usize,
    pub height: usize,
    /// `width * height` texels, each `[r, g, b]` in `[0, 1]`.
    pub texels: Vec<[f32; 3]>,
}

impl Texture {
    pub fn from_rgb8(img: &image::RgbImage) -> Self {
        let texels = img
            .pixels()
            .map(|p| {
                [
                    p[0] as f32 / 255.0,
                    p[1] as f32 / 255.0,
                    p[2] as f32 / 255.0,
                ]
            })
            .collect();
        Texture {
            width: img.width() as usize,
            height: img.height() as usize,
            texels,
        }
    }

    pub fn to_rgb8(&self) -> image::RgbImage {
        let mut img = image::RgbImage::new(self.width as u32, self.height as u32);
        for (p, t) in img.pixels_mut().zip(&self.texels) {
            *p = image::Rgb(t.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8));
        }
        img
    }

    /// A texture of one colour.
    pub fn solid(width: usize, height: usize, rgb: [f32; 3]) -> Self {
        Texture {
            width,
            height,
            texels: vec![rgb; width * height],
        }
    }
}
