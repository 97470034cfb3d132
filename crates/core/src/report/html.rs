//! A self-contained HTML page: headings, paragraphs, preformatted blocks, tables and images
//! embedded as base64 PNG data URIs, with a small inline style sheet. One string, one file, no
//! external resources.

use super::Table;
use anyhow::{Context, Result};

/// Escapes `&`, `<`, `>` and `"` for HTML text and attribute values.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o += "&amp;",
            '<' => o += "&lt;",
            '>' => o += "&gt;",
            '"' => o += "&quot;",
            c => o.push(c),
        }
    }
    o
}

/// Standard base64 with padding.
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut o = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for ch in bytes.chunks(3) {
        let n = (ch[0] as u32) << 16
            | (*ch.get(1).unwrap_or(&0) as u32) << 8
            | *ch.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= ch.len() {
                o.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                o.push('=');
            }
        }
    }
    o
}

/// A PNG data URI of `img`.
pub(crate) fn png_data_uri(img: &image::RgbImage) -> Result<String> {
    let mut buf = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut buf), image::ImageFormat::Png)
        .context("cannot encode an image for the HTML report")?;
    Ok(format!("data:image/png;base64,{}", base64(&buf)))
}

/// A JPEG data URI of `img` (quality 1–100): for photographs and renders, far smaller than PNG.
pub(crate) fn jpeg_data_uri(img: &image::RgbImage, quality: u8) -> Result<String> {
    let mut buf = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, quality.clamp(1, 100))
        .encode_image(img)
        .context("cannot encode an image for the HTML report")?;
    Ok(format!("data:image/jpeg;base64,{}", base64(&buf)))
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;\
color:#222}table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #bbb;\
padding:3px 8px;text-align:right}th{background:#eee}td:first-child{text-align:left}\
pre{background:#f6f6f6;padding:1em;overflow:auto}figure{display:inline-block;margin:4px;\
vertical-align:top}figcaption{font-size:small;text-align:center;max-width:100%}img{max-width:100%}";

/// Builds one self-contained page. Methods append in order; [`Html::finish`] returns the page.
#[derive(Clone, Debug)]
pub struct Html {
    title: String,
    body: String,
}

impl Html {
    /// A page whose `<title>` and first heading are `title`.
    pub fn new(title: &str) -> Self {
        Html {
            title: title.to_string(),
            body: format!("<h1>{}</h1>\n", escape(title)),
        }
    }

    /// A heading, level 2..=6 (level 1 is the title).
    pub fn heading(&mut self, level: u8, text: &str) -> &mut Self {
        let l = level.clamp(2, 6);
        self.body += &format!("<h{l}>{}</h{l}>\n", escape(text));
        self
    }

    /// A paragraph of plain text.
    pub fn paragraph(&mut self, text: &str) -> &mut Self {
        self.body += &format!("<p>{}</p>\n", escape(text));
        self
    }

    /// A preformatted block (the protocol statement, a command line).
    pub fn pre(&mut self, text: &str) -> &mut Self {
        self.body += &format!("<pre>{}</pre>\n", escape(text));
        self
    }

    /// A table (see [`Table::html`]).
    pub fn table(&mut self, t: &Table) -> &mut Self {
        self.body += &t.html();
        self
    }

    /// Images side by side, each a captioned figure embedded as PNG (lossless: plots), displayed
    /// at most `width` CSS pixels wide (0 = natural size).
    pub fn figures(
        &mut self,
        images: &[(&image::RgbImage, &str)],
        width: u32,
    ) -> Result<&mut Self> {
        self.embed(images, width, None)
    }

    /// Like [`Html::figures`] but embedded as JPEG at quality 85 (renders, camera frames).
    pub fn photos(&mut self, images: &[(&image::RgbImage, &str)], width: u32) -> Result<&mut Self> {
        self.embed(images, width, Some(85))
    }

    fn embed(
        &mut self,
        images: &[(&image::RgbImage, &str)],
        width: u32,
        jpeg: Option<u8>,
    ) -> Result<&mut Self> {
        self.body += "<div>\n";
        for (img, cap) in images {
            let style = if width > 0 {
                format!(" style=\"width:{width}px\"")
            } else {
                String::new()
            };
            self.body += &format!(
                "<figure{style}><img src=\"{}\" alt=\"{c}\"><figcaption>{c}</figcaption></figure>\n",
                match jpeg {
                    Some(q) => jpeg_data_uri(img, q)?,
                    None => png_data_uri(img)?,
                },
                c = escape(cap)
            );
        }
        self.body += "</div>\n";
        Ok(self)
    }

    /// One captioned image at its natural size.
    pub fn image(&mut self, img: &image::RgbImage, caption: &str) -> Result<&mut Self> {
        self.figures(&[(img, caption)], 0)
    }

    /// The finished page.
    pub fn finish(&self) -> String {
        format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n\
             <style>{STYLE}</style>\n</head>\n<body>\n{}</body>\n</html>\n",
            escape(&self.title),
            self.body
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode64(s: &str) -> Vec<u8> {
        let v = |c: u8| {
            (match c {
                b'A'..=b'Z' => c - b'A',
                b'a'..=b'z' => c - b'a' + 26,
                b'0'..=b'9' => c - b'0' + 52,
                b'+' => 62,
                _ => 63,
            }) as u32
        };
        let mut out = Vec::new();
        for ch in s.as_bytes().chunks(4) {
            let pad = ch.iter().filter(|&&c| c == b'=').count();
            let n = ch
                .iter()
                .fold(0u32, |n, &c| n << 6 | if c == b'=' { 0 } else { v(c) });
            out.extend_from_slice(&n.to_be_bytes()[1..4 - pad]);
        }
        out
    }

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn page_embeds_images_that_decode_back() {
        let img =
            image::RgbImage::from_fn(5, 3, |x, y| image::Rgb([x as u8 * 40, y as u8 * 80, 7]));
        let mut h = Html::new("A <report>");
        h.paragraph("x & y").pre("P@0.5").table(&Table::new(["a"]));
        h.image(&img, "view 1").unwrap();
        let page = h.finish();
        assert!(page.contains("<title>A &lt;report&gt;</title>"));
        assert!(page.contains("<p>x &amp; y</p>"));
        assert!(!page.contains("src=\"http"), "self-contained");
        let b64 = page
            .split("data:image/png;base64,")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap();
        let png = decode64(b64);
        let back = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(back, img, "the embedded PNG decodes to the same pixels");
        let big = image::RgbImage::from_fn(64, 64, |x, y| {
            image::Rgb([(x * 4) as u8, (y * 4) as u8, 90])
        });
        let mut j = Html::new("j");
        j.photos(&[(&big, "a")], 100).unwrap();
        let page = j.finish();
        let b64 = page
            .split("data:image/jpeg;base64,")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap();
        let back = image::load_from_memory(&decode64(b64)).unwrap().to_rgb8();
        assert_eq!(back.dimensions(), (64, 64));
        assert!(page.contains("style=\"width:100px\""));
    }
}
