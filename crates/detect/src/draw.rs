//! Detections drawn for a person to look at (`cac detect --draw`): 2-pixel boxes, one colour
//! per COCO class, straight into the image.

use crate::detector::Detection;

/// Draws 2-px boxes, one colour per class.
pub fn class_boxes(mut img: image::RgbImage, dets: &[Detection]) -> image::RgbImage {
    for d in dets {
        let c = d.class_id as u32;
        let colour = [
            (50 + c * 97 % 206) as u8,
            (255 - c * 53 % 200) as u8,
            (c * 31 % 256) as u8,
        ];
        cac_core::report::draw::labelled_box(&mut img, d.bbox, colour, 2, "");
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_pixel_outline_clipped_to_the_image() {
        let d = |bbox| Detection {
            class_id: 2,
            label: "car",
            score: 0.9,
            bbox,
        };
        let img = class_boxes(
            image::RgbImage::new(20, 20),
            &[d([4.0, 5.0, 12.0, 15.0]), d([15.0, 15.0, 40.0, 40.0])],
        );
        // Class 2: (50 + 2·97 mod 206, 255 − 2·53 mod 200, 2·31).
        let c = image::Rgb([244, 149, 62]);
        for (x, y) in [
            (4, 5),
            (5, 6),
            (12, 15),
            (11, 14),
            (8, 5),
            (4, 10),
            (15, 19),
        ] {
            assert_eq!(*img.get_pixel(x, y), c, "({x}, {y}) on the outline");
        }
        for (x, y) in [(6, 7), (8, 10), (10, 13), (3, 5), (13, 15), (0, 0)] {
            assert_eq!(*img.get_pixel(x, y), image::Rgb([0, 0, 0]), "({x}, {y})");
        }
    }
}
