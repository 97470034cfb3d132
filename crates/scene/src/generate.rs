//! The project's default objects, generated in code and committed under `meshes/` as OBJ + MTL +
//! PNG (`cac meshes generate`): a jeep-like vehicle, a barrel and a shipping container.
//!
//! Every part is a closed prism (a 2D profile extruded along an axis), so each part is a closed,
//! consistently oriented shell. Paintable faces are packed into one UV atlas (shelf packing, area
//! proportional to metres), so a texel covers about the same surface everywhere.

use super::polygon::{ear_clip, OnEdge};
use crate::material::Material;
use crate::mesh::{Scene, Triangle};
use crate::texture::Texture;
use glam::{Mat4, Vec2, Vec3};

/// Builds a scene part by part and packs the paintable faces into one atlas at the end.
struct Builder {
    scene: Scene,
    /// For each paintable face: its UV indices and its local rectangle (min, max) in metres.
    faces: Vec<(Vec<u32>, Vec2, Vec2)>,
    /// Curvature of the next prisms' caps (shading normals only): the cap's normal tilts up
    /// towards its top edge and down towards its bottom by up to this much (0 = flat).
    cap_bulge: f32,
}

impl Builder {
    fn new(name: &str) -> Self {
        Builder {
            scene: Scene::empty(name),
            faces: vec![],
            cap_bulge: 0.0,
        }
    }

    fn material(
        &mut self,
        name: &str,
        color: [f32; 3],
        specular: f32,
        shininess: f32,
        paint: bool,
    ) -> u32 {
        if let Some(i) = self.scene.materials.iter().position(|m| m.name == name) {
            return i as u32;
        }
        self.scene.materials.push(Material {
            name: name.into(),
            base_color: color,
            texture: None,
            specular,
            shininess,
        });
        self.scene.paintable.push(paint);
        (self.scene.materials.len() - 1) as u32
    }

    /// Adds a triangle, flipping it if needed so that its normal points along `outward`.
    fn tri(
        &mut self,
        mut p: [u32; 3],
        mut uv: Option<[u32; 3]>,
        mut n: Option<[u32; 3]>,
        material: u32,
        outward: Vec3,
    ) {
        let [a, b, c] = p.map(|i| self.scene.positions[i as usize]);
        if (b - a).cross(c - a).dot(outward) < 0.0 {
            p.swap(1, 2);
            if let Some(u) = uv.as_mut() {
                u.swap(1, 2);
            }
            if let Some(nn) = n.as_mut() {
                nn.swap(1, 2);
            }
        }
        self.scene.triangles.push(Triangle { p, uv, n, material });
    }

    /// Extrudes a counter-clockwise 2D profile (x, y) from z0 to z1, transformed by `m`.
    /// `smooth` gives the side faces per-vertex normals (cylinders). Paintable materials get UVs.
    #[allow(clippy::too_many_arguments)]
    fn prism(
        &mut self,
        profile: &[Vec2],
        z0: f32,
        z1: f32,
        m: Mat4,
        side_mat: u32,
        cap_mat: u32,
        smooth: bool,
    ) {
        let base = self.scene.positions.len() as u32;
        for &q in profile {
            self.scene
                .positions
                .push(m.transform_point3(Vec3::new(q.x, q.y, z0)));
            self.scene
                .positions
                .push(m.transform_point3(Vec3::new(q.x, q.y, z1)));
        }
        let nm = m.inverse().transpose();
        self.prism_sides(profile, (z0, z1), nm, base, side_mat, smooth);
        self.prism_caps(profile, (z0, z1), nm, base, cap_mat);
    }

    /// The side faces of [`Self::prism`] (its positions from `base`; `nm` the normal matrix).
    fn prism_sides(
        &mut self,
        profile: &[Vec2],
        (z0, z1): (f32, f32),
        nm: Mat4,
        base: u32,
        side_mat: u32,
        smooth: bool,
    ) {
        let n = profile.len();
        let centre2 = profile.iter().copied().sum::<Vec2>() / n as f32;
        let side_paint = self.scene.paintable[side_mat as usize];
        let mut along = 0.0f32;
        for i in 0..n {
            let j = (i + 1) % n;
            let (a0, a1, b0, b1) = (
                base + 2 * i as u32,
                base + 2 * i as u32 + 1,
                base + 2 * j as u32,
                base + 2 * j as u32 + 1,
            );
            let d = profile[j] - profile[i];
            let out2 = Vec2::new(d.y, -d.x).normalize_or_zero();
            let outward = nm
                .transform_vector3(Vec3::new(out2.x, out2.y, 0.0))
                .normalize_or_zero();
            let len = d.length();
            let uv = if side_paint {
                let u0 = self.scene.uvs.len() as u32;
                let w = (z1 - z0).abs();
                for t in [
                    Vec2::new(along, 0.0),
                    Vec2::new(along, w),
                    Vec2::new(along + len, 0.0),
                    Vec2::new(along + len, w),
                ] {
                    self.scene.uvs.push(t);
                }
                self.faces.push((
                    (u0..u0 + 4).collect(),
                    Vec2::new(along, 0.0),
                    Vec2::new(along + len, w),
                ));
                Some([u0, u0 + 1, u0 + 2, u0 + 3])
            } else {
                None
            };
            along += len;
            let nrm = if smooth {
                let n0 = self.scene.normals.len() as u32;
                for q in [profile[i], profile[j]] {
                    let r = (q - centre2).normalize_or_zero();
                    self.scene.normals.push(
                        nm.transform_vector3(Vec3::new(r.x, r.y, 0.0))
                            .normalize_or_zero(),
                    );
                }
                Some([n0, n0, n0 + 1, n0 + 1])
            } else {
                None
            };
            let pick = |k: [usize; 3], arr: Option<[u32; 4]>| arr.map(|a| k.map(|x| a[x]));
            let idx = [a0, a1, b0, b1];
            self.tri(
                [0, 2, 3].map(|k| idx[k]),
                pick([0, 2, 3], uv),
                pick([0, 2, 3], nrm),
                side_mat,
                outward,
            );
            self.tri(
                [0, 3, 1].map(|k| idx[k]),
                pick([0, 3, 1], uv),
                pick([0, 3, 1], nrm),
                side_mat,
                outward,
            );
        }
    }

    /// The two caps of [`Self::prism`], by ear clipping (the back one's UVs mirrored).
    fn prism_caps(
        &mut self,
        profile: &[Vec2],
        (z0, z1): (f32, f32),
        nm: Mat4,
        base: u32,
        cap_mat: u32,
    ) {
        let n = profile.len();
        let cap_paint = self.scene.paintable[cap_mat as usize];
        let ears = ear_clip(profile, OnEdge::Allowed);
        let (lo, hi) = profile.iter().fold(
            (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN)),
            |(l, h), &q| (l.min(q), h.max(q)),
        );
        for (cap, z_off, dir) in [(0u32, 0u32, -1.0f32), (1, 1, 1.0)] {
            let _ = cap;
            let outward = nm
                .transform_vector3(Vec3::new(0.0, 0.0, dir * (z1 - z0).signum()))
                .normalize_or_zero();
            let uv0 = self.scene.uvs.len() as u32;
            if cap_paint {
                // Mirror the back cap so the texture reads the right way round from outside.
                for &q in profile {
                    let u = if dir > 0.0 { q.x - lo.x } else { hi.x - q.x };
                    self.scene.uvs.push(Vec2::new(u, q.y - lo.y));
                }
                self.faces
                    .push(((uv0..uv0 + n as u32).collect(), Vec2::ZERO, hi - lo));
            }
            let n0 = self.scene.normals.len() as u32;
            let bulge = self.cap_bulge;
            if bulge > 0.0 {
                let (cy, hy) = (0.5 * (lo.y + hi.y), 0.5 * (hi.y - lo.y).max(1e-6));
                for &q in profile {
                    let t = ((q.y - cy) / hy).clamp(-1.0, 1.0);
                    let local = Vec3::new(0.0, bulge * t, dir * (z1 - z0).signum());
                    self.scene
                        .normals
                        .push(nm.transform_vector3(local).normalize_or_zero());
                }
            }
            for e in &ears {
                let p = e.map(|k| base + 2 * k as u32 + z_off);
                let uv = cap_paint.then(|| e.map(|k| uv0 + k as u32));
                let nrm = (bulge > 0.0).then(|| e.map(|k| n0 + k as u32));
                self.tri(p, uv, nrm, cap_mat, outward);
            }
        }
    }

    /// A box from `lo` to `hi` (axis-aligned in the frame `m`).
    fn cuboid(&mut self, lo: Vec3, hi: Vec3, m: Mat4, mat: u32) {
        let prof = [
            Vec2::new(lo.x, lo.y),
            Vec2::new(hi.x, lo.y),
            Vec2::new(hi.x, hi.y),
            Vec2::new(lo.x, hi.y),
        ];
        self.prism(&prof, lo.z, hi.z, m, mat, mat, false);
    }

    /// A cylinder of radius `r` around the Z axis of frame `m`, from z0 to z1.
    #[allow(clippy::too_many_arguments)]
    fn cylinder(
        &mut self,
        r: f32,
        z0: f32,
        z1: f32,
        segments: usize,
        m: Mat4,
        side: u32,
        cap: u32,
    ) {
        let prof: Vec<Vec2> = (0..segments)
            .map(|i| {
                let a = i as f32 / segments as f32 * std::f32::consts::TAU;
                Vec2::new(r * a.cos(), r * a.sin())
            })
            .collect();
        self.prism(&prof, z0, z1, m, side, cap, true);
    }

    /// Packs the paintable faces into [0,1]² (shelf packing with a gutter) and attaches an atlas
    /// texture of `res x res` filled by `paint(u, v)` to every paintable material.
    fn finish(mut self, res: usize, paint: impl Fn(f32, f32) -> [f32; 3]) -> Scene {
        let gutter = 4.0 / res as f32;
        let sizes: Vec<Vec2> = self.faces.iter().map(|(_, lo, hi)| *hi - *lo).collect();
        let area: f32 = sizes.iter().map(|s| s.x * s.y).sum();
        // Find the largest scale at which the shelves fit.
        let mut scale = 0.95 / area.sqrt().max(1e-6);
        let mut order: Vec<usize> = (0..sizes.len()).collect();
        order.sort_by(|&a, &b| sizes[b].y.total_cmp(&sizes[a].y));
        let offsets = loop {
            let (mut x, mut y, mut shelf_h) = (gutter, gutter, 0.0f32);
            let mut off = vec![Vec2::ZERO; sizes.len()];
            let mut ok = true;
            for &i in &order {
                let s = sizes[i] * scale;
                if x + s.x + gutter > 1.0 {
                    x = gutter;
                    y += shelf_h + gutter;
                    shelf_h = 0.0;
                }
                if s.x + 2.0 * gutter > 1.0 || y + s.y + gutter > 1.0 {
                    ok = false;
                    break;
                }
                off[i] = Vec2::new(x, y);
                x += s.x + gutter;
                shelf_h = shelf_h.max(s.y);
            }
            if ok {
                break off;
            }
            scale *= 0.97;
        };
        for (i, (uvs, lo, _)) in self.faces.iter().enumerate() {
            for &k in uvs {
                let t = &mut self.scene.uvs[k as usize];
                *t = offsets[i] + (*t - *lo) * scale;
            }
        }
        let mut atlas = Texture::solid(res, res, [0.0; 3]);
        for y in 0..res {
            for x in 0..res {
                atlas.texels[y * res + x] = paint(
                    (x as f32 + 0.5) / res as f32,
                    1.0 - (y as f32 + 0.5) / res as f32,
                );
            }
        }
        self.scene.textures.push(atlas);
        let ti = self.scene.textures.len() - 1;
        for (m, &p) in self.scene.materials.iter_mut().zip(&self.scene.paintable) {
            if p {
                m.texture = Some(ti);
                m.base_color = [1.0; 3];
            }
        }
        self.scene
    }
}

fn v2(x: f32, y: f32) -> Vec2 {
    Vec2::new(x, y)
}

/// Cheap deterministic value noise in [0, 1] for procedural textures.
pub fn value_noise(x: f32, y: f32, seed: u32) -> f32 {
    let h = |ix: i32, iy: i32| {
        let mut k = (ix as u32).wrapping_mul(0x8da6b343)
            ^ (iy as u32).wrapping_mul(0xd8163841)
            ^ seed.wrapping_mul(0xcb1ab31f);
        k ^= k >> 13;
        k = k.wrapping_mul(0x5bd1e995);
        k ^= k >> 15;
        (k & 0xffff) as f32 / 65535.0
    };
    let (x0, y0) = (x.floor() as i32, y.floor() as i32);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let top = h(x0, y0) * (1.0 - sx) + h(x0 + 1, y0) * sx;
    let bot = h(x0, y0 + 1) * (1.0 - sx) + h(x0 + 1, y0 + 1) * sx;
    top * (1.0 - sy) + bot * sy
}

/// A jeep-like vehicle, 4.3 m long, front towards +X: body and cab (paintable), windows, wheels
/// with rims, head and tail lights, grille, bumpers and a spare wheel.
pub fn jeep() -> Scene {
    vehicle(false)
}

/// A jeep-style pickup (short cab and a covered load bed), 4.3 m long, front towards +X.
pub fn pickup() -> Scene {
    vehicle(true)
}

fn vehicle(pickup: bool) -> Scene {
    let mut b = Builder::new(if pickup { "pickup" } else { "jeep" });
    // Created in this order (the order of the materials in the file).
    let look = VehicleLook {
        body: b.material("body_paint", [1.0; 3], 0.25, 40.0, true),
        glass: b.material("window_glass", [0.08, 0.10, 0.12], 0.9, 120.0, false),
        tyre: b.material("wheel_tyre", [0.05, 0.05, 0.05], 0.03, 8.0, false),
        rim: b.material("wheel_rim", [0.55, 0.56, 0.58], 0.6, 60.0, false),
        head: b.material("headlight", [0.95, 0.95, 0.88], 0.9, 100.0, false),
        tail: b.material("taillight", [0.75, 0.05, 0.04], 0.6, 80.0, false),
        trim: b.material("trim_black", [0.07, 0.07, 0.075], 0.1, 16.0, false),
    };
    body_shell(&mut b, pickup, &look);
    windows(&mut b, pickup, &look);
    lights_and_bumpers(&mut b, &look);
    wheels(&mut b, &look);
    doors(&mut b, pickup, &look);
    plates_and_mirrors(&mut b, &look);
    if !pickup {
        spare_wheel(&mut b, &look);
    }
    b.finish(512, body_paint)
}

/// The vehicles' materials (indices into the builder's list).
struct VehicleLook {
    body: u32,
    glass: u32,
    tyre: u32,
    rim: u32,
    head: u32,
    tail: u32,
    trim: u32,
}

/// Half the body's width and a panel's thickness (m).
const HW: f32 = 0.9;
const ZW: f32 = 0.006;

/// The body: the side profile (x forward, y up), counter-clockwise — underbody, nose, hood,
/// windshield, then the roof and back, which differ between the two styles — extruded across
/// the width. The sill runs 0.30 m above the ground and arches over each wheel (radius 0.47
/// around the axle), so the upper part of the wheels sits in wheel wells as on a real vehicle.
fn body_shell(b: &mut Builder, pickup: bool, look: &VehicleLook) {
    let id = Mat4::IDENTITY;
    let mut profile = vec![v2(-2.15, 0.30)];
    for axle in [-1.35f32, 1.35] {
        let (r, y0) = (0.47f32, 0.40f32);
        let start = std::f32::consts::PI + ((y0 - 0.30) / r).asin();
        let end = -((y0 - 0.30) / r).asin();
        for k in 0..=12 {
            let a = start + (end - start) * k as f32 / 12.0;
            profile.push(v2(axle + r * a.cos(), y0 + r * a.sin()));
        }
    }
    profile.extend([
        v2(2.05, 0.30),
        v2(2.15, 0.50),
        v2(2.15, 0.92),
        v2(2.05, 1.02),
        v2(0.95, 1.10),
        v2(0.38, 1.80),
    ]);
    profile.extend(if pickup {
        // Short cab, then a covered load bed at waist height.
        [v2(-0.72, 1.84), v2(-0.80, 1.16), v2(-2.15, 1.12)]
    } else {
        [v2(-1.95, 1.84), v2(-2.12, 1.77), v2(-2.15, 1.02)]
    });
    // Body sides curve like real panels (shading normals): the upper part faces the sky, the
    // lower part the ground, so reflections and light grade down the side.
    b.cap_bulge = 0.45;
    b.prism(&profile, -HW, HW, id, look.body, look.body, false);
    b.cap_bulge = 0.0;
}

/// Side windows, windshield and rear window.
fn windows(b: &mut Builder, pickup: bool, look: &VehicleLook) {
    let id = Mat4::IDENTITY;
    // Side windows (thin closed panels on both sides).
    let front_win = [
        v2(0.80, 1.17),
        v2(0.36, 1.72),
        v2(-0.50, 1.74),
        v2(-0.50, 1.17),
    ];
    let rear_win = [
        v2(-0.62, 1.17),
        v2(-0.62, 1.74),
        v2(-1.88, 1.76),
        v2(-1.88, 1.17),
    ];
    let side_windows: Vec<&[Vec2]> = if pickup {
        vec![&front_win[..]]
    } else {
        vec![&front_win[..], &rear_win[..]]
    };
    for w in side_windows {
        b.prism(w, HW, HW + ZW, id, look.glass, look.glass, false);
        b.prism(w, -HW - ZW, -HW, id, look.glass, look.glass, false);
    }
    // Windshield and rear window: panels lying on the slanted / back faces.
    let panel_on = |b: &mut Builder, p: Vec2, q: Vec2, t0: f32, t1: f32, z: f32, mat: u32| {
        let d = (q - p).normalize();
        let n = Vec2::new(d.y, -d.x);
        let a = p + (q - p) * t0;
        let c = p + (q - p) * t1;
        let prof = [a, c, c + n * ZW * 1.5, a + n * ZW * 1.5];
        // Keep the profile counter-clockwise.
        let area: f32 = (0..4).map(|i| prof[i].perp_dot(prof[(i + 1) % 4])).sum();
        let prof: Vec<Vec2> = if area < 0.0 {
            prof.iter().rev().copied().collect()
        } else {
            prof.to_vec()
        };
        b.prism(&prof, -z, z, Mat4::IDENTITY, mat, mat, false);
    };
    panel_on(
        b,
        v2(0.95, 1.10),
        v2(0.38, 1.80),
        0.06,
        0.94,
        0.80,
        look.glass,
    );
    if pickup {
        panel_on(
            b,
            v2(-0.72, 1.84),
            v2(-0.80, 1.16),
            0.08,
            0.55,
            0.72,
            look.glass,
        );
    } else {
        panel_on(
            b,
            v2(-2.12, 1.77),
            v2(-2.15, 1.02),
            0.06,
            0.50,
            0.72,
            look.glass,
        );
    }
}

fn lights_and_bumpers(b: &mut Builder, look: &VehicleLook) {
    let id = Mat4::IDENTITY;
    // Lights, grille, bumpers.
    for s in [1.0f32, -1.0] {
        let (za, zb) = if s > 0.0 {
            (0.50, 0.80)
        } else {
            (-0.80, -0.50)
        };
        b.prism(
            &[
                v2(2.15, 0.72),
                v2(2.165, 0.72),
                v2(2.165, 0.88),
                v2(2.15, 0.88),
            ],
            za,
            zb,
            id,
            look.head,
            look.head,
            false,
        );
        b.prism(
            &[
                v2(-2.165, 0.80),
                v2(-2.15, 0.80),
                v2(-2.15, 0.98),
                v2(-2.165, 0.98),
            ],
            za + s * 0.05,
            zb + s * 0.05,
            id,
            look.tail,
            look.tail,
            false,
        );
    }
    b.prism(
        &[
            v2(2.15, 0.60),
            v2(2.162, 0.60),
            v2(2.162, 0.90),
            v2(2.15, 0.90),
        ],
        -0.38,
        0.38,
        id,
        look.trim,
        look.trim,
        false,
    );
    b.cuboid(
        Vec3::new(2.10, 0.32, -0.92),
        Vec3::new(2.30, 0.52, 0.92),
        id,
        look.trim,
    );
    b.cuboid(
        Vec3::new(-2.28, 0.32, -0.92),
        Vec3::new(-2.10, 0.52, 0.92),
        id,
        look.trim,
    );
}

fn wheels(b: &mut Builder, look: &VehicleLook) {
    let id = Mat4::IDENTITY;
    // Wheels: tyres and rims, axis along Z.
    for x in [1.35f32, -1.35] {
        for s in [1.0f32, -1.0] {
            let m = Mat4::from_translation(Vec3::new(x, 0.40, 0.0));
            let (z0, z1) = if s > 0.0 {
                (0.62, 0.90)
            } else {
                (-0.90, -0.62)
            };
            b.cylinder(0.40, z0, z1, 32, m, look.tyre, look.tyre);
            let (r0, r1) = if s > 0.0 {
                (0.90, 0.915)
            } else {
                (-0.915, -0.90)
            };
            b.cylinder(0.22, r0, r1, 24, m, look.rim, look.rim);
        }
        // The dark wheel wells: a half ring behind each look.tyre fills the arch above it.
        let (a0, a1) = ((-15.0f32).to_radians(), 195.0f32.to_radians());
        let arc = |r: f32, k: usize| {
            let a = a0 + (a1 - a0) * k as f32 / 16.0;
            v2(x + r * a.cos(), 0.40 + r * a.sin())
        };
        let well: Vec<Vec2> = (0..=16)
            .map(|k| arc(0.465, k))
            .chain((0..=16).rev().map(|k| arc(0.38, k)))
            .collect();
        b.prism(&well, 0.585, 0.61, id, look.trim, look.trim, false);
        b.prism(&well, -0.61, -0.585, id, look.trim, look.trim, false);
    }
}

fn doors(b: &mut Builder, pickup: bool, look: &VehicleLook) {
    let id = Mat4::IDENTITY;
    // Door gaps (dark lines a few millimetres proud of the panel) and door handles.
    let doors: &[(f32, f32)] = if pickup {
        &[(0.92, -0.62)]
    } else {
        &[(0.92, -0.56), (-0.60, -1.62)]
    };
    for &(front, back) in doors {
        for s in [1.0f32, -1.0] {
            let (z0, z1) = if s > 0.0 {
                (HW, HW + 0.004)
            } else {
                (-HW - 0.004, -HW)
            };
            for x in [front, back] {
                b.cuboid(
                    Vec3::new(x - 0.006, 0.34, z0),
                    Vec3::new(x + 0.006, 1.12, z1),
                    id,
                    look.trim,
                );
            }
            let (h0, h1) = if s > 0.0 {
                (HW - 0.002, HW + 0.012)
            } else {
                (-HW - 0.012, -HW + 0.002)
            };
            b.cuboid(
                Vec3::new(back + 0.10, 0.96, h0),
                Vec3::new(back + 0.28, 1.01, h1),
                id,
                look.trim,
            );
        }
    }
}

fn plates_and_mirrors(b: &mut Builder, look: &VehicleLook) {
    let id = Mat4::IDENTITY;
    // Licence plates, front and back, and the door mirrors.
    let plate = b.material("licence_plate", [0.88, 0.88, 0.84], 0.3, 30.0, false);
    b.cuboid(
        Vec3::new(2.30, 0.36, -0.26),
        Vec3::new(2.312, 0.48, 0.26),
        id,
        plate,
    );
    b.cuboid(
        Vec3::new(-2.292, 0.36, -0.26),
        Vec3::new(-2.28, 0.48, 0.26),
        id,
        plate,
    );
    for s in [1.0f32, -1.0] {
        let (z0, z1) = if s > 0.0 {
            (0.90, 1.08)
        } else {
            (-1.08, -0.90)
        };
        b.cuboid(
            Vec3::new(0.80, 1.14, z0),
            Vec3::new(0.92, 1.26, z1),
            id,
            look.trim,
        );
    }
}

/// The spare wheel on the back (the jeep only).
fn spare_wheel(b: &mut Builder, look: &VehicleLook) {
    let m = Mat4::from_translation(Vec3::new(-2.15, 1.25, 0.0))
        * Mat4::from_rotation_y(std::f32::consts::FRAC_PI_2);
    b.cylinder(0.36, 0.0, 0.26, 28, m, look.tyre, look.tyre);
    b.cylinder(0.20, 0.26, 0.28, 20, m, look.rim, look.rim);
}

/// Body colour: a painted red with faint mottling, like weathered paint.
fn body_paint(u: f32, v: f32) -> [f32; 3] {
    let n = value_noise(u * 40.0, v * 40.0, 7) * 0.5 + value_noise(u * 160.0, v * 160.0, 9) * 0.5;
    let k = 0.92 + 0.16 * n;
    [0.62 * k, 0.09 * k, 0.08 * k]
}

/// A 200-litre steel drum (0.58 m across, 0.88 m tall) with two rolling hoops; the shell is paintable.
pub fn barrel() -> Scene {
    let mut b = Builder::new("barrel");
    let shell = b.material("barrel_shell", [1.0; 3], 0.35, 40.0, true);
    let hoop = b.material("barrel_rim", [0.25, 0.27, 0.30], 0.5, 40.0, false);
    let up = Mat4::from_rotation_x(-std::f32::consts::FRAC_PI_2);
    b.cylinder(0.29, 0.0, 0.88, 48, up, shell, shell);
    for y in [0.29f32, 0.59] {
        b.cylinder(0.297, y, y + 0.025, 48, up, hoop, hoop);
    }
    b.finish(512, |u, v| {
        let k = 0.9 + 0.2 * value_noise(u * 30.0, v * 30.0, 3);
        [0.10 * k, 0.25 * k, 0.55 * k]
    })
}

/// A 20-foot shipping container (6.06 x 2.44 x 2.59 m), paintable walls, door bars at the back.
pub fn container() -> Scene {
    let mut b = Builder::new("container");
    let walls = b.material("container_walls", [1.0; 3], 0.2, 20.0, true);
    let bars = b.material("door_trim", [0.2, 0.2, 0.22], 0.3, 30.0, false);
    b.cuboid(
        Vec3::new(-3.03, 0.0, -1.22),
        Vec3::new(3.03, 2.59, 1.22),
        Mat4::IDENTITY,
        walls,
    );
    for z in [-0.8f32, -0.35, 0.35, 0.8] {
        b.cuboid(
            Vec3::new(-3.06, 0.1, z - 0.03),
            Vec3::new(-3.03, 2.49, z + 0.03),
            Mat4::IDENTITY,
            bars,
        );
    }
    b.finish(512, |u, v| {
        // Corrugation: vertical stripes in the atlas's u direction.
        let stripe = 0.9 + 0.1 * (u * 512.0 / 6.0).sin().signum();
        let k = stripe * (0.92 + 0.16 * value_noise(u * 50.0, v * 50.0, 5));
        [0.70 * k, 0.33 * k, 0.12 * k]
    })
}

/// The default objects by name.
pub fn by_name(name: &str) -> Option<Scene> {
    match name {
        "jeep" => Some(jeep()),
        "pickup" => Some(pickup()),
        "barrel" => Some(barrel()),
        "container" => Some(container()),
        _ => None,
    }
}

/// The names of the default objects.
pub const DEFAULT_OBJECTS: [&str; 4] = ["jeep", "pickup", "barrel", "container"];

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// Every edge of a closed, consistently oriented shell appears once in each direction.
    fn assert_closed_oriented(s: &Scene) {
        let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
        for t in &s.triangles {
            for k in 0..3 {
                *edges.entry((t.p[k], t.p[(k + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &c) in &edges {
            assert_eq!(c, 1, "edge {a}->{b} used {c} times");
            assert_eq!(
                edges.get(&(b, a)),
                Some(&1),
                "edge {a}->{b} has no twin: open or flipped"
            );
        }
    }

    #[test]
    fn default_objects_are_closed_and_outward_facing() {
        for name in DEFAULT_OBJECTS {
            let s = by_name(name).unwrap();
            s.validate().unwrap();
            assert_closed_oriented(&s);
            // Outward orientation: the signed volume is positive.
            let vol: f32 = s
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.p.map(|i| s.positions[i as usize]);
                    a.dot(b.cross(c)) / 6.0
                })
                .sum();
            assert!(vol > 0.0, "{name}: negative volume {vol}");
        }
    }

    #[test]
    fn paintable_uvs_are_inside_the_atlas_and_faces_do_not_overlap() {
        let s = jeep();
        let mut covered = vec![0u8; 256 * 256];
        for t in s.triangles.iter().filter(|t| s.is_paintable(t)) {
            let uv = t.uv.unwrap().map(|i| s.uvs[i as usize]);
            for q in uv {
                assert!(
                    (0.0..=1.0).contains(&q.x) && (0.0..=1.0).contains(&q.y),
                    "{q:?}"
                );
            }
            // Rasterise the UV triangle's centroid neighbourhood coarsely.
            let c = (uv[0] + uv[1] + uv[2]) / 3.0;
            let _ = c;
        }
        // Rasterise each paintable triangle in UV space and count texels claimed twice.
        let mut overlap = 0;
        for t in s.triangles.iter().filter(|t| s.is_paintable(t)) {
            let [a, b, c] = t.uv.unwrap().map(|i| s.uvs[i as usize] * 256.0);
            let area = (b - a).perp_dot(c - a);
            if area.abs() < 1e-6 {
                continue;
            }
            for y in 0..256 {
                for x in 0..256 {
                    let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    let w0 = (b - p).perp_dot(c - p) / area;
                    let w1 = (c - p).perp_dot(a - p) / area;
                    let w2 = 1.0 - w0 - w1;
                    if w0 > 0.01 && w1 > 0.01 && w2 > 0.01 {
                        covered[y * 256 + x] += 1;
                        if covered[y * 256 + x] > 1 {
                            overlap += 1;
                        }
                    }
                }
            }
        }
        assert_eq!(overlap, 0, "atlas faces overlap");
        let used = covered.iter().filter(|&&c| c > 0).count();
        assert!(used > 256 * 256 / 3, "atlas poorly used: {used} texels");
    }
}
