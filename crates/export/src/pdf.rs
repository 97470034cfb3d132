//! PDF output of the paste-on sheets through `pdf-writer`: one page per image, the image
//! (RGB, Flate-compressed) covering its page at the paper's exact size, so printing the PDF at
//! 100 % reproduces the sheets' physical sizes.

use anyhow::Result;
use image::RgbImage;

/// A PDF with one page per image, each image covering its page at the paper's exact size.
pub(crate) fn pages_to_pdf(
    images: &[RgbImage],
    paper_mm: (f32, f32),
    title: &str,
) -> Result<Vec<u8>> {
    use pdf_writer::{Content, Filter, Finish, Name, Pdf, Rect, Ref, TextStr};
    use std::io::Write;
    let (wpt, hpt) = (paper_mm.0 / 25.4 * 72.0, paper_mm.1 / 25.4 * 72.0);
    let mut pdf = Pdf::new();
    let (catalog, tree, info) = (Ref::new(1), Ref::new(2), Ref::new(3));
    let page_ids: Vec<Ref> = (0..images.len())
        .map(|k| Ref::new(10 + 3 * k as i32))
        .collect();
    pdf.catalog(catalog).pages(tree);
    pdf.pages(tree)
        .kids(page_ids.iter().copied())
        .count(images.len() as i32);
    pdf.document_info(info)
        .title(TextStr(&format!("cac paste-on sheets: {title}")))
        .creator(TextStr("cac export"));
    for (k, img) in images.iter().enumerate() {
        let (page_id, img_id, content_id) = (
            page_ids[k],
            Ref::new(11 + 3 * k as i32),
            Ref::new(12 + 3 * k as i32),
        );
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(img.as_raw())?;
        let data = z.finish()?;
        let mut page = pdf.page(page_id);
        page.media_box(Rect::new(0.0, 0.0, wpt, hpt))
            .parent(tree)
            .contents(content_id);
        page.resources().x_objects().pair(Name(b"Im1"), img_id);
        page.finish();
        let mut x = pdf.image_xobject(img_id, &data);
        x.filter(Filter::FlateDecode);
        x.width(img.width() as i32)
            .height(img.height() as i32)
            .bits_per_component(8);
        x.color_space().device_rgb();
        x.finish();
        let mut c = Content::new();
        c.save_state()
            .transform([wpt, 0.0, 0.0, hpt, 0.0, 0.0])
            .x_object(Name(b"Im1"))
            .restore_state();
        pdf.stream(content_id, &c.finish());
    }
    Ok(pdf.finish())
}
