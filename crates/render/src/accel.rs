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
    /// The scene's bounds, padded: a ray that misses them misses every triangle, and most
    /// rays (sky, ground, the ground's shadow rays) are turned away by this one test before
    /// the BVH's root is read (a fifth of a view's ray-casting and shading time).
    lo: Vec3A,
    hi: Vec3A,
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
        let (mut lo, mut hi) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
        for t in &tris {
            for v in [t.v0, t.v1, t.v2] {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        // Padded by a thousandth of the scene's size: far more than the slab test's rounding.
        let pad = (hi - lo).max_element().max(1e-3) * 1e-3;
        (
            Accel {
                tris: prepared,
                ids,
                bvh,
                lo: lo - pad,
                hi: hi + pad,
            },
            start.elapsed(),
        )
    }

    /// The closest hit along `origin + t * dir` for `t` in `(tmin, tmax)`.
    pub fn closest(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        let (o, d) = (Vec3A::from(origin), Vec3A::from(dir));
        if !self.may_hit(o, d, tmin, tmax) {
            return None;
        }
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
        if !self.may_hit(o, d, tmin, tmax) {
            return false;
        }
        let ray = Ray::new(o, d, tmin, tmax);
        !self.bvh.ray_traverse_miss(ray, |r, id| {
            intersect(&self.tris[id], o, d, tmin, r.tmax)
                .map(|h| h.0)
                .unwrap_or(f32::INFINITY)
        })
    }

    /// Does the ray meet the padded scene bounds within `(tmin, tmax)`? (slab test)
    #[inline(always)]
    fn may_hit(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> bool {
        let inv = d.recip();
        let (a, b) = ((self.lo - o) * inv, (self.hi - o) * inv);
        if (a.is_nan_mask() | b.is_nan_mask()).any() {
            // 0 · ∞: a ray parallel to a face of the bounds starting on its plane. Let the BVH
            // decide.
            return true;
        }
        let (near, far) = (a.min(b), a.max(b));
        let t0 = near.max_element().max(tmin);
        let t1 = far.min_element().min(tmax);
        !(t0 > t1)
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

    /// The bounds test turns no ray away that hits a triangle: closest hits and shadow queries
    /// equal a brute-force test of every triangle, for seeded random rays from around and inside
    /// the box-shaped container and the pickup, axis-parallel ones (directions with zero
    /// components) and rays starting exactly on a face of the bounds among them.
    #[test]
    fn the_bounds_test_loses_no_hit() {
        let mut state = 0x5EED_u64;
        let mut next = move || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
        };
        for scene in [
            cac_scene::generate::container(),
            cac_scene::generate::pickup(),
        ] {
            let accel = Accel::build(&scene);
            let (lo, hi) = (accel.lo, accel.hi);
            let size = (hi - lo).max_element();
            let mut hits = 0;
            for k in 0..4000 {
                let mut o =
                    lo + (hi - lo) * Vec3A::new(next(), next(), next()) * 2.0 - (hi - lo) * 0.5;
                let mut d = Vec3A::new(next() - 0.5, next() - 0.5, next() - 0.5);
                match k % 4 {
                    // Axis-parallel: zero out one or two components.
                    1 => d.x = 0.0,
                    2 => (d.y, d.z) = (0.0, 0.0),
                    // On a face of the bounds, running along it.
                    3 => (o.y, d.y) = (lo.y, 0.0),
                    _ => {}
                }
                if d.length_squared() < 1e-6 {
                    continue;
                }
                let d = d.normalize();
                let tmax = if k % 5 == 0 {
                    size * next()
                } else {
                    f32::INFINITY
                };
                let brute = accel
                    .tris
                    .iter()
                    .enumerate()
                    .filter_map(|(i, t)| intersect(t, o, d, 0.0, tmax).map(|h| (h.0, i)))
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                let got = accel.closest(o.into(), d.into(), 0.0, tmax);
                // The same distance (two triangles sharing an edge may both hold the hit).
                assert_eq!(
                    got.map(|h| h.t),
                    brute.map(|(t, _)| t),
                    "ray {k}: {o} + t·{d}"
                );
                assert_eq!(
                    accel.occluded(o.into(), d.into(), 0.0, tmax),
                    brute.is_some()
                );
                hits += brute.is_some() as usize;
            }
            assert!(
                hits > 200,
                "too few rays hit the object ({hits}) to test anything"
            );
        }
    }
}
