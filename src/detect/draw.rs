//! Detections drawn for a person to look at (`cac detect --draw`): 2-pixel boxes, one colour
//! per COCO class, straight into the image.

use super::Detection;

/// Draws 2-px boxes, one colour per class.
pub fn class_boxes(mut img: image::RgbImage, dets: &[Detection]) -> image::RgbImage {
    let (w, h) = (img.width() as i64, img.height() as i64);
    for d in dets {
        let c = d.class_id as u32;
        let colour = image::Rgb([
            (50 + c * 97 % 206) as u8,
            (255 - c * 53 % 200) as u8,
            (c * 31 % 256) as u8,
        ]);
        let [x1, y1, x2, y2] = d.bbox.map(|v| v.round() as i64);
        let mut put = |x: i64, y: i64| {
            if x >= 0 && y >= 0 && x < w && y < h {
                img.put_pixel(x as u32, y as u32, colour);
            }
        };
        for t in 0..2 {
            for x in x1..=x2 {
                put(x, y1 + t);
                put(x, y2 - t);
            }
            for y in y1..=y2 {
                put(x1 + t, y);
                put(x2 - t, y);
            }
        }
    }
    img
}
