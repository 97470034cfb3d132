//! The paper's attack baselines, run in the same renderer, environment and detectors as CAC so
//! tables compare like with like.
//!
//! * 3D, full atlas, EOT over the environment (the trainer's atlas parameterisation with another
//!   objective): **UPC** (Huang et al. 2020) and **CAMOU** (Zhang et al. 2019).
//! * 2D, a square patch trained under plane transformations pasted on rendered images of the
//!   vehicle, then tiled over every paintable texel (the trainer's [`patch::Patch`]
//!   parameterisation, [`atlas`]): **AdvPat** (Thys et al. 2019) and **ShapeShifter** (Chen et
//!   al. 2018).
//!
//! All five are trained by the one [`crate::Trainer`].
//!
//! The objectives are in [`objectives`]; `docs/attack.md` says exactly how each paper is realised
//! and where it departs from it. Not here: the CLI, evaluation.

pub mod atlas;
pub mod objectives;
pub mod patch;
pub mod patch2d;

pub use objectives::objective;

use serde::{Deserialize, Serialize};

/// Which attack to run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Coated adversarial camouflage: dense-proposals loss, full atlas, 3D EOT (this paper).
    #[default]
    Cac,
    /// Thys et al. 2019: minimise the best vehicle score; 2D patch, tiled on all sides.
    Advpat,
    /// Chen et al. 2018: targeted loss over the proposals under 2D EOT; 2D patch, tiled.
    Shapeshifter,
    /// Huang et al. 2020: objectness + targeted classification + box regression, full atlas, 3D.
    Upc,
    /// Zhang et al. 2019: hide the vehicle (suppress car/bus/truck in every candidate), 3D.
    Camou,
}

cac_core::choices!(Method {
    Cac => "cac": "Coated adversarial camouflage: dense-proposals loss, full atlas, 3D EOT (this paper)",
    Advpat => "advpat": "Thys et al. 2019: minimise the best vehicle score; 2D patch, tiled on all sides",
    Shapeshifter => "shapeshifter": "Chen et al. 2018: targeted loss over the proposals under 2D EOT; 2D patch, tiled",
    Upc => "upc": "Huang et al. 2020: objectness + targeted classification + box regression, full atlas, 3D",
    Camou => "camou": "Zhang et al. 2019: hide the vehicle (suppress car/bus/truck in every candidate), 3D",
});

impl Method {
    /// Trained as a 2D patch (then pasted on the object), not on the atlas in 3D.
    pub fn is_2d(self) -> bool {
        matches!(self, Method::Advpat | Method::Shapeshifter)
    }

    /// Uses the target class (CAC unless `--hide`, ShapeShifter, UPC).
    pub fn is_targeted(self) -> bool {
        matches!(self, Method::Cac | Method::Shapeshifter | Method::Upc)
    }
}
