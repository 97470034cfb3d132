//! Report building blocks shared by every stage that shows results to a person: tables written as
//! Markdown and CSV from the same rows ([`table`]), plots drawn to images with `plotters`
//! ([`plot`]: xy lines with error bars, polar plots against azimuth), and a self-contained HTML
//! page with its images embedded ([`html`]), boxes and labels drawn into images ([`draw`]) with a
//! small bitmap font (`font`), and the benchmarks' one timer ([`timer`]). Nothing here writes
//! files; callers do, atomically
//! (`cac::io`).

pub mod draw;
pub mod font;
pub mod html;
pub mod plot;
pub mod table;
pub mod timer;

pub use html::Html;
pub use plot::{Plot, Series};
pub use table::Table;
