//! PDF output of the paste-on sheets, streamed: each page image is written to the file as soon
//! as it is drawn and then freed, so a layout of hundreds of pages holds one page at a time. The
//! image data is the page PNG's own compressed data (Flate with PNG row predictors, which PDF
//! reads as they are), so nothing is compressed twice. Each image covers its page at the
//! paper's exact size, so printing the PDF at 100 % reproduces the sheets' physical sizes.
//!
//! Objects: 1 catalog, 2 page tree, 3 document info, then per page `k` the page (`4 + 3k`), its
//! image (`5 + 3k`) and its content stream (`6 + 3k`); the page tree is written last (it lists
//! the pages' numbers, known from the start), then the cross-reference table.

use anyhow::{ensure, Result};
use std::io::Write;

/// A PDF being written page by page into `w`.
pub(crate) struct PdfStream<'w, W: Write> {
    w: &'w mut W,
    /// Bytes written so far (the next object's offset).
    pos: u64,
    /// Byte offset of each object, by number (index 0: the free head).
    offsets: Vec<u64>,
    pages: usize,
    written: usize,
}

/// Object numbers of page `k`: the page, its image and its content stream.
fn page_ids(k: usize) -> (usize, usize, usize) {
    (4 + 3 * k, 5 + 3 * k, 6 + 3 * k)
}

impl<'w, W: Write> PdfStream<'w, W> {
    /// Writes the header, catalog and document info of a PDF of `pages` pages.
    pub(crate) fn start(w: &'w mut W, title: &str, pages: usize) -> Result<Self> {
        let mut s = PdfStream {
            w,
            pos: 0,
            offsets: vec![0; 4 + 3 * pages],
            pages,
            written: 0,
        };
        s.raw(b"%PDF-1.7\n%\xE2\xE3\xCF\xD3\n")?;
        s.object(1, b"<< /Type /Catalog /Pages 2 0 R >>")?;
        let info = format!(
            "<< /Title {} /Creator {} >>",
            text_string(title),
            text_string("cac export")
        );
        s.object(3, info.as_bytes())?;
        Ok(s)
    }

    /// Appends the next page: the 8-bit RGB PNG `png` covering a page of `paper_mm`.
    pub(crate) fn page(&mut self, png: &[u8], paper_mm: (f32, f32)) -> Result<()> {
        ensure!(self.written < self.pages, "more PDF pages than announced");
        let (width, height, data) = png_rgb8_data(png)?;
        let (wpt, hpt) = (paper_mm.0 / 25.4 * 72.0, paper_mm.1 / 25.4 * 72.0);
        let (page, image, content) = page_ids(self.written);
        let dict = format!(
            "<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {wpt:.3} {hpt:.3}] /Resources << \
             /XObject << /Im1 {image} 0 R >> >> /Contents {content} 0 R >>"
        );
        self.object(page, dict.as_bytes())?;
        let head = format!(
            "<< /Type /XObject /Subtype /Image /Width {width} /Height {height} /ColorSpace \
             /DeviceRGB /BitsPerComponent 8 /Filter /FlateDecode /DecodeParms << /Predictor 15 \
             /Colors 3 /BitsPerComponent 8 /Columns {width} >> /Length {} >>",
            data.len()
        );
        self.stream(image, &head, &data)?;
        drop(data);
        let draw = format!("q {wpt:.3} 0 0 {hpt:.3} 0 0 cm /Im1 Do Q");
        let head = format!("<< /Length {} >>", draw.len());
        self.stream(content, &head, draw.as_bytes())?;
        self.written += 1;
        Ok(())
    }

    /// Writes the page tree, the cross-reference table and the trailer.
    pub(crate) fn finish(mut self) -> Result<()> {
        ensure!(
            self.written == self.pages,
            "{} PDF pages written of {} announced",
            self.written,
            self.pages
        );
        let kids: Vec<String> = (0..self.pages)
            .map(|k| format!("{} 0 R", page_ids(k).0))
            .collect();
        let tree = format!(
            "<< /Type /Pages /Kids [{}] /Count {} >>",
            kids.join(" "),
            self.pages
        );
        self.object(2, tree.as_bytes())?;
        let xref = self.pos;
        let mut t = format!("xref\n0 {}\n0000000000 65535 f\r\n", self.offsets.len());
        for &o in &self.offsets[1..] {
            t.push_str(&format!("{o:010} 00000 n\r\n"));
        }
        t.push_str(&format!(
            "trailer\n<< /Size {} /Root 1 0 R /Info 3 0 R >>\nstartxref\n{xref}\n%%EOF\n",
            self.offsets.len()
        ));
        self.raw(t.as_bytes())
    }

    fn raw(&mut self, b: &[u8]) -> Result<()> {
        self.w.write_all(b)?;
        self.pos += b.len() as u64;
        Ok(())
    }

    fn object(&mut self, id: usize, dict: &[u8]) -> Result<()> {
        self.offsets[id] = self.pos;
        self.raw(format!("{id} 0 obj\n").as_bytes())?;
        self.raw(dict)?;
        self.raw(b"\nendobj\n")
    }

    fn stream(&mut self, id: usize, head: &str, data: &[u8]) -> Result<()> {
        self.offsets[id] = self.pos;
        self.raw(format!("{id} 0 obj\n{head}\nstream\n").as_bytes())?;
        self.raw(data)?;
        self.raw(b"\nendstream\nendobj\n")
    }
}

/// The width, height and compressed image data (the IDAT chunks joined: a zlib stream of
/// PNG-filtered rows) of a non-interlaced 8-bit RGB PNG.
fn png_rgb8_data(png: &[u8]) -> Result<(u32, u32, Vec<u8>)> {
    ensure!(
        png.starts_with(b"\x89PNG\r\n\x1a\n"),
        "a sheet page is not a PNG"
    );
    let (mut at, mut size, mut data) = (8, None, Vec::new());
    while at + 8 <= png.len() {
        let len = u32::from_be_bytes(png[at..at + 4].try_into()?) as usize;
        let kind = &png[at + 4..at + 8];
        let body = png
            .get(at + 8..at + 8 + len)
            .ok_or_else(|| anyhow::anyhow!("a sheet page's PNG is truncated"))?;
        match kind {
            b"IHDR" => {
                let be = |i: usize| u32::from_be_bytes(body[i..i + 4].try_into().unwrap());
                ensure!(
                    len == 13 && body[8..] == [8, 2, 0, 0, 0],
                    "a sheet page's PNG is not 8-bit RGB without interlacing"
                );
                size = Some((be(0), be(4)));
            }
            b"IDAT" => data.extend_from_slice(body),
            b"IEND" => break,
            _ => {}
        }
        at += 12 + len;
    }
    let (w, h) = size.ok_or_else(|| anyhow::anyhow!("a sheet page's PNG has no header"))?;
    Ok((w, h, data))
}

/// A PDF text string in UTF-16BE with its byte-order mark, as hex (any title, no escaping).
fn text_string(s: &str) -> String {
    let mut out = String::from("<FEFF");
    for u in s.encode_utf16() {
        out.push_str(&format!("{u:04X}"));
    }
    out.push('>');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cross_reference_table_points_at_every_object() {
        let mut buf = Vec::new();
        let img = image::RgbImage::from_pixel(8, 12, image::Rgb([10, 200, 30]));
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let (w, h, data) = png_rgb8_data(&png).unwrap();
        assert_eq!((w, h), (8, 12));
        // The IDAT data is a zlib stream of 12 rows of a filter byte and 8 RGB pixels.
        let mut rows = vec![];
        std::io::Read::read_to_end(&mut flate2::read::ZlibDecoder::new(&data[..]), &mut rows)
            .unwrap();
        assert_eq!(rows.len(), 12 * (1 + 8 * 3));
        let mut pdf = PdfStream::start(&mut buf, "t (1)", 2).unwrap();
        pdf.page(&png, (210.0, 297.0)).unwrap();
        pdf.page(&png, (210.0, 297.0)).unwrap();
        pdf.finish().unwrap();
        let text = String::from_utf8_lossy(&buf);
        let start: usize = text
            .rsplit("startxref\n")
            .next()
            .unwrap()
            .lines()
            .next()
            .unwrap()
            .parse()
            .unwrap();
        // Offsets count bytes (the lossy text above differs where the image data is binary).
        let table = String::from_utf8_lossy(&buf[start..]).to_string();
        assert!(table.starts_with("xref\n0 10\n"), "{table}");
        let entries: Vec<&str> = table.lines().skip(3).take(9).collect();
        for (i, e) in entries.iter().enumerate() {
            let off: usize = e[..10].parse().unwrap();
            let want = format!("{} 0 obj", i + 1);
            assert!(buf[off..].starts_with(want.as_bytes()), "object {}", i + 1);
        }
        assert!(text.contains("/Kids [4 0 R 7 0 R] /Count 2"));
        assert!(text.contains("/MediaBox [0 0 595.276 841.890]"));
    }

    #[test]
    fn a_page_count_other_than_announced_is_an_error() {
        let mut buf = Vec::new();
        let pdf = PdfStream::start(&mut buf, "t", 1).unwrap();
        assert!(pdf.finish().is_err());
    }
}
