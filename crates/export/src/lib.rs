//! Fabrication: bakes a learned camouflage texture into files that printers and slicers accept.
//!
//! [`prepare`] turns a [`Scene`] plus the camouflage atlas into a [`PrintMesh`]: welded positions
//! in millimetres at the chosen scale (3MF frame: **+Z up**, X = the object's length, ground at
//! `z = 0`), per-corner paint (texture + UVs, or a solid colour) and a print-readiness report
//! ([`printcheck`]). When the check fails, [`export`] repairs it ([`repair`]: weld, dedupe, zip
//! T-junctions, fill small holes) or rebuilds it as one closed solid keeping its colours
//! ([`solidify`], on the BVH queries of [`surface`]), and checks printability at the chosen scale
//! ([`printability`]: wall thickness, sheets, floating and tiny parts, build volume). Writers then
//! produce:
//! - [`threemf`]: textured 3MF (`m:texture2d` + `m:texture2dgroup`), baked-colour 3MF
//!   (`m:colorgroup` per corner after [`bake`]'s adaptive subdivision) and, for a multi-material
//!   FDM printer profile, the painted 3MF that slicers open as a painted object ([`painted`]:
//!   the slicers' per-triangle painting trees, and the G-code's cost when sliced);
//! - [`obj`]: OBJ + MTL + PNG (optionally zipped) and a vertex-colour OBJ from the same bake;
//! - [`vrml`]: VRML 2.0 + PNG for full-colour print services (with a full-colour profile);
//! - [`sheets`]: paste-on sheets at true physical size (PNG pages, PDF, JSON sidecar).
//!
//! See `docs/export.md` for the conventions, tolerances and the bake's error/run-time table.

pub mod bake;
mod load;
mod mesh;
mod obj;
mod options;
pub mod painted;
mod pdf;
mod pipeline;
pub mod printability;
mod printable;
mod printcheck;
mod repair;
pub mod sheets;
mod solidify;
mod surface;
mod threemf;
mod vrml;

#[cfg(test)]
mod fixtures;

pub use bake::{BakeLimits, Baked};
pub use load::{load_mesh, load_texture, prepare};
pub use mesh::{Paint, PrintMesh, PrintReport, PrintTri, Scale};
pub use options::{ExportOptions, Format, RepairMode};
pub use pipeline::{export, ExportSummary, PRINTER_SIZE_TOLERANCE};
pub use printability::{PrintLimits, Printability, ThinPolicy};
pub use printcheck::weld_and_check;
pub use solidify::{fidelity, solidify, Fidelity, SolidifyOptions, SolidifyReport};
