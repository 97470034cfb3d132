//! A part's surface ([`Material`]) and which parts the camouflage paints ([`PaintRule`]).

use serde::{Deserialize, Serialize};

/// Surface appearance of one part.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    /// Base colour (display values), multiplied with the texture when there is one.
    pub base_color: [f32; 3],
    /// Index into [`Scene::textures`].
    pub texture: Option<usize>,
    /// Strength of a Blinn-Phong highlight (0 = matte); glass and chrome are shiny.
    pub specular: f32,
    /// Blinn-Phong exponent.
    pub shininess: f32,
}

impl Material {
    /// The GGX roughness of the Blinn-Phong exponent: `(2 / (n + 2))^¼`, whose α = roughness² =
    /// `sqrt(2 / (n + 2))` is the lobe's width in radians. The Blender job gives Cycles this
    /// roughness, and the image-based light picks a part's reflection blur by its α.
    pub fn roughness(&self) -> f32 {
        (2.0 / (self.shininess.max(0.0) + 2.0)).powf(0.25)
    }

    pub fn plain(name: &str, base_color: [f32; 3]) -> Self {
        Material {
            name: name.into(),
            base_color,
            texture: None,
            specular: 0.04,
            shininess: 16.0,
        }
    }
}

/// Which parts may be painted, chosen by material (or OBJ object/group) name.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PaintRule {
    /// A material is paintable when its name contains any of these (case-insensitive) ...
    #[serde(default = "PaintRule::default_include")]
    pub include: Vec<String>,
    /// ... and none of these.
    #[serde(default = "PaintRule::default_exclude")]
    pub exclude: Vec<String>,
}

impl Default for PaintRule {
    fn default() -> Self {
        PaintRule {
            include: Self::default_include(),
            exclude: Self::default_exclude(),
        }
    }
}

impl PaintRule {
    /// The camouflage covers the body: by default any material whose name says body, paint,
    /// truck, car or hull, or `*` for every textured part.
    fn default_include() -> Vec<String> {
        [
            "body",
            "paint",
            "truck",
            "car",
            "hull",
            "shell",
            "barrel",
            "container",
        ]
        .map(String::from)
        .to_vec()
    }
    /// Wheels, glass, lights and trim stay as they are.
    fn default_exclude() -> Vec<String> {
        [
            "wheel", "tire", "tyre", "glass", "window", "light", "lamp", "trim", "rim", "chrome",
        ]
        .map(String::from)
        .to_vec()
    }

    pub fn is_paintable(&self, name: &str) -> bool {
        let n = name.to_lowercase();
        let inc = self
            .include
            .iter()
            .any(|p| p == "*" || n.contains(&p.to_lowercase()));
        let exc = self.exclude.iter().any(|p| n.contains(&p.to_lowercase()));
        inc && !exc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paint_rule_includes_body_and_excludes_wheels() {
        let r = PaintRule::default();
        assert!(r.is_paintable("Body_paint"));
        assert!(r.is_paintable("truck"));
        assert!(!r.is_paintable("wheels"));
        assert!(!r.is_paintable("truck_glass"));
        assert!(!r.is_paintable("seat"));
    }
}
