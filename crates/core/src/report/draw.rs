//! Boxes with labels drawn into images (detections, ground truth), for example views in reports.

use super::font;
use image::RgbImage;

/// Draws the outline of `bbox` (`x1, y1, x2, y2` in pixels), `stroke` px wide, and `label` (may
/// be empty) in the bitmap font on a filled tab above its top-left corner (inside when at the top).
pub fn labelled_box(img: &mut RgbImage, bbox: [f32; 4], rgb: [u8; 3], stroke: u32, label: &str) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let [x1, y1, x2, y2] = bbox.map(|v| v.round() as i64);
    let mut put = |x: i64, y: i64| {
        if x >= 0 && y >= 0 && x < w && y < h {
            img.put_pixel(x as u32, y as u32, image::Rgb(rgb));
        }
    };
    for t in 0..stroke as i64 {
        for x in x1..=x2 {
            put(x, y1 + t);
            put(x, y2 - t);
        }
        for y in y1..=y2 {
            put(x1 + t, y);
            put(x2 - t, y);
        }
    }
    if label.is_empty() {
        return;
    }
    let th = 9;
    let ty = if y1 - th >= 0 {
        y1 - th
    } else {
        y1 + stroke as i64
    };
    let tw = font::text_width(label, 1) as i64 + 3;
    for y in ty.max(0)..(ty + th).min(h) {
        for x in x1.max(0)..(x1 + tw).min(w) {
            img.put_pixel(x as u32, y as u32, image::Rgb(rgb));
        }
    }
    let ink = if rgb.iter().map(|&c| c as u32).sum::<u32>() > 380 {
        [0, 0, 0]
    } else {
        [255, 255, 255]
    };
    font::draw_text(img, x1 + 2, ty + 1, label, 1, ink);
}

/// A fixed colour per COCO class id (distinct neighbours).
pub fn class_colour(class_id: usize) -> [u8; 3] {
    let c = class_id as u32;
    [
        (50 + c * 97 % 206) as u8,
        (255 - c * 53 % 200) as u8,
        (c * 31 % 256) as u8,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outline_and_tab_are_drawn_where_the_box_is() {
        let mut img = RgbImage::new(64, 48);
        labelled_box(
            &mut img,
            [10.0, 20.0, 50.0, 40.0],
            [255, 0, 0],
            2,
            "CAR 0.9",
        );
        assert_eq!(img.get_pixel(30, 20).0, [255, 0, 0], "top edge");
        assert_eq!(img.get_pixel(49, 30).0, [255, 0, 0], "right edge (2 px)");
        assert_eq!(img.get_pixel(30, 30).0, [0, 0, 0], "inside is untouched");
        assert_eq!(img.get_pixel(5, 5).0, [0, 0, 0], "outside is untouched");
        let tab = (11..20)
            .filter(|&y| img.get_pixel(11, y).0 == [255, 0, 0])
            .count();
        assert!(tab >= 8, "label tab above the box ({tab} px)");
        labelled_box(&mut img, [-5.0, -5.0, 100.0, 100.0], [0, 255, 0], 1, "X");
    }
}
