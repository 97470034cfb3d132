//! Contact sheets: several images in a near-square grid.

/// Lays images (all the same size) out in a grid with a 4-pixel gutter.
pub fn contact_sheet(images: &[image::RgbImage]) -> image::RgbImage {
    assert!(!images.is_empty());
    let (w, h) = images[0].dimensions();
    let cols = (images.len() as f64).sqrt().ceil() as u32;
    let rows = (images.len() as u32).div_ceil(cols);
    let g = 4;
    let mut out = image::RgbImage::from_pixel(
        cols * (w + g) + g,
        rows * (h + g) + g,
        image::Rgb([255, 255, 255]),
    );
    for (i, img) in images.iter().enumerate() {
        let (c, r) = (i as u32 % cols, i as u32 / cols);
        image::imageops::overlay(
            &mut out,
            img,
            (g + c * (w + g)) as i64,
            (g + r * (h + g)) as i64,
        );
    }
    out
}
