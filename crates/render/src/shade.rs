//! Shading and composition of one view from its G-buffer into a [`RenderPlan`]: the image as
//! `base + Σ weight · atlas[texel]`, where `base` holds everything that does not depend on the
//! camouflage (sky or background, ground, fixed parts, highlights) and the taps hold the
//! paintable surface: bilinear texel weights times diffuse shading, averaged over samples.
//!
//! Lighting ([`super::light`]) is ambient plus one directional sun with shadow rays (none are
//! cast when the sun is off), or a photographed environment ([`super::ibl`]): its sun with
//! shadow rays, its residual's irradiance occluded by the body, in colour, so the taps then
//! carry a colour each. Shading is applied to display-encoded values, as in the neural renderers
//! used by published camouflage attacks; paint replaces the paintable parts' colour entirely.

use super::accel::Accel;
use super::gbuffer::{GBuffer, Sample, Surface};
use super::ibl::{self, ImageLight, Sh9};
use super::light::{background_colour, environment_colour, mean_colour};
use super::light::{Backdrop, Background, Lighting};
use cac_core::colour;
use cac_scene::bilinear::{self, Wrap};
use cac_scene::{Material, Scene, Texture};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// One view, ready to be composited with any camouflage atlas (see [`super::composite`]).
#[derive(Clone, Debug)]
pub struct RenderPlan {
    pub width: usize,
    pub height: usize,
    /// Side of the square atlas the texel indices refer to.
    pub atlas_res: usize,
    /// Per pixel, row-major: the part of the colour that does not depend on the atlas.
    pub base: Vec<[f32; 3]>,
    pub tap_pixel: Vec<u32>,
    pub tap_texel: Vec<u32>,
    pub tap_weight: Vec<f32>,
    /// Empty under a grey light; under a coloured one (an environment), the light's colour per
    /// tap, multiplying its weight channel by channel.
    pub tap_colour: Vec<[f32; 3]>,
    /// Fraction of each pixel covered by the object.
    pub coverage: Vec<f32>,
    /// Ground-truth box of the visible object, pixels `[x1, y1, x2, y2]`.
    pub object_box: Option<[f32; 4]>,
}

/// Shades a G-buffer into a render plan for an atlas of `atlas_res x atlas_res`: of the whole
/// view, or of the band of rows the G-buffer holds (join bands with [`RenderPlan::stack`]).
pub fn plan(
    scene: &Scene,
    accel: &Accel,
    g: &GBuffer,
    light: &Lighting,
    backdrop: &Backdrop,
    atlas_res: usize,
) -> RenderPlan {
    let s = g.samples;
    let ibl = light.image.as_ref().map(|l| Ibl {
        light: l,
        sh: l.residual_sh(),
        ground_sh: l.map.sh_upper.map(|k| k.map(|v| v * l.strength)),
        sun: l.sun(),
    });
    let sh = Shader {
        scene,
        accel,
        light,
        backdrop,
        atlas_res,
        inv_s: 1.0 / s as f32,
        shadows: light.sun > 0.0 || ibl.as_ref().is_some_and(|i| i.sun.is_some()),
        ibl,
        eps: 1e-3 * (g.camera.eye.length() + 1.0),
        image_mean: match &backdrop.background {
            Background::Image(img) => mean_colour(img),
            _ => [0.0; 3],
        },
    };
    // One image row at a time (in parallel): its pixels' constant colours, the atlas taps of
    // their samples and the taps' colours, stacked in row order.
    let rows: Vec<RenderPlan> = g
        .data
        .par_chunks(s * g.width)
        .enumerate()
        .map(|(row, samples)| {
            let mut out = RenderPlan::empty(g.width, atlas_res);
            out.height = 1;
            let mut taps = Vec::new();
            for (x, samples) in samples.chunks_exact(s).enumerate() {
                let mut base = [0.0f32; 3];
                taps.clear();
                let pi = row * g.width + x;
                let global = (g.rows.start * g.width + pi) as u64;
                for (k, sm) in samples.iter().enumerate() {
                    let phase = sample_phase(global, k);
                    match sm.surface {
                        Surface::Sky if sh.ibl.is_some() => {
                            let i = sh.ibl.as_ref().expect("checked");
                            add(&mut base, i.light.backdrop(sm.dir), sh.inv_s);
                        }
                        Surface::Sky => {
                            let c = background_colour(
                                &backdrop.background,
                                sm.dir,
                                x,
                                g.rows.start + row,
                                g.width,
                                g.height,
                            );
                            add(&mut base, c, sh.inv_s);
                        }
                        Surface::Ground => add(&mut base, sh.ground(sm, phase), sh.inv_s),
                        Surface::Object => {
                            sh.object(sm, phase, &mut base, &mut taps, &mut out.tap_colour)
                        }
                    }
                }
                out.base.push(base);
                for &(t, w) in &taps {
                    out.tap_pixel.push(x as u32);
                    out.tap_texel.push(t);
                    out.tap_weight.push(w);
                }
            }
            out
        })
        .collect();
    let mut out =
        RenderPlan::stack(std::iter::once(RenderPlan::empty(g.width, atlas_res)).chain(rows));
    out.coverage = g.coverage();
    out.object_box = g.object_box();
    out
}

/// `base += c · k`, per channel.
fn add(base: &mut [f32; 3], c: [f32; 3], k: f32) {
    for i in 0..3 {
        base[i] += c[i] * k;
    }
}

/// A per-sample phase in [0, 1) for the occlusion rays' pattern, from the sample's place in the
/// whole view (so a band of rows shades exactly as the whole view does).
fn sample_phase(pixel: u64, sample: usize) -> f32 {
    let mut x = pixel.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (sample as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 31;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 29;
    (x >> 40) as f32 / (1u64 << 24) as f32
}

/// An environment's light prepared for one view: the residual's coefficients as the object
/// sees them (ground below) and as the ground sees them (the sky above), and its sun.
struct Ibl<'a> {
    light: &'a ImageLight,
    sh: Sh9,
    ground_sh: Sh9,
    sun: Option<(Vec3, [f32; 3])>,
}

/// What shading one G-buffer sample needs: the scene and its BVH (shadow rays), the light, the
/// backdrop, the atlas size, the sample weight, the shadow-ray offset and the backdrop image's
/// mean colour (what glossy parts reflect of an image backdrop).
struct Shader<'a> {
    scene: &'a Scene,
    accel: &'a Accel,
    light: &'a Lighting,
    backdrop: &'a Backdrop,
    atlas_res: usize,
    inv_s: f32,
    shadows: bool,
    eps: f32,
    image_mean: [f32; 3],
    ibl: Option<Ibl<'a>>,
}

impl Shader<'_> {
    /// The display light (per channel) an environment gives a surface at `p` with normal `n`:
    /// the residual's irradiance from `sh` times the share of it the body lets through (from
    /// `occlusion_rays` rays weighted by the residual's luminance in their direction), plus the
    /// shadowed sun; `srgb(E / π)`. Also the sun's display level for highlights, and whether
    /// the sun is seen.
    fn ibl_light(
        &self,
        i: &Ibl,
        sh: &Sh9,
        p: Vec3,
        n: Vec3,
        phase: f32,
    ) -> ([f32; 3], [f32; 3], f32) {
        let mut e = i.light.irradiance(sh, n);
        let rays = i.light.settings.occlusion_rays;
        if rays > 0 {
            let (mut open, mut all) = (0.0f32, 0.0f32);
            for d in ibl::cosine_directions(n, rays, phase) {
                let wgt = i.light.residual_luminance(sh, d) + 1e-6;
                all += wgt;
                if !self.accel.occluded(p + n * self.eps, d, 0.0, f32::INFINITY) {
                    open += wgt;
                }
            }
            let share = open / all;
            e = e.map(|v| v * share);
        }
        let (mut sun_disp, mut vis) = ([0.0f32; 3], 0.0);
        if let Some((dir, s)) = i.sun {
            let ndl = n.dot(dir);
            if ndl > 0.0
                && !self
                    .accel
                    .occluded(p + n * self.eps, dir, 0.0, f32::INFINITY)
            {
                vis = 1.0;
                for c in 0..3 {
                    e[c] += s[c] * ndl;
                }
            }
            sun_disp = s.map(|v| colour::encode(v / std::f32::consts::PI));
        }
        (
            e.map(|v| colour::encode(v / std::f32::consts::PI)),
            sun_disp,
            vis,
        )
    }

    /// A ground sample's colour: its texture lit by the ambient and the (shadowed) sun, fading
    /// into the horizon with distance.
    fn ground(&self, sm: &Sample, phase: f32) -> [f32; 3] {
        let gr = self
            .backdrop
            .ground
            .as_ref()
            .expect("ground hit without a ground");
        let p = sm.position;
        if let Some(i) = &self.ibl {
            // Lit by the environment's sky and sun, shadowed by the body; no aerial
            // perspective (the photographed horizon is the map's own).
            let (k, _, _) = self.ibl_light(i, &i.ground_sh, p, Vec3::Y, phase);
            let uv = (Vec2::new(p.x, p.z) + gr.offset) / gr.tile_m;
            let c = gr.texture.sample(uv);
            return [0, 1, 2].map(|j| c[j] * k[j]);
        }
        let vis = if self.shadows
            && self.accel.occluded(
                p + Vec3::Y * self.eps,
                self.light.sun_dir,
                0.0,
                f32::INFINITY,
            ) {
            0.0
        } else {
            1.0
        };
        let k = self.light.ambient + self.light.sun * self.light.sun_dir.y.max(0.0) * vis;
        let uv = (Vec2::new(p.x, p.z) + gr.offset) / gr.tile_m;
        let c = gr.texture.sample(uv);
        // Aerial perspective: far ground fades to the horizon colour.
        let fog = 1.0 - (-sm.depth / 150.0).exp();
        let hz = match &self.backdrop.background {
            Background::Sky { horizon, .. } => *horizon,
            Background::Color(c) => *c,
            Background::Image(_) => c,
        };
        [0, 1, 2].map(|i| (c[i] * k) * (1.0 - fog) + hz[i] * fog)
    }

    /// An object sample: the highlight and the reflected environment into `base`; the lit
    /// albedo into `base`, or, on paintable parts, the lit atlas texels into `taps` (and, under
    /// coloured light, their light into `colours`).
    fn object(
        &self,
        sm: &Sample,
        phase: f32,
        base: &mut [f32; 3],
        taps: &mut Vec<(u32, f32)>,
        colours: &mut Vec<[f32; 3]>,
    ) {
        let tri = &self.scene.triangles[sm.tri as usize];
        let mat = &self.scene.materials[tri.material as usize];
        let n = sm.normal;
        let (diffuse, highlight) = match &self.ibl {
            Some(i) => self.environment_light(i, sm, mat, phase),
            None => self.sun_light(sm, mat),
        };
        add(base, highlight, self.inv_s);
        // Mirror reflection of the environment on glossy parts (clear coat,
        // glass, chrome), weighted by Schlick's Fresnel term.
        let gloss = (mat.specular * 1.5).min(1.0);
        if gloss > 0.05 {
            let cos = (-sm.dir).dot(n).clamp(0.0, 1.0);
            let fresnel = 0.04 + 0.96 * (1.0 - cos).powi(5);
            let r = sm.dir - n * 2.0 * sm.dir.dot(n);
            let env = match &self.ibl {
                Some(i) => i.light.reflected(r, mat.roughness()),
                None => environment_colour(self.backdrop, self.light, self.image_mean, r),
            };
            add(base, env, gloss * fresnel * self.inv_s);
        }
        if self.scene.is_paintable(tri) {
            for (texel, w) in bilinear::taps(sm.uv, self.atlas_res, self.atlas_res, Wrap::Repeat) {
                if w > 0.0 {
                    match diffuse {
                        Diffuse::Grey(d) => taps.push((texel, w * d * self.inv_s)),
                        Diffuse::Colour(k) => {
                            taps.push((texel, w * self.inv_s));
                            colours.push(k);
                        }
                    }
                }
            }
        } else {
            let albedo = match (mat.texture, tri.uv) {
                (Some(t), Some(_)) => {
                    let c = self.scene.textures[t].sample(sm.uv);
                    [0, 1, 2].map(|i| c[i] * mat.base_color[i])
                }
                _ => mat.base_color,
            };
            match diffuse {
                Diffuse::Grey(d) => add(base, albedo, d * self.inv_s),
                Diffuse::Colour(k) => add(base, [0, 1, 2].map(|j| albedo[j] * k[j]), self.inv_s),
            }
        }
    }

    /// The diffuse light and the highlight of an object sample under the ambient and the sun.
    fn sun_light(&self, sm: &Sample, mat: &Material) -> (Diffuse, [f32; 3]) {
        let n = sm.normal;
        let ndl = n.dot(self.light.sun_dir);
        let vis = if self.shadows
            && ndl > 0.0
            && self.accel.occluded(
                sm.position + n * self.eps,
                self.light.sun_dir,
                0.0,
                f32::INFINITY,
            ) {
            0.0
        } else {
            1.0
        };
        let ambient = match self.light.sky_occlusion {
            None => self.light.ambient,
            Some(albedo) => {
                let sky = 0.5 + 0.5 * n.y.clamp(-1.0, 1.0);
                let ground =
                    albedo * (self.light.ambient + self.light.sun * self.light.sun_dir.y.max(0.0));
                self.light.ambient * sky + ground * (1.0 - sky)
            }
        };
        let diffuse = ambient + self.light.sun * ndl.max(0.0) * vis;
        let h = (self.light.sun_dir - sm.dir).normalize_or_zero();
        let spec = if ndl > 0.0 {
            mat.specular * self.light.sun * vis * n.dot(h).max(0.0).powf(mat.shininess)
        } else {
            0.0
        };
        (Diffuse::Grey(diffuse), [spec; 3])
    }

    /// The diffuse light and the highlight of an object sample under an environment: coloured.
    fn environment_light(
        &self,
        i: &Ibl,
        sm: &Sample,
        mat: &Material,
        phase: f32,
    ) -> (Diffuse, [f32; 3]) {
        let n = sm.normal;
        let (k, sun_disp, vis) = self.ibl_light(i, &i.sh, sm.position, n, phase);
        let mut highlight = [0.0; 3];
        if let Some((dir, _)) = i.sun {
            let h = (dir - sm.dir).normalize_or_zero();
            let s = mat.specular * vis * n.dot(h).max(0.0).powf(mat.shininess);
            highlight = sun_disp.map(|v| v * s);
        }
        (Diffuse::Colour(k), highlight)
    }
}

/// The diffuse light on a sample: one grey level, or per channel.
#[derive(Clone, Copy)]
enum Diffuse {
    Grey(f32),
    Colour([f32; 3]),
}

impl RenderPlan {
    /// The weight of tap `k` in channel `c`.
    pub fn weight(&self, k: usize, c: usize) -> f32 {
        match self.tap_colour.get(k) {
            Some(col) => self.tap_weight[k] * col[c],
            None => self.tap_weight[k],
        }
    }

    /// A plan of no rows, `width` wide.
    fn empty(width: usize, atlas_res: usize) -> RenderPlan {
        RenderPlan {
            width,
            height: 0,
            atlas_res,
            base: vec![],
            tap_pixel: vec![],
            tap_texel: vec![],
            tap_weight: vec![],
            tap_colour: vec![],
            coverage: vec![],
            object_box: None,
        }
    }

    /// The plan of a whole view from the plans of its bands of rows, top to bottom (all of one
    /// width and atlas): the same plan, bit for bit, as shading the view at once.
    pub fn stack(bands: impl IntoIterator<Item = RenderPlan>) -> RenderPlan {
        let mut bands = bands.into_iter();
        let mut out = bands.next().expect("stack needs at least one band");
        for b in bands {
            assert!(
                b.width == out.width && b.atlas_res == out.atlas_res,
                "bands differ in width or atlas"
            );
            let offset = (out.width * out.height) as u32;
            out.height += b.height;
            out.base.extend(b.base);
            out.tap_pixel
                .extend(b.tap_pixel.iter().map(|&p| p + offset));
            out.tap_texel.extend(b.tap_texel);
            out.tap_weight.extend(b.tap_weight);
            out.tap_colour.extend(b.tap_colour);
            out.coverage.extend(b.coverage);
            out.object_box = match (out.object_box, b.object_box) {
                (Some(a), Some(c)) => Some([
                    a[0].min(c[0]),
                    a[1].min(c[1]),
                    a[2].max(c[2]),
                    a[3].max(c[3]),
                ]),
                (a, c) => a.or(c),
            };
        }
        out
    }

    /// Composites on the CPU (no gradients): the reference for the tensor path.
    pub fn render_cpu(&self, atlas: &Texture) -> Vec<[f32; 3]> {
        assert_eq!(
            atlas.width, self.atlas_res,
            "atlas size differs from the plan's"
        );
        let mut img = self.base.clone();
        for k in 0..self.tap_pixel.len() {
            let t = atlas.texels[self.tap_texel[k] as usize];
            let p = &mut img[self.tap_pixel[k] as usize];
            for c in 0..3 {
                p[c] += self.weight(k, c) * t[c];
            }
        }
        img
    }
}
