//! A second, independent renderer: Blender (Cycles on the CPU, headless), driven at the same
//! camera poses and lighting levels as cac's own renderer, so that a texture's P@0.5 can be
//! reported in both (adversarial textures often lose much of their effect when re-rendered).
//!
//! cac writes the object as OBJ (its own frame, +Y up, kept in Blender unchanged), the paint
//! texture(s) and ground textures as PNG, and a JSON job file; `tools/blender/render_views.py`
//! (embedded here) builds the scene and renders every view in one `blender -b` run. Conversions:
//! - camera: cac's OpenCV pose (columns right, down, forward) → Blender's camera matrix (columns
//!   right, up, backward); focal length and principal point → lens, sensor and shift;
//! - light: cac multiplies display (sRGB) values by `ambient + sun·cos`; Blender works in linear
//!   light, so the uniform world's strength is `lin(ambient)` and the sun's irradiance is
//!   `π (lin(ambient + sun) − lin(ambient))`: a white surface facing the sun, or in shade under an
//!   open sky, gets the same display value in both. The ground, GI, soft sky occlusion and
//!   Fresnel reflections are Cycles' own (that is the point of a second renderer); [`Shading`]
//!   takes Cycles step by step towards cac's own image formation instead, to find which
//!   difference a texture's loss comes from;
//! - materials: Principled BSDF, base colour = texture or colour (sRGB decoded), roughness from the
//!   Blinn-Phong exponent (`(2 / (n + 2))^¼`), reflectance at normal incidence as cac's mirror
//!   term (`0.04 · min(1.5 · specular, 1)`);
//! - backdrop: rendered with a transparent film and composited here with cac's own sky, flat
//!   colour or image (so both renderers show the same background; cac's aerial perspective on
//!   the far ground is not reproduced).
//!
//! An HDR environment ([`World`]: one Blender ships, or any equirectangular image) can light the
//! scene instead: Cycles' world, importance-sampled, replacing the ambient and the sun, and seen
//! behind the object (the image is then written opaque, not composited over cac's backdrop).
//! cac's own renderer has no image-based lighting yet: this is the judge under real light.
//!
//! Sampling: `samples` per pixel (box filter one pixel wide), no denoising by default, a fixed
//! seed; `bounces` light bounces (0: direct light only). The object mask comes from a second
//! view layer in which the ground is a holdout: its alpha is the object's coverage, from which
//! the ground-truth box is taken as in cac.

use super::{ImageScore, Protocol, Scorer};
use anyhow::{bail, Context, Result};
use burn::tensor::Device;
use cac_detect::Detector;
use cac_render::environment::{self, Condition, Environment};
use cac_render::{self as render, light, Camera, Renderer};
use cac_scene::{obj_write, Texture};
use glam::Vec3;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

/// The Python side, run by Blender.
pub(crate) const SCRIPT: &str = include_str!("../../../tools/blender/render_views.py");

/// How Blender is run.
#[derive(Clone, Debug)]
pub struct BlenderSettings {
    /// The Blender executable (default: `blender` on the PATH; the command line takes
    /// `$CAC_BLENDER`).
    pub executable: PathBuf,
    /// Cycles samples per pixel.
    pub samples: usize,
    /// Samples of the coverage mask.
    pub mask_samples: usize,
    /// Cycles' light-path bounce limit (default 4, diffuse and glossy at most 2); 0 renders
    /// direct light only (sun and sky with their shadows, no bounce light), the closest to cac's
    /// own shading, to tell a loss from indirect light apart from one from the rest.
    pub bounces: usize,
    /// How Cycles forms the image: physically (the default), or step by step closer to cac's own
    /// image formation, to tell which difference a texture's loss comes from.
    pub shading: Shading,
    /// Glossy rays that leave for the sky see the sky cac composites behind the object (its
    /// horizon-to-zenith gradient, decoded in linear light) rather than the uniform ambient world
    /// (always so with cac's surfaces).
    pub sky_reflections: bool,
    /// CPU threads (0: Blender's choice).
    pub threads: usize,
    /// Denoise (OpenImageDenoise, when the Blender build has it).
    pub denoise: bool,
    /// Keep the job folder here (default: a temporary folder that is removed afterwards; the
    /// command line takes `$CAC_BLENDER_WORK`).
    pub work_dir: Option<PathBuf>,
    /// Light the scene with a photographed HDR environment instead of the condition's ambient and
    /// sun (see [`World`]); `None`: the condition's light.
    pub world: Option<World>,
}

/// A photographed environment as Cycles' world: it lights the object and the ground (image-based
/// lighting, importance-sampled, with the ground's and the body's occlusion and bounce light) and
/// is the backdrop seen behind them. The photographed scene's up is cac's +Y.
#[derive(Clone, Debug, PartialEq)]
pub struct World {
    /// An equirectangular image Blender reads (EXR, HDR), or the name of one of the HDR
    /// environments Blender ships (`city`, `courtyard`, `forest`, `interior`, `night`, `studio`,
    /// `sunrise`, `sunset`: its `datafiles/studiolights/world/NAME.exr`, CC0).
    pub image: String,
    /// The environment's strength (1: as photographed).
    pub strength: f32,
    /// Turn of the environment about the vertical axis, degrees.
    pub rotation_deg: f32,
}

/// The HDR environments Blender ships (`World::image` names).
pub use cac_render::ibl::BLENDER_WORLDS;

impl World {
    /// `name` (one of [`BLENDER_WORLDS`]) or a path to an existing image file; else an error
    /// naming the choices.
    pub fn new(image: &str, strength: f32, rotation_deg: f32) -> Result<World> {
        let known = BLENDER_WORLDS.contains(&image);
        if !known {
            // Neither a name nor a file: the one error that says so (`render::ibl::resolve`).
            cac_render::ibl::resolve(image)?;
        }
        if !(strength.is_finite() && strength > 0.0) {
            bail!("HDR environment strength {strength} must be positive");
        }
        let image = if known {
            image.to_string()
        } else {
            std::fs::canonicalize(image)?.display().to_string()
        };
        Ok(World {
            image,
            strength,
            rotation_deg,
        })
    }

    /// The short name used in tables: the Blender name, or the file's stem.
    pub fn name(&self) -> String {
        Path::new(&self.image)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.image.clone())
    }
}

impl BlenderSettings {
    /// The renderer's name in tables: "blender" with the default image formation, else the
    /// settings that differ from it (e.g. "blender:cac,b0"), so rows of different settings
    /// cannot be mistaken for each other.
    pub fn label(&self) -> String {
        let mut parts = vec![];
        if self.shading != Shading::Linear {
            parts.push(self.shading.to_string());
        }
        if self.bounces != 4 {
            parts.push(format!("b{}", self.bounces));
        }
        if self.sky_reflections {
            parts.push("sky".into());
        }
        match parts.is_empty() {
            true => "blender".into(),
            false => format!("blender:{}", parts.join(",")),
        }
    }
}

impl Default for BlenderSettings {
    fn default() -> Self {
        BlenderSettings {
            executable: "blender".into(),
            samples: 32,
            mask_samples: 16,
            bounces: 4,
            shading: Shading::Linear,
            sky_reflections: false,
            threads: 0,
            denoise: false,
            work_dir: None,
            world: None,
        }
    }
}

/// How Cycles forms the image: see [`BlenderSettings::shading`]. Each step towards cac's own
/// image formation keeps the one before it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shading {
    /// Physical: colours and textures decoded from sRGB, lights converted so that a white
    /// surface facing the sun or the open sky shows cac's display value, Principled BSDF, the
    /// ambient a uniform world (occluded by the ground and the body), the image encoded to sRGB.
    Linear,
    /// As `Linear`, but colours, textures and light levels taken as display values and the image
    /// written as computed (view transform "Raw"): albedo × light on display values, as in cac.
    Display,
    /// As `Display`, with cac's surfaces: a Lambert diffuse, a GGX glossy lobe weighted by cac's
    /// gloss × dielectric Fresnel, and glossy rays that leave for the sky seeing cac's reflected
    /// sky (horizon to zenith by the square root of the ray's height); the ambient is still the
    /// uniform world, occluded by the ground and the body.
    CacSurfaces,
    /// As `CacSurfaces`, with cac's ambient term: albedo × ambient whatever occludes the sky (an
    /// emission; the world lights glossy rays only). Left to Cycles: shadows, the highlight's
    /// shape (GGX), bounce light and its sampling.
    Cac,
}

cac_core::choices!(Shading {
    Linear => "linear": "Physical: colours and textures decoded from sRGB, lights converted so that a \
        white surface facing the sun or the open sky shows cac's display value, Principled BSDF, \
        the ambient a uniform world (occluded by the ground and the body), the image encoded to sRGB",
    Display => "display": "As `Linear`, but colours, textures and light levels taken as display \
        values and the image written as computed (view transform \"Raw\"): albedo × light on \
        display values, as in cac",
    CacSurfaces => "cac-surfaces": "As `Display`, with cac's surfaces: a Lambert diffuse, a GGX \
        glossy lobe weighted by cac's gloss × dielectric Fresnel, and glossy rays that leave for \
        the sky seeing cac's reflected sky (horizon to zenith by the square root of the ray's \
        height); the ambient is still the uniform world, occluded by the ground and the body",
    Cac => "cac": "As `CacSurfaces`, with cac's ambient term: albedo × ambient whatever occludes \
        the sky (an emission; the world lights glossy rays only). Left to Cycles: shadows, the \
        highlight's shape (GGX), bounce light and its sampling",
});

/// The horizon and zenith colours cac's mirror term reflects (`shade`'s environment colour above
/// the horizon): the sky's, a flat background's colour, an image background's mean.
fn reflected_sky(bg: &render::Background) -> [[f32; 3]; 2] {
    match bg {
        render::Background::Sky {
            horizon, zenith, ..
        } => [*horizon, *zenith],
        render::Background::Color(c) => [*c, *c],
        render::Background::Image(img) => [light::mean_colour(img); 2],
    }
}

/// One view rendered by Blender.
pub struct BlenderView {
    pub image: image::RgbImage,
    /// Fraction of each pixel covered by the object (row-major).
    pub coverage: Vec<f32>,
    /// Tight box `[x1, y1, x2, y2]` of the pixels the object covers (`None`: not visible).
    pub object_box: Option<[f32; 4]>,
}

/// Blender's camera for a cac camera: `matrix_world` (row-major 4×4), lens and sensor (mm),
/// sensor fit and shift. Assumes square pixels (`fx == fy`).
pub(crate) fn blender_camera(cam: &Camera) -> serde_json::Value {
    let k = cam.intrinsics;
    let (w, h) = (k.width as f32, k.height as f32);
    let big = w.max(h);
    let (fit, sensor) = if w >= h {
        ("HORIZONTAL", 36.0 * w / big)
    } else {
        ("VERTICAL", 36.0 * h / big)
    };
    // Focal length in pixels over the fitted side, in millimetres of the sensor.
    let lens = if w >= h {
        k.fx * sensor / w
    } else {
        k.fy * sensor / h
    };
    // Blender's shift is in units of the larger image side; +x moves the view right, +y up.
    let shift_x = (0.5 * w - k.cx) / big;
    let shift_y = (k.cy - 0.5 * h) / big;
    let r = cam.rotation;
    let (right, up, back) = (r.x_axis, -r.y_axis, -r.z_axis);
    let e = cam.eye;
    let m = [
        [right.x, up.x, back.x, e.x],
        [right.y, up.y, back.y, e.y],
        [right.z, up.z, back.z, e.z],
        [0.0, 0.0, 0.0, 1.0],
    ];
    json!({
        "matrix_world": m, "lens": lens, "sensor_fit": fit,
        "sensor_width": 36.0 * w / big, "sensor_height": 36.0 * h / big,
        "shift_x": shift_x, "shift_y": shift_y,
        "clip_start": 0.01, "clip_end": 10000.0,
    })
}

/// A sun lamp pointing along `-dir` (Blender lamps shine along their local −Z).
fn sun_matrix(dir: Vec3) -> [[f32; 4]; 4] {
    let z = dir.normalize();
    let x = if z.y.abs() < 0.99 {
        Vec3::Y.cross(z).normalize()
    } else {
        Vec3::X
    };
    let y = z.cross(x);
    [
        [x.x, y.x, z.x, 0.0],
        [x.y, y.y, z.y, 0.0],
        [x.z, y.z, z.z, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// Is Blender there? Returns its version line, or a clear error.
pub fn check(s: &BlenderSettings) -> Result<String> {
    if s.world.is_some() && (s.shading != Shading::Linear || s.sky_reflections) {
        bail!(
            "an HDR environment lights Blender's scene physically: it goes with the linear shading and without sky reflections (the steps towards cac's image formation model cac's ambient and sun, which the environment replaces)"
        );
    }
    let out = Command::new(&s.executable)
        .args(["-b", "--factory-startup", "--version"])
        .output()
        .with_context(|| {
            format!(
                "cannot run Blender ({}): install it (Debian: apt-get install blender) or set CAC_BLENDER",
                s.executable.display()
            )
        })?;
    let text = String::from_utf8_lossy(&out.stdout);
    match text.lines().find(|l| l.starts_with("Blender")) {
        Some(l) if out.status.success() => Ok(l.trim().to_string()),
        _ => bail!(
            "{} --version failed: {}",
            s.executable.display(),
            tail(&String::from_utf8_lossy(&out.stderr), 2000)
        ),
    }
}

fn tail(s: &str, n: usize) -> &str {
    let start = s.len().saturating_sub(n);
    let mut i = start;
    while !s.is_char_boundary(i) {
        i += 1;
    }
    &s[i..]
}

/// Renders `atlas` on the renderer's object in every condition with Blender: same cameras (with
/// the conditions' shifts), lighting levels, sun, ground and backdrop; print error is applied
/// to the atlas and the photometric transforms to the images exactly as in cac's pipeline.
/// Conditions lit by one of the environment's HDR maps (`Condition::hdri`) are rendered with
/// that map as the world, turned and exposed as drawn (one Blender run per distinct draw);
/// `s.world` lights the others.
pub fn render_views(
    r: &Renderer,
    env: &Environment,
    conds: &[Condition],
    atlas: &Texture,
    s: &BlenderSettings,
    device: &Device,
) -> Result<Vec<BlenderView>> {
    let mut groups: Vec<(Option<cac_render::environment::HdriDraw>, Vec<usize>)> = vec![];
    for (i, c) in conds.iter().enumerate() {
        match groups.iter_mut().find(|(d, _)| *d == c.hdri) {
            Some((_, v)) => v.push(i),
            None => groups.push((c.hdri, vec![i])),
        }
    }
    if groups.len() == 1 && groups[0].0.is_none() {
        return render_group(r, env, conds, atlas, s, device);
    }
    let mut out: Vec<Option<BlenderView>> = (0..conds.len()).map(|_| None).collect();
    for (draw, idx) in groups {
        let mut sg = s.clone();
        if let Some(d) = draw {
            let path = env.hdri_path(d.index);
            sg.world = Some(World::new(
                &path.display().to_string(),
                d.exposure_stops.exp2(),
                d.rotation_deg,
            )?);
        }
        let cs: Vec<Condition> = idx.iter().map(|&i| conds[i].clone()).collect();
        for (i, v) in idx
            .into_iter()
            .zip(render_group(r, env, &cs, atlas, &sg, device)?)
        {
            out[i] = Some(v);
        }
    }
    Ok(out
        .into_iter()
        .map(|v| v.expect("every view rendered"))
        .collect())
}

/// [`render_views`] of conditions that share one world.
fn render_group(
    r: &Renderer,
    env: &Environment,
    conds: &[Condition],
    atlas: &Texture,
    s: &BlenderSettings,
    device: &Device,
) -> Result<Vec<BlenderView>> {
    check(s)?;
    let tmp;
    let dir: &Path = match &s.work_dir {
        Some(d) => {
            std::fs::create_dir_all(d)
                .with_context(|| format!("cannot create Blender work folder {}", d.display()))?;
            d
        }
        None => {
            tmp = tempfile::tempdir()?;
            tmp.path()
        }
    };
    let job = Job::new(r, env, s, dir)?;
    let (job, cams) = job.views(conds, atlas, device)?;
    run_blender(s, dir, &job)?;
    // Read back, composite the backdrop, apply the photometric transforms.
    cams.iter()
        .zip(conds)
        .enumerate()
        .map(|(i, ((cam, backdrop), c))| {
            let backdrop = s.world.is_none().then_some(backdrop);
            read_view(r, dir, i, cam, backdrop, c, device)
        })
        .collect()
}

/// The job file Blender renders from, written into `dir` as it is built: the object as OBJ with
/// its materials, then per view the camera, light, ground and paint texture (identical textures
/// shared between views).
struct Job<'a> {
    r: &'a Renderer,
    env: &'a Environment,
    s: &'a BlenderSettings,
    dir: &'a Path,
    materials: serde_json::Map<String, serde_json::Value>,
    paints: Vec<(Vec<u8>, String)>,
    grounds: Vec<(*const Texture, String)>,
}

impl<'a> Job<'a> {
    /// Writes the object (paintable parts white, to take the per-view paint texture) and
    /// describes its materials.
    fn new(
        r: &'a Renderer,
        env: &'a Environment,
        s: &'a BlenderSettings,
        dir: &'a Path,
    ) -> Result<Self> {
        let mut scene = r.scene.clone();
        for (m, &p) in scene.materials.iter_mut().zip(&scene.paintable) {
            if p {
                m.texture = None;
                m.base_color = [1.0; 3];
            }
        }
        obj_write::write_obj(&scene, dir, "object")?;
        let mut materials = serde_json::Map::new();
        for (m, &p) in scene.materials.iter().zip(&scene.paintable) {
            let rough = m.roughness();
            materials.insert(
                m.name.clone(),
                json!({
                    "color": m.base_color.map(|x| decode(s, x)),
                    "texture": m.texture.map(|t| format!("object_tex{t}.png")),
                    "paintable": p,
                    "roughness": rough,
                    // cac reflects min(1.5·specular, 1) × Schlick(F0 = 0.04); Principled's F0 is
                    // 0.08 × Specular.
                    "specular": 0.5 * (1.5 * m.specular).min(1.0),
                }),
            );
        }
        Ok(Job {
            r,
            env,
            s,
            dir,
            materials,
            paints: vec![],
            grounds: vec![],
        })
    }

    /// The whole job with one entry per condition, and each view's camera and backdrop (for
    /// compositing the images Blender returns).
    fn views(
        mut self,
        conds: &[Condition],
        atlas: &Texture,
        device: &Device,
    ) -> Result<(serde_json::Value, Vec<(Camera, light::Backdrop)>)> {
        let s = self.s;
        let cac_surfaces = matches!(s.shading, Shading::CacSurfaces | Shading::Cac);
        let a = render::atlas_tensor(atlas, device);
        let mut views = vec![];
        let mut cams = vec![];
        for (i, c) in conds.iter().enumerate() {
            let pa = render::atlas_texture(&environment::print_error(
                a.clone(),
                std::slice::from_ref(c),
            ))
            .to_rgb8();
            let paint = self.paint(pa)?;
            let cam = self.r.camera(&c.viewpoint)?;
            let light = self.env.lighting(c);
            let backdrop = self.env.backdrop(c);
            let amb = decode(s, light.ambient);
            let sun = (light.sun > 0.0).then(|| {
                json!({
                    "strength": std::f32::consts::PI * (decode(s, light.ambient + light.sun) - amb),
                    "matrix_world": sun_matrix(light.sun_dir),
                })
            });
            let ground = match &backdrop.ground {
                None => serde_json::Value::Null,
                Some(g) => self.ground(g)?,
            };
            views.push(json!({
                "camera": blender_camera(&cam),
                "world_strength": amb,
                "reflected_sky": (cac_surfaces || s.sky_reflections)
                    .then(|| reflected_sky(&backdrop.background).map(|c| c.map(|x| decode(s, x)))),
                "sun": sun,
                "ground": ground,
                "paint_texture": paint,
                "out": format!("view{i:04}.png"),
                "mask_prefix": format!("mask{i:04}_"),
            }));
            cams.push((cam, backdrop));
        }
        let job = json!({
            "obj": "object.obj",
            "width": self.r.settings.width, "height": self.r.settings.height,
            "samples": s.samples, "mask_samples": s.mask_samples, "threads": s.threads,
            "bounces": s.bounces,
            "display_values": s.shading != Shading::Linear,
            "cac_surfaces": cac_surfaces,
            "cac_ambient": s.shading == Shading::Cac,
            "sky_reflections": s.sky_reflections,
            "denoise": s.denoise, "seed": 0, "ground_half_size": 1000.0,
            "world": s.world.as_ref().map(|w| json!({
                "image": w.image, "strength": w.strength, "rotation_deg": w.rotation_deg,
            })),
            "materials": self.materials,
            "ground_textures": self.grounds.iter().map(|(_, n)| n.clone()).collect::<Vec<_>>(),
            "views": views,
        });
        Ok((job, cams))
    }

    /// The file name of a view's paint texture (print error differs per view), written once.
    fn paint(&mut self, pa: image::RgbImage) -> Result<String> {
        if let Some((_, n)) = self
            .paints
            .iter()
            .find(|(b, _)| *b == pa.as_raw().as_slice())
        {
            return Ok(n.clone());
        }
        let n = format!("paint{}.png", self.paints.len());
        cac_core::io::save_png_atomic(&self.dir.join(&n), &pa)?;
        self.paints.push((pa.into_raw(), n.clone()));
        Ok(n)
    }

    /// A view's ground: its texture (written once per texture) and the UVs of its corners.
    fn ground(&mut self, g: &light::Ground) -> Result<serde_json::Value> {
        let ptr = Arc::as_ptr(&g.texture);
        let gi = match self.grounds.iter().position(|(p, _)| *p == ptr) {
            Some(k) => k,
            None => {
                let n = format!("ground{}.png", self.grounds.len());
                cac_core::io::save_png_atomic(&self.dir.join(&n), &g.texture.to_rgb8())?;
                self.grounds.push((ptr, n));
                self.grounds.len() - 1
            }
        };
        // cac's ground UV is (x, z + ...) shifted and scaled: linear, so exact at corners.
        const L: f32 = 1000.0;
        let uv = [(-L, -L), (L, -L), (L, L), (-L, L)]
            .map(|(x, z)| [(x + g.offset.x) / g.tile_m, (z + g.offset.y) / g.tile_m]);
        Ok(json!({ "texture": gi, "uv": uv }))
    }
}

/// A display value as the shading mode hands it to Blender (sRGB-decoded in linear mode).
fn decode(s: &BlenderSettings, x: f32) -> f32 {
    match s.shading {
        Shading::Linear => cac_core::colour::decode(x),
        Shading::Display | Shading::CacSurfaces | Shading::Cac => x,
    }
}

/// Writes the job and the script into `dir` and runs Blender headless on them.
fn run_blender(s: &BlenderSettings, dir: &Path, job: &serde_json::Value) -> Result<()> {
    let job_path = dir.join("job.json");
    cac_core::io::write_atomic(&job_path, serde_json::to_string_pretty(job)?.as_bytes())?;
    let script = dir.join("render_views.py");
    cac_core::io::write_atomic(&script, SCRIPT.as_bytes())?;
    let out = Command::new(&s.executable)
        .args([
            "-b",
            "--factory-startup",
            "-noaudio",
            "--python-exit-code",
            "3",
            "-P",
        ])
        .arg(&script)
        .arg("--")
        .arg(&job_path)
        .output()
        .with_context(|| format!("cannot run Blender ({})", s.executable.display()))?;
    if !out.status.success() {
        bail!(
            "Blender failed ({}) on {}:\n{}\n{}",
            out.status,
            job_path.display(),
            tail(&String::from_utf8_lossy(&out.stdout), 1500),
            tail(&String::from_utf8_lossy(&out.stderr), 2500)
        );
    }
    Ok(())
}

/// View `i` as Blender rendered it: composited over cac's own backdrop (none: Blender's image is
/// opaque, its own environment behind the object), with the condition's photometric transforms,
/// and the object's coverage and box from the mask layer.
fn read_view(
    r: &Renderer,
    dir: &Path,
    i: usize,
    cam: &Camera,
    backdrop: Option<&light::Backdrop>,
    cond: &Condition,
    device: &Device,
) -> Result<BlenderView> {
    let (w, h) = (r.settings.width, r.settings.height);
    let p = dir.join(format!("view{i:04}.png"));
    let rgba = image::open(&p)
        .with_context(|| format!("Blender wrote no readable image {}", p.display()))?
        .to_rgba32f();
    let mp = find_mask(dir, &format!("mask{i:04}_"))?;
    let mask = image::open(&mp)
        .with_context(|| format!("unreadable Blender mask {}", mp.display()))?
        .to_luma32f();
    if rgba.dimensions() != (w as u32, h as u32) || mask.dimensions() != rgba.dimensions() {
        bail!(
            "Blender image {} is {:?}, expected {w}x{h}",
            p.display(),
            rgba.dimensions()
        );
    }
    let mut data = vec![0.0f32; 3 * w * h];
    for (x, y, px) in rgba.enumerate_pixels() {
        let (xi, yi) = (x as usize, y as usize);
        let (bg, al) = match backdrop {
            Some(b) => {
                let dirv = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
                (
                    light::background_colour(&b.background, dirv, xi, yi, w, h),
                    px[3],
                )
            }
            None => ([0.0; 3], 1.0),
        };
        for c in 0..3 {
            data[(c * h + yi) * w + xi] = px[c] * al + bg[c] * (1.0 - al);
        }
    }
    let img = burn::tensor::Tensor::<4>::from_data(
        burn::tensor::TensorData::new(data, [1, 3, h, w]),
        device,
    );
    let img = environment::photometric(img, std::slice::from_ref(cond));
    let coverage: Vec<f32> = mask.pixels().map(|p| p[0]).collect();
    Ok(BlenderView {
        image: render::to_images(&img).remove(0),
        object_box: coverage_box(&coverage, w, 0.5 / 255.0),
        coverage,
    })
}

fn find_mask(dir: &Path, prefix: &str) -> Result<PathBuf> {
    for e in std::fs::read_dir(dir)? {
        let e = e?;
        let n = e.file_name().to_string_lossy().to_string();
        if n.starts_with(prefix) && n.ends_with(".png") {
            return Ok(e.path());
        }
    }
    bail!("Blender wrote no mask {prefix}*.png in {}", dir.display())
}

/// The tight box of the pixels whose coverage exceeds `eps`.
pub(crate) fn coverage_box(cov: &[f32], w: usize, eps: f32) -> Option<[f32; 4]> {
    let mut b: Option<[f32; 4]> = None;
    for (i, &c) in cov.iter().enumerate() {
        if c > eps {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            b = Some(match b {
                None => [x, y, x + 1.0, y + 1.0],
                Some(o) => [
                    o[0].min(x),
                    o[1].min(y),
                    o[2].max(x + 1.0),
                    o[3].max(y + 1.0),
                ],
            });
        }
    }
    b
}

/// Scores Blender views with each model against the views' own (Blender) boxes.
pub(crate) fn score_views(
    views: &[BlenderView],
    dets: &[&dyn Detector],
    p: &Protocol,
    device: &Device,
) -> Result<Vec<Vec<ImageScore>>> {
    let mut out = vec![vec![]; dets.len()];
    let scorer = Scorer::new(dets, p)?;
    for (i, v) in views.iter().enumerate() {
        let gt = v
            .object_box
            .with_context(|| format!("Blender view {i}: the object is not visible"))?;
        let t = cac_detect::preprocess::image_to_tensor(&v.image, device);
        for (m, o) in scorer.frame(t, &gt, None)?.into_iter().enumerate() {
            out[m].push(o.score);
        }
    }
    Ok(out)
}
