//! Ray casting against a scene: a compressed wide BVH (CWBVH, `obvhs`) over the scene's triangles,
//! closest-hit queries with barycentrics, and any-hit (shadow) queries.
//!
//! The triangle test is Cramer's rule with a precomputed normal (one cross product per test) and
//! a relative determinant cut-off, so zero-area and edge-on triangles are never hit (no NaN
//! barycentrics).

use cac_scene::Scene;
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

/// A triangle prepared for ray tests: vertex 0, both edges, the (unnormalised) normal and a
/// determinant threshold; `eps < 0` marks a zero-area triangle, which is never hit.
#[derive(Clone, Copy)]
struct Prepared {
    v0: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
    n: Vec3A,
    eps: f32,
}

impl Prepared {
    fn new(a: Vec3A, b: Vec3A, c: Vec3A) -> Self {
        let (e1, e2) = (b - a, c - a);
        let n = e1.cross(e2);
        let len = n.length();
        let scale = e1.length_squared().max(e2.length_squared());
        let eps = if len > 1e-12 * scale && len.is_finite() {
            1e-9 * len
        } else {
            -1.0
        };
        Prepared {
            v0: a,
            e1,
            e2,
            n,
            eps,
        }
    }
}

/// Ray–triangle test: `(t, b1, b2)` for a hit with `tmin < t < tmax`.
#[inline(always)]
fn intersect(t: &Prepared, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
    let det = d.dot(t.n);
    if !(det.abs() > t.eps) {
        return None;
    }
    let inv = 1.0 / det;
    let c = t.v0 - o;
    let r = d.cross(c);
    let u = -t.e2.dot(r) * inv;
    let v = t.e1.dot(r) * inv;
    if u < 0.0 || v < 0.0 || u + v > 1.0 {
        return None;
    }
    let tt = c.dot(t.n) * inv;
    (tt > tmin && tt < tmax).then_some((tt, u, v))
}

/// The acceleration structure of one scene.
pub struct Accel {
    bvh: CwBvh,
    /// Triangles in BVH primitive order (so traversal reads them sequentially).
    tris: Vec<Prepared>,
    /// Scene triangle index of each BVH primitive.
    ids: Vec<u32>,
}

impl Accel {
    /// Builds the BVH.
    pub fn build(scene: &Scene) -> Accel {
        Self::build_timed(scene).0
    }

    /// Builds the BVH and returns the build's wall time.
    pub(crate) fn build_timed(scene: &Scene) -> (Accel, Duration) {
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
            BvhBuildParams::very_slow_build(),
            &mut Duration::default(),
        );
        let ids: Vec<u32> = bvh.primitive_indices.clone();
        let prepared = ids
            .iter()
            .map(|&i| {
                let t = &tris[i as usize];
                Prepared::new(t.v0, t.v1, t.v2)
            })
            .collect();
        (
            Accel {
                tris: prepared,
                ids,
                bvh,
            },
            start.elapsed(),
        )
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
        // Every finite value the closure returns is closer than the current best and is accepted
        // by the traversal, so `best` belongs to the closest hit.
        found.then(|| Hit {
            tri: self.ids[hit.primitive_id as usize],
            t: hit.t,
            bary: Vec2::new(best.0, best.1),
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn barycentrics_and_distance_are_exact_on_a_known_triangle() {
        let t = Prepared::new(Vec3A::ZERO, Vec3A::X, Vec3A::Y);
        let (tt, u, v) = intersect(&t, Vec3A::new(0.2, 0.3, 1.0), Vec3A::NEG_Z, 0.0, 10.0).unwrap();
        assert!((tt - 1.0).abs() < 1e-6 && (u - 0.2).abs() < 1e-6 && (v - 0.3).abs() < 1e-6);
        // Back side, outside, parallel, degenerate.
        assert!(intersect(&t, Vec3A::new(0.2, 0.3, -1.0), Vec3A::Z, 0.0, 10.0).is_some());
        assert!(intersect(&t, Vec3A::new(0.8, 0.3, 1.0), Vec3A::NEG_Z, 0.0, 10.0).is_none());
        assert!(intersect(&t, Vec3A::new(0.2, 0.3, 0.0), Vec3A::X, 0.0, 10.0).is_none());
        let d = Prepared::new(Vec3A::ZERO, Vec3A::X, Vec3A::X * 2.0);
        assert!(intersect(&d, Vec3A::new(0.5, 0.0, 1.0), Vec3A::NEG_Z, 0.0, 10.0).is_none());
    }
}
