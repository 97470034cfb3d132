//! Ray casting against a scene: a compressed wide BVH (CWBVH, `obvhs`) over the scene's triangles,
//! closest-hit queries with barycentrics, and any-hit (shadow) queries.
//!
//! The triangle test is Möller–Trumbore with a relative determinant cut-off, so zero-area and
//! edge-on triangles are never hit (no NaN barycentrics).

use crate::scene::Scene;
use glam::{Vec2, Vec3, Vec3A};
use obvhs::{
    cwbvh::builder::build_cwbvh_from_tris, cwbvh::CwBvh, ray::Ray, ray::RayHit, BvhBuildParams,
};
use std::time::Duration;

/// A closest hit: scene triangle index, distance, and barycentrics `(b1, b2)` of corners 1 and 2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub tri: u32,
    pub t: f32,
    pub bary: Vec2,
}

/// The acceleration structure of one scene.
pub struct Accel {
    bvh: CwBvh,
    /// Triangles in BVH primitive order (so traversal reads them sequentially).
    tris: Vec<[Vec3A; 3]>,
    /// Scene triangle index of each BVH primitive.
    ids: Vec<u32>,
}

#[inline(always)]
fn intersect(t: &[Vec3A; 3], o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
    let e1 = t[1] - t[0];
    let e2 = t[2] - t[0];
    let p = d.cross(e2);
    let det = e1.dot(p);
    // Relative cut-off: rejects degenerate triangles and rays in the triangle's plane.
    if det.abs() <= 1e-12 * e1.length_squared().max(e2.length_squared()).max(1e-30) {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - t[0];
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let tt = e2.dot(q) * inv;
    (tt > tmin && tt < tmax && tt.is_finite()).then_some((tt, u, v))
}

impl Accel {
    /// Builds the BVH (time it with [`Accel::build_timed`]).
    pub fn build(scene: &Scene) -> Accel {
        Self::build_timed(scene).0
    }

    /// Builds the BVH and returns the build's wall time.
    pub fn build_timed(scene: &Scene) -> (Accel, Duration) {
        let start = std::time::Instant::now();
        let tris: Vec<obvhs::triangle::Triangle> = scene
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.p.map(|i| Vec3A::from(scene.positions[i as usize]));
                obvhs::triangle::Triangle {
                    v0: a,
                    v1: b,
                    v2: c,
                }
            })
            .collect();
        let bvh = build_cwbvh_from_tris(
            &tris,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let ids: Vec<u32> = bvh.primitive_indices.clone();
        let ordered = ids.iter().map(|&i| {
            let t = &tris[i as usize];
            [t.v0, t.v1, t.v2]
        });
        let accel = Accel {
            tris: ordered.collect(),
            ids,
            bvh,
        };
        (accel, start.elapsed())
    }

    /// The closest hit along `origin + t * dir` for `t` in `(tmin, tmax)`.
    pub fn closest(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        let (o, d) = (Vec3A::from(origin), Vec3A::from(dir));
        let ray = Ray::new(o, d, tmin, tmax);
        let mut hit = RayHit::none();
        let mut best = (0.0f32, 0.0f32);
        let found = self.bvh.ray_traverse(ray, &mut hit, |r, id| {
            match intersect(&self.tris[id], o, d, tmin, r.tmax) {
                Some((t, u, v)) => {
                    best = (u, v);
                    t
                }
                None => f32::INFINITY,
            }
        });
        if !found {
            return None;
        }
        // `best` belongs to the last accepted (closest) primitive only if it was the last
        // improvement; recompute for the final primitive to be exact.
        let id = hit.primitive_id as usize;
        let (t, u, v) =
            intersect(&self.tris[id], o, d, tmin, tmax).unwrap_or((hit.t, best.0, best.1));
        Some(Hit {
            tri: self.ids[id],
            t,
            bary: Vec2::new(u, v),
        })
    }

    /// Is anything hit along the ray for `t` in `(tmin, tmax)`? (shadow rays)
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> bool {
        let (o, d) = (Vec3A::from(origin), Vec3A::from(dir));
        let ray = Ray::new(o, d, tmin, tmax);
        !self.bvh.ray_traverse_miss(ray, |r, id| {
            intersect(&self.tris[id], o, d, tmin, r.tmax)
                .map(|h| h.0)
                .unwrap_or(f32::INFINITY)
        })
    }

    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }
}
