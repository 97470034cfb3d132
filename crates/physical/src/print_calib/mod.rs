//! Calibrating a printer from a photograph of a printed chart (`cac print chart`, `cac print
//! calibrate`; docs/physical.md, "Calibrating a printer").
//!
//! 1. [`chart`]: the chart to print — an A4 page with a fiducial marker at each corner, N colour
//!    patches spread over the sRGB cube (seeded, stratified; the cube's corners and greys among
//!    them) and the squares of a ColorChecker Classic (24) where a real card is laid; `chart.png`
//!    and `chart.json` (docs/formats.md, "Print chart"). For multi-material FDM the chart has a
//!    labelled square per filament instead, where a printed swatch of it is laid.
//! 2. [`detect`]: finds the four markers in the photograph (three nested squares each, told from
//!    everything else by their nesting), the homography of the page (through the lens's
//!    distortion when its calibration is given) and the trimmed mean of each patch's interior.
//! 3. [`fit`]: corrects the camera with the ColorChecker (a per-channel tone curve from its grey
//!    row, then a 3×3 matrix in linear light, fitted to its published values) and fits the
//!    printer's response (`cac_core::printer::Response`, the 3×6 root-polynomial, weighted least
//!    squares in linear light) on the printed patches less a seeded held-out share.
//! 4. [`calibrate`]: the whole run and its refusals (no markers, clipped patches, a chart of
//!    another printer kind, a photo too small, a photo of another chart); writes the profile.
//! 5. [`simulate`]: a simulated printer and the digital twin photographing the printed chart
//!    (tests, and `cac bench calibration` in `cac-bench`).

pub mod calibrate;
pub mod chart;
pub mod detect;
pub mod fit;
mod linalg;
pub mod simulate;

pub use calibrate::{calibrate, calibrate_files, CalibrateOptions, Calibration};
pub use chart::{Chart, ChartSpec, Patch, PrinterKind, Role};
pub use simulate::{photograph, Shot, SimulatedPrinter};
