//! What `cac export` is asked for: the scale, the formats, the repair mode and the rest of
//! [`ExportOptions`] with their defaults.

use crate::bake::BakeLimits;
use crate::mesh::Scale;
use crate::printability::PrintLimits;
use crate::sheets;
use anyhow::{bail, Result};
use cac_core::memory::MemoryBudget;
use cac_core::printer::Profile;
use cac_scene::LoadOptions;
use serde::Serialize;
use std::str::FromStr;

/// An output format of `cac export`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
pub enum Format {
    /// `<name>_texture.3mf`: Materials extension texture.
    ThreeMfTexture,
    /// `<name>_color.3mf`: baked per-corner colours.
    ThreeMfColor,
    /// `<name>.obj` + `.mtl` + PNGs (and `<name>_obj.zip` when zipping).
    Obj,
    /// `<name>_vc.obj`: baked vertex colours.
    ObjVc,
    /// `sheets/`: paste-on pages (PNG, PDF, JSON).
    Sheets,
    /// `<name>_painted.3mf`: multi-material painting for slicers (needs an FDM printer profile).
    ThreeMfPainted,
    /// `<name>.wrl` + PNGs: VRML 2.0 for full-colour print services (added with a full-colour
    /// printer profile).
    Vrml,
}

impl FromStr for Format {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Format> {
        let s = s.trim();
        if s == "3mf-colour" {
            return Ok(Format::ThreeMfColor);
        }
        let all = Format::ALL
            .into_iter()
            .chain([Format::ThreeMfPainted, Format::Vrml]);
        Ok(match all.into_iter().find(|f| f.name() == s) {
            Some(f) => f,
            None => bail!(
                "unknown export format '{s}' (expected 3mf-texture, 3mf-color, obj, obj-vc, sheets, 3mf-painted, wrl)"
            ),
        })
    }
}

impl Format {
    /// The formats written without a printer profile (the default; `3mf-painted` needs one).
    pub const ALL: [Format; 5] = [
        Format::ThreeMfTexture,
        Format::ThreeMfColor,
        Format::Obj,
        Format::ObjVc,
        Format::Sheets,
    ];
    /// The name `--formats` takes.
    pub fn name(&self) -> &'static str {
        match self {
            Format::ThreeMfTexture => "3mf-texture",
            Format::ThreeMfColor => "3mf-color",
            Format::Obj => "obj",
            Format::ObjVc => "obj-vc",
            Format::Sheets => "sheets",
            Format::ThreeMfPainted => "3mf-painted",
            Format::Vrml => "wrl",
        }
    }

    /// The stage that writes it, as the memory guard names it.
    pub fn stage(&self) -> &'static str {
        match self {
            Format::ThreeMfTexture => "textured 3MF",
            Format::ThreeMfColor => "colour 3MF",
            Format::Obj => "textured OBJ",
            Format::ObjVc => "vertex-colour OBJ",
            Format::Sheets => "paste-on sheets",
            Format::ThreeMfPainted => "painted 3MF",
            Format::Vrml => "VRML",
        }
    }

    /// Does this format carry printable geometry (and so need a closed mesh)?
    pub(crate) fn is_geometry(&self) -> bool {
        !matches!(self, Format::Sheets)
    }
}

/// How `cac export` repairs a mesh that fails the print check (`--repair`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum RepairMode {
    /// Light repair when the check fails, then solidify what it cannot fix (the default).
    Auto,
    /// Light repair only; refuse what it cannot fix.
    Light,
    /// Always rebuild the solid (unites overlapping parts even when the check passes).
    Solid,
    /// No repair: refuse a failing mesh (or write it with `--allow-open`).
    Off,
}

impl FromStr for RepairMode {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        Ok(match s {
            "auto" => RepairMode::Auto,
            "light" => RepairMode::Light,
            "solid" | "solidify" => RepairMode::Solid,
            "off" | "none" => RepairMode::Off,
            o => bail!("unknown --repair '{o}' (expected auto, light, solid or off)"),
        })
    }
}

/// Everything `cac export` needs besides the input files.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    pub formats: Vec<Format>,
    pub scale: Scale,
    pub bake: BakeLimits,
    pub sheets: sheets::SheetOptions,
    /// Also bundle the OBJ, MTL and PNGs into `<name>_obj.zip`.
    pub zip_obj: bool,
    /// Write geometry even when the mesh is open or non-manifold (a warning instead of an error).
    pub allow_open: bool,
    pub load: LoadOptions,
    pub repair: RepairMode,
    /// Minimum wall and feature, build volume, and what to do with thin regions.
    pub limits: PrintLimits,
    /// Solidify grid spacing in mm at print scale (`None`: [`auto_voxel`]).
    pub voxel_mm: Option<f32>,
    /// Light repair fills holes up to this perimeter, mm at print scale.
    pub max_hole_mm: f32,
    /// The memory budget (default: the process's, [`MemoryBudget::current`]): the texture, the
    /// solid, the bake and the paste-on sheets are estimated against it first.
    pub memory: MemoryBudget,
    /// Told the name of each stage as it starts (the CLI prints it; default: nothing).
    pub progress: fn(&str),
    /// The printer the object is made on (`--printer`). A multi-material FDM profile makes the
    /// 3MF the painted one (`3mf-texture` / `3mf-color` become `3mf-painted`) and its
    /// `object_size_mm` must match the scale; other profiles are refused with a 3MF format.
    pub printer: Option<Profile>,
    /// Slice the painted 3MF with PrusaSlicer's command line and report what the print costs
    /// (`--slice`).
    pub slice: bool,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            formats: Format::ALL.to_vec(),
            scale: Scale { denominator: 1.0 },
            bake: BakeLimits::default(),
            sheets: sheets::SheetOptions::default(),
            zip_obj: false,
            allow_open: false,
            load: LoadOptions::default(),
            repair: RepairMode::Auto,
            limits: PrintLimits::default(),
            voxel_mm: None,
            max_hole_mm: 20.0,
            memory: MemoryBudget::current(),
            progress: |_| {},
            printer: None,
            slice: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_parses_and_refuses_zero() {
        assert_eq!("1:24".parse::<Scale>().unwrap().denominator, 24.0);
        assert_eq!("35".parse::<Scale>().unwrap().denominator, 35.0);
        for bad in ["1:0", "0:5", "1:-3", "1:x", "1:inf"] {
            let e = format!("{:#}", bad.parse::<Scale>().unwrap_err());
            assert!(e.contains(bad), "{e}");
        }
    }

    #[test]
    fn formats_parse() {
        assert_eq!("3mf-color".parse::<Format>().unwrap(), Format::ThreeMfColor);
        assert!("stl".parse::<Format>().is_err());
    }
}
