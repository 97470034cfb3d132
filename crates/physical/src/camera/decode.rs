//! Pixel formats of webcams: MJPEG (whose frames often omit the Huffman tables — motion-JPEG
//! relies on the standard ones of JPEG Annex K, which are inserted before decoding) and packed
//! YUYV 4:2:2 (BT.601, limited range).

use super::CameraError;
use image::RgbImage;

// JPEG Annex K.3: the standard Huffman tables (bits per code length, then symbol values).
const DC_LUMA_BITS: [u8; 16] = [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0];
const DC_CHROMA_BITS: [u8; 16] = [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0];
const DC_VALUES: [u8; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
const AC_LUMA_BITS: [u8; 16] = [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7D];
const AC_LUMA_VALUES: [u8; 162] = [
    0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61, 0x07,
    0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xA1, 0x08, 0x23, 0x42, 0xB1, 0xC1, 0x15, 0x52, 0xD1, 0xF0,
    0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0A, 0x16, 0x17, 0x18, 0x19, 0x1A, 0x25, 0x26, 0x27, 0x28,
    0x29, 0x2A, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49,
    0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69,
    0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89,
    0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9A, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7,
    0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4, 0xB5, 0xB6, 0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3, 0xC4, 0xC5,
    0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA, 0xE1, 0xE2,
    0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8, 0xE9, 0xEA, 0xF1, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7, 0xF8,
    0xF9, 0xFA,
];
const AC_CHROMA_BITS: [u8; 16] = [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77];
const AC_CHROMA_VALUES: [u8; 162] = [
    0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61, 0x71,
    0x13, 0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xA1, 0xB1, 0xC1, 0x09, 0x23, 0x33, 0x52, 0xF0,
    0x15, 0x62, 0x72, 0xD1, 0x0A, 0x16, 0x24, 0x34, 0xE1, 0x25, 0xF1, 0x17, 0x18, 0x19, 0x1A, 0x26,
    0x27, 0x28, 0x29, 0x2A, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48,
    0x49, 0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68,
    0x69, 0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87,
    0x88, 0x89, 0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9A, 0xA2, 0xA3, 0xA4, 0xA5,
    0xA6, 0xA7, 0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4, 0xB5, 0xB6, 0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3,
    0xC4, 0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA,
    0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8, 0xE9, 0xEA, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7, 0xF8,
    0xF9, 0xFA,
];

/// The DHT segment (marker included) defining the four standard tables.
pub fn standard_dht() -> Vec<u8> {
    let tables: [(u8, &[u8; 16], &[u8]); 4] = [
        (0x00, &DC_LUMA_BITS, &DC_VALUES),
        (0x10, &AC_LUMA_BITS, &AC_LUMA_VALUES),
        (0x01, &DC_CHROMA_BITS, &DC_VALUES),
        (0x11, &AC_CHROMA_BITS, &AC_CHROMA_VALUES),
    ];
    let mut body = Vec::new();
    for (class_id, bits, values) in tables {
        body.push(class_id);
        body.extend_from_slice(bits);
        body.extend_from_slice(values);
    }
    let len = (body.len() + 2) as u16;
    let mut seg = vec![0xFF, 0xC4];
    seg.extend_from_slice(&len.to_be_bytes());
    seg.extend_from_slice(&body);
    seg
}

fn bad(detail: impl Into<String>) -> CameraError {
    CameraError::Decode {
        what: "MJPEG frame".into(),
        detail: detail.into(),
    }
}

/// Make an MJPEG frame a complete JPEG: if no DHT segment precedes the first SOS, insert the
/// standard tables right before it. Frames that already carry tables are returned unchanged.
pub fn with_huffman_tables(jpeg: &[u8]) -> Result<std::borrow::Cow<'_, [u8]>, CameraError> {
    if jpeg.get(..2) != Some(&[0xFF, 0xD8]) {
        return Err(bad("no JPEG start-of-image marker"));
    }
    let mut pos = 2;
    loop {
        // Markers may be preceded by fill bytes 0xFF.
        while jpeg.get(pos) == Some(&0xFF) && jpeg.get(pos + 1) == Some(&0xFF) {
            pos += 1;
        }
        let (Some(&0xFF), Some(&marker)) = (jpeg.get(pos), jpeg.get(pos + 1)) else {
            return Err(bad(format!("truncated or corrupt marker at byte {pos}")));
        };
        match marker {
            0xC4 => return Ok(std::borrow::Cow::Borrowed(jpeg)),
            0xDA => {
                let mut out = Vec::with_capacity(jpeg.len() + 432);
                out.extend_from_slice(&jpeg[..pos]);
                out.extend_from_slice(&standard_dht());
                out.extend_from_slice(&jpeg[pos..]);
                return Ok(std::borrow::Cow::Owned(out));
            }
            0xD9 => return Err(bad("end of image before any scan")),
            0x01 | 0xD0..=0xD7 => pos += 2,
            _ => {
                let len = jpeg
                    .get(pos + 2..pos + 4)
                    .map(|b| usize::from(u16::from_be_bytes([b[0], b[1]])))
                    .ok_or_else(|| bad("truncated segment header"))?;
                if len < 2 {
                    return Err(bad(format!("segment length {len} at byte {pos}")));
                }
                pos += 2 + len;
            }
        }
    }
}

/// Decode one MJPEG frame (with or without Huffman tables) to RGB. A frame cut short (no
/// end-of-image marker before the zero padding some cameras add) is refused: JPEG decoders fill
/// the missing part with grey instead of failing, and a truncated USB transfer looks like that.
pub fn decode_mjpeg(frame: &[u8]) -> Result<RgbImage, CameraError> {
    let end = frame.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    if end < 4 || frame[end - 2..end] != [0xFF, 0xD9] {
        return Err(bad(format!(
            "no end-of-image marker: the frame was cut short ({end} bytes)"
        )));
    }
    let jpeg = with_huffman_tables(frame)?;
    image::load_from_memory_with_format(&jpeg, image::ImageFormat::Jpeg)
        .map(|i| i.to_rgb8())
        .map_err(|e| bad(e.to_string()))
}

/// Convert packed YUYV 4:2:2 (Y0 U Y1 V per pixel pair, BT.601 limited range) to RGB.
/// `stride` is the byte length of a row (≥ 2·width; drivers may pad rows).
pub fn yuyv_to_rgb(
    data: &[u8],
    width: u32,
    height: u32,
    stride: usize,
) -> Result<RgbImage, CameraError> {
    let yuyv = |d: String| CameraError::Decode {
        what: format!("YUYV {width}x{height}"),
        detail: d,
    };
    if width % 2 != 0 || width == 0 || height == 0 {
        return Err(yuyv("width must be even and the size non-zero".into()));
    }
    let row = width as usize * 2;
    if stride < row {
        return Err(yuyv(format!("row stride {stride} < {row}")));
    }
    let need = stride * (height as usize - 1) + row;
    if data.len() < need {
        return Err(yuyv(format!("{} bytes, need {need}", data.len())));
    }
    let mut img = RgbImage::new(width, height);
    let conv = |y: u8, u: u8, v: u8| {
        let c = 1.164 * (f32::from(y) - 16.0);
        let (d, e) = (f32::from(u) - 128.0, f32::from(v) - 128.0);
        let q = |x: f32| x.round().clamp(0.0, 255.0) as u8;
        image::Rgb([
            q(c + 1.596 * e),
            q(c - 0.392 * d - 0.813 * e),
            q(c + 2.017 * d),
        ])
    };
    for yy in 0..height {
        let line = &data[yy as usize * stride..yy as usize * stride + row];
        for (i, px) in line.chunks_exact(4).enumerate() {
            let x = 2 * i as u32;
            img.put_pixel(x, yy, conv(px[0], px[1], px[3]));
            img.put_pixel(x + 1, yy, conv(px[2], px[1], px[3]));
        }
    }
    Ok(img)
}
