//! Printer models: what a printer makes of a requested colour. A profile (TOML, docs/formats.md
//! "Printer profile") is one of
//! - **multi-material FDM** ([`Fdm`]): K filaments with their measured colours; the printer makes
//!   exactly those colours, so a texture is printable when every texel is one of them;
//! - **full-colour** (binder-jet, PolyJet, colour MJF): a fitted [`Response`] from requested to
//!   printed-and-photographed colour; what it can make (its gamut) is the response's image of the
//!   sRGB cube;
//! - **paper / vinyl** (sheets, wraps): the same fitted response, with the media width.
//!
//! [`Printer::as_printed`] is the one function every stage judges with: training renders it,
//! evaluation scores it, export writes it.

use crate::colour;
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Most filaments a multi-material profile may name (the slicers' painting encodes 16 states).
pub const MAX_FILAMENTS: usize = 16;

/// A printer profile as read from its file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    /// What the profile describes, for reports.
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fdm: Option<Fdm>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub full_colour: Option<FullColour>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub paper: Option<Paper>,
}

/// A multi-material FDM printer and the filaments loaded in it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Fdm {
    pub filaments: Vec<Filament>,
    /// Nozzle width, mm: the smallest colour region the printer draws.
    pub nozzle_mm: f32,
    /// Layer height, mm.
    pub layer_mm: f32,
    /// The object's longest side as it will be printed, mm (the export's `--scale` must match):
    /// with the nozzle it sets the smallest colour region on the texture.
    pub object_size_mm: f32,
}

/// One filament: its name and its colour as measured (sRGB display value).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Filament {
    pub name: String,
    /// `#RRGGBB`.
    pub srgb: String,
    /// Where the colour comes from (a measurement, a vendor's published value).
    #[serde(default)]
    pub source: String,
}

/// A full-colour printer: its fitted response.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FullColour {
    pub response: Response,
}

/// Paper or vinyl: the fitted response and the media.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Paper {
    pub response: Response,
    /// Printable width of the media (the roll or the sheet), mm.
    pub media_width_mm: f32,
}

/// Requested → printed colour: a per-channel tone curve, then the degree-2 root-polynomial of
/// Finlayson, Mackiewicz & Hurlbert (2015) in linear light: with `c' = c^γ_c` for each linear
/// channel `c`, `printed = M · [r', g', b', √(r'g'), √(g'b'), √(r'b')]`, clipped to 0..1. The
/// polynomial's terms are of degree one, so alone it cannot bend the grey axis; the curve is
/// what follows a printer's dot gain.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Response {
    /// Per-channel exponent of the tone curve on the requested linear colour (1: none).
    #[serde(default = "unit_gamma", skip_serializing_if = "is_unit_gamma")]
    pub gamma: [f32; 3],
    /// Rows: printed linear R, G, B; columns: the six terms.
    pub matrix: [[f32; 6]; 3],
    /// How the fit was judged: mean and 95th-percentile ΔE2000 on patches held out of it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out_de2000: Option<[f32; 2]>,
}

/// A loaded printer model, ready to apply.
#[derive(Clone, Debug, PartialEq)]
pub enum Printer {
    /// The filaments' sRGB colours and the printer's geometry.
    Fdm {
        palette: Vec<[f32; 3]>,
        palette_lab: Vec<[f32; 3]>,
        fdm: Fdm,
    },
    /// A fitted response (full-colour or paper).
    Response(Response),
}

impl Response {
    /// The identity response (a printer that makes what it is asked).
    pub fn identity() -> Self {
        let mut m = [[0.0; 6]; 3];
        (0..3).for_each(|i| m[i][i] = 1.0);
        Response {
            gamma: [1.0; 3],
            matrix: m,
            held_out_de2000: None,
        }
    }

    /// The six terms of a linear-light colour after the tone curves `gamma`.
    pub fn terms(lin: [f32; 3], gamma: [f32; 3]) -> [f32; 6] {
        let [r, g, b] = std::array::from_fn(|i| lin[i].max(0.0).powf(gamma[i]));
        [r, g, b, (r * g).sqrt(), (g * b).sqrt(), (r * b).sqrt()]
    }

    /// The printed sRGB colour of a requested sRGB colour.
    pub fn apply(&self, srgb: [f32; 3]) -> [f32; 3] {
        let t = Self::terms(srgb.map(|v| colour::decode(v.clamp(0.0, 1.0))), self.gamma);
        let row = |m: &[f32; 6]| m.iter().zip(&t).map(|(a, b)| a * b).sum::<f32>();
        self.matrix.map(|m| colour::encode(row(&m).clamp(0.0, 1.0)))
    }
}

impl Profile {
    /// Reads and checks a profile; errors name the file and what is wrong.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading printer profile {}", path.display()))?;
        let p: Profile =
            toml::from_str(&text).with_context(|| format!("printer profile {}", path.display()))?;
        p.printer()
            .with_context(|| format!("printer profile {}", path.display()))?;
        Ok(p)
    }

    /// The profile as TOML.
    pub fn to_toml(&self) -> Result<String> {
        Ok(toml::to_string_pretty(self)?)
    }

    /// The printer model the profile describes (exactly one of `[fdm]`, `[full_colour]`,
    /// `[paper]`), checked.
    pub fn printer(&self) -> Result<Printer> {
        match (&self.fdm, &self.full_colour, &self.paper) {
            (Some(f), None, None) => f.printer(),
            (None, Some(c), None) => checked(&c.response).map(Printer::Response),
            (None, None, Some(p)) => {
                if !(p.media_width_mm > 0.0) {
                    bail!(
                        "[paper] media_width_mm must be positive, not {}",
                        p.media_width_mm
                    );
                }
                checked(&p.response).map(Printer::Response)
            }
            _ => bail!("a printer profile has exactly one of [fdm], [full_colour] or [paper]"),
        }
    }

    /// `fdm`, `full-colour` or `paper`.
    pub fn kind(&self) -> &'static str {
        match (&self.fdm, &self.full_colour) {
            (Some(_), _) => "fdm",
            (None, Some(_)) => "full-colour",
            _ => "paper",
        }
    }
}

fn unit_gamma() -> [f32; 3] {
    [1.0; 3]
}

fn is_unit_gamma(g: &[f32; 3]) -> bool {
    *g == [1.0; 3]
}

fn checked(r: &Response) -> Result<Response> {
    if r.matrix.iter().flatten().any(|v| !v.is_finite()) {
        bail!("the response matrix has a value that is not finite");
    }
    if r.gamma.iter().any(|g| !(0.1..=10.0).contains(g)) {
        bail!("the response's gamma {:?} is outside 0.1..10", r.gamma);
    }
    Ok(r.clone())
}

impl Fdm {
    fn printer(&self) -> Result<Printer> {
        let k = self.filaments.len();
        if !(2..=MAX_FILAMENTS).contains(&k) {
            bail!("[fdm] names {k} filaments; a multi-material profile has 2 to {MAX_FILAMENTS}");
        }
        for (what, v) in [
            ("nozzle_mm", self.nozzle_mm),
            ("layer_mm", self.layer_mm),
            ("object_size_mm", self.object_size_mm),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                bail!("[fdm] {what} must be a positive number of mm, not {v}");
            }
        }
        let mut palette = Vec::with_capacity(k);
        for (i, f) in self.filaments.iter().enumerate() {
            let c = colour::from_hex(&f.srgb).with_context(|| {
                format!(
                    "filament {} ({:?}): srgb {:?} is not #RRGGBB",
                    i + 1,
                    f.name,
                    f.srgb
                )
            })?;
            palette.push(c);
        }
        Ok(Printer::Fdm {
            palette_lab: palette.iter().map(|&c| colour::srgb_to_lab(c)).collect(),
            palette,
            fdm: self.clone(),
        })
    }
}

impl Printer {
    /// What the printer makes of a requested sRGB colour: the nearest filament (ΔE2000) on an
    /// FDM printer, the response on the others.
    pub fn as_printed(&self, srgb: [f32; 3]) -> [f32; 3] {
        match self {
            Printer::Fdm { palette, .. } => palette[self.nearest(srgb)],
            Printer::Response(r) => r.apply(srgb),
        }
    }

    /// The filament nearest a requested colour by ΔE2000 (0 for a response printer).
    pub fn nearest(&self, srgb: [f32; 3]) -> usize {
        let Printer::Fdm { palette_lab, .. } = self else {
            return 0;
        };
        let lab = colour::srgb_to_lab(srgb);
        let d = |i: usize| colour::delta_e2000(lab, palette_lab[i]);
        (0..palette_lab.len())
            .min_by(|&a, &b| d(a).total_cmp(&d(b)))
            .unwrap_or(0)
    }

    /// The filaments' sRGB colours (empty for a response printer).
    pub fn palette(&self) -> &[[f32; 3]] {
        match self {
            Printer::Fdm { palette, .. } => palette,
            Printer::Response(_) => &[],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FOUR: &str = r##"
name = "four PLA"
[fdm]
nozzle_mm = 0.4
layer_mm = 0.2
object_size_mm = 200
[[fdm.filaments]]
name = "white"
srgb = "#F2F2F0"
[[fdm.filaments]]
name = "black"
srgb = "#1A1A1A"
[[fdm.filaments]]
name = "red"
srgb = "#C12E1F"
[[fdm.filaments]]
name = "blue"
srgb = "#0A2989"
"##;

    #[test]
    fn an_fdm_printer_makes_only_its_filaments_nearest_by_de2000() {
        let p: Profile = toml::from_str(FOUR).unwrap();
        let pr = p.printer().unwrap();
        assert_eq!(p.kind(), "fdm");
        assert_eq!(pr.nearest([1.0, 1.0, 1.0]), 0);
        assert_eq!(pr.nearest([0.0, 0.0, 0.0]), 1);
        assert_eq!(pr.nearest([0.9, 0.1, 0.1]), 2);
        assert_eq!(pr.nearest([0.1, 0.2, 0.7]), 3);
        for c in [[0.3, 0.6, 0.2], [0.5, 0.5, 0.5], [1.0, 0.0, 1.0]] {
            assert!(pr.palette().contains(&pr.as_printed(c)));
        }
    }

    #[test]
    fn bad_profiles_are_refused_saying_what_is_wrong() {
        let e = |s: &str| {
            let p: Result<Profile, _> = toml::from_str(s);
            match p {
                Err(e) => e.to_string(),
                Ok(p) => format!("{:#}", p.printer().unwrap_err()),
            }
        };
        assert!(e(&FOUR.replace("#0A2989", "blue")).contains("filament 4"));
        assert!(e(&FOUR.replace("nozzle_mm = 0.4", "nozzle_mm = 0")).contains("nozzle_mm"));
        assert!(e(&FOUR.replace("layer_mm", "layer_height")).contains("layer_height"));
        assert!(e("name = \"x\"").contains("exactly one"));
    }

    #[test]
    fn the_identity_response_prints_what_it_is_asked() {
        let r = Response::identity();
        for c in [[0.0, 0.0, 0.0], [0.2, 0.5, 0.9], [1.0, 1.0, 1.0]] {
            let p = r.apply(c);
            assert!((0..3).all(|i| (p[i] - c[i]).abs() < 1e-5), "{c:?} → {p:?}");
        }
    }
}
