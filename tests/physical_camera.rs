//! Camera sources without a camera: the folder source, MJPEG frames with and without Huffman
//! tables (as many webcams send them), YUYV conversion, and robustness on corrupt frames.

use cac::physical::camera::decode::{decode_mjpeg, standard_dht, with_huffman_tables, yuyv_to_rgb};
use cac::physical::{CameraError, FolderSource, FrameSource};
use image::{Rgb, RgbImage};
use std::borrow::Cow;

fn test_image(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        Rgb([
            (x * 7 % 256) as u8,
            (y * 5 % 256) as u8,
            ((x + y) * 3 % 256) as u8,
        ])
    })
}

fn jpeg(img: &RgbImage) -> Vec<u8> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 85)
        .encode_image(img)
        .unwrap();
    out
}

/// Remove every DHT segment before the first scan, as an MJPEG webcam sends its frames.
fn strip_dht(j: &[u8]) -> Vec<u8> {
    let mut out = j[..2].to_vec();
    let mut pos = 2;
    loop {
        assert_eq!(j[pos], 0xFF);
        let marker = j[pos + 1];
        if marker == 0xDA {
            out.extend_from_slice(&j[pos..]);
            return out;
        }
        let len = usize::from(u16::from_be_bytes([j[pos + 2], j[pos + 3]]));
        if marker != 0xC4 {
            out.extend_from_slice(&j[pos..pos + 2 + len]);
        }
        pos += 2 + len;
    }
}

#[test]
fn mjpeg_without_huffman_tables_decodes_like_the_original() {
    let img = test_image(64, 48);
    let full = jpeg(&img);
    let stripped = strip_dht(&full);
    assert!(stripped.len() < full.len() && !stripped.windows(2).any(|w| w == [0xFF, 0xC4]));
    assert!(matches!(
        with_huffman_tables(&full).unwrap(),
        Cow::Borrowed(_)
    ));
    let fixed = with_huffman_tables(&stripped).unwrap();
    assert!(matches!(fixed, Cow::Owned(_)));
    assert!(fixed
        .windows(standard_dht().len())
        .any(|w| w == standard_dht().as_slice()));
    let a = decode_mjpeg(&full).unwrap();
    let b = decode_mjpeg(&stripped).unwrap();
    assert_eq!(a.dimensions(), (64, 48));
    assert_eq!(
        a, b,
        "the inserted tables are the ones the encoder used (JPEG Annex K)"
    );
    // And close to the source pixels (lossy).
    let err: f64 = a
        .pixels()
        .zip(img.pixels())
        .map(|(p, q)| (f64::from(p[1]) - f64::from(q[1])).abs())
        .sum::<f64>()
        / f64::from(64 * 48);
    assert!(err < 12.0, "mean abs error {err}");
}

#[test]
fn corrupt_mjpeg_frames_are_errors_not_panics() {
    let full = jpeg(&test_image(32, 32));
    let stripped = strip_dht(&full);
    assert!(matches!(
        decode_mjpeg(b"not a jpeg"),
        Err(CameraError::Decode { .. })
    ));
    assert!(decode_mjpeg(&[]).is_err());
    assert!(decode_mjpeg(&[0xFF, 0xD8, 0xFF, 0xD9]).is_err());
    // Every truncation is refused (a decoder would grey-fill the rest), also with the zero
    // padding cameras leave after the data; the whole frame with padding decodes.
    for n in 0..stripped.len() {
        let mut cut = stripped[..n].to_vec();
        assert!(
            decode_mjpeg(&cut).is_err(),
            "cut at {n} of {}",
            stripped.len()
        );
        cut.resize(n + 64, 0);
        assert!(decode_mjpeg(&cut).is_err(), "cut at {n}, padded");
    }
    let mut padded = stripped.clone();
    padded.resize(stripped.len() + 100, 0);
    assert_eq!(
        decode_mjpeg(&padded).unwrap(),
        decode_mjpeg(&stripped).unwrap()
    );
    // A sweep of single-byte corruptions: errors or images, never a panic.
    let mut seed = 0x1234_5678u32;
    for i in 0..2000 {
        let mut f = stripped.clone();
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let at = (seed as usize >> 8) % f.len();
        f[at] = (seed >> 24) as u8 ^ (i as u8 | 1);
        let _ = decode_mjpeg(&f);
    }
}

#[test]
fn yuyv_conversion() {
    // Two rows of 4 pixels, rows padded to 12 bytes: black/white pair, then BT.601 red and blue.
    let mut data = vec![0u8; 12 * 2];
    data[..8].copy_from_slice(&[16, 128, 235, 128, 16, 128, 235, 128]);
    data[12..20].copy_from_slice(&[81, 90, 81, 240, 41, 240, 41, 110]);
    let img = yuyv_to_rgb(&data, 4, 2, 12).unwrap();
    assert_eq!(img.get_pixel(0, 0), &Rgb([0, 0, 0]));
    assert_eq!(img.get_pixel(1, 0), &Rgb([255, 255, 255]));
    let red = img.get_pixel(0, 1);
    assert!(red[0] >= 250 && red[1] <= 5 && red[2] <= 5, "{red:?}");
    let blue = img.get_pixel(2, 1);
    assert!(blue[2] >= 250 && blue[0] <= 5 && blue[1] <= 5, "{blue:?}");
    assert!(matches!(
        yuyv_to_rgb(&data, 4, 3, 12),
        Err(CameraError::Decode { .. })
    ));
    assert!(yuyv_to_rgb(&data, 3, 2, 12).is_err());
    assert!(yuyv_to_rgb(&data, 4, 2, 6).is_err());
}

#[test]
fn folder_source_in_name_order_then_exhausted_or_looping() {
    let dir = tempfile::tempdir().unwrap();
    for (name, shade) in [
        ("frame_002.png", 20u8),
        ("frame_000.png", 0),
        ("frame_001.jpg", 10),
    ] {
        let img = RgbImage::from_pixel(8, 6, Rgb([shade, shade, shade]));
        img.save(dir.path().join(name)).unwrap();
    }
    std::fs::write(dir.path().join("notes.txt"), "not an image").unwrap();
    let mut src = FolderSource::open(dir.path(), false).unwrap();
    assert_eq!(src.len(), 3);
    assert!(src.describe().contains("3 images"));
    let frames: Vec<_> = (0..3).map(|_| src.capture().unwrap()).collect();
    assert!(
        frames[0].origin.ends_with("frame_000.png") && frames[2].origin.ends_with("frame_002.png")
    );
    assert_eq!(frames[1].index, 1);
    assert_eq!(frames[2].image.dimensions(), (8, 6));
    assert!((i32::from(frames[1].image.get_pixel(0, 0)[0]) - 10).abs() <= 3);
    assert!(matches!(src.capture(), Err(CameraError::Exhausted(_))));
    let mut looping = FolderSource::open(dir.path(), true).unwrap();
    let names: Vec<_> = (0..5).map(|_| looping.capture().unwrap().origin).collect();
    assert_eq!(names[0], names[3]);
    assert_eq!(names[1], names[4]);
}

#[test]
fn folder_source_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let e = FolderSource::open(dir.path(), false).unwrap_err();
    assert!(e.to_string().contains("no .png/.jpg images"), "{e}");
    assert!(FolderSource::open(&dir.path().join("missing"), false).is_err());
    std::fs::write(dir.path().join("broken.png"), b"\x89PNG\r\n\x1a\nnope").unwrap();
    let mut src = FolderSource::open(dir.path(), false).unwrap();
    let e = src.capture().unwrap_err();
    assert!(
        matches!(e, CameraError::Decode { .. }) && e.to_string().contains("broken.png"),
        "{e}"
    );
}
