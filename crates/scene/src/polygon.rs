//! Polygons in a plane: triangulation by ear clipping, shared by the generated meshes' side
//! profiles (`scene::generate`) and the hole filling of mesh repair (`export::repair`).

use glam::Vec2;

/// Whether a vertex lying on a candidate ear's boundary blocks that ear. Repair clips holes
/// whose rings touch themselves (`Blocks`); the generated profiles are simple (`Allowed`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnEdge {
    /// A vertex on the ear's boundary blocks it (inclusive inside test).
    Blocks,
    /// Only a vertex strictly inside blocks it.
    Allowed,
}

/// Triangulates a polygon (either orientation) by ear clipping; returns index triples,
/// counter-clockwise. A polygon that is not simple may leave vertices unclipped: then fewer
/// than `n − 2` triangles come back.
pub fn ear_clip(poly: &[Vec2], on_edge: OnEdge) -> Vec<[usize; 3]> {
    let n = poly.len();
    let mut idx: Vec<usize> = (0..n).collect();
    let area: f32 = (0..n).map(|i| poly[i].perp_dot(poly[(i + 1) % n])).sum();
    if area < 0.0 {
        idx.reverse();
    }
    let mut out = Vec::new();
    let inside = |p: Vec2, a: Vec2, b: Vec2, c: Vec2| {
        let d = [
            (b - a).perp_dot(p - a),
            (c - b).perp_dot(p - b),
            (a - c).perp_dot(p - c),
        ];
        match on_edge {
            OnEdge::Blocks => d.iter().all(|&x| x >= 0.0),
            OnEdge::Allowed => d.iter().all(|&x| x > 0.0),
        }
    };
    // Each pass clips one ear or stops.
    while idx.len() > 3 {
        let m = idx.len();
        let mut clipped = false;
        for i in 0..m {
            let (ia, ib, ic) = (idx[(i + m - 1) % m], idx[i], idx[(i + 1) % m]);
            let (a, b, c) = (poly[ia], poly[ib], poly[ic]);
            if (b - a).perp_dot(c - b) <= 0.0 {
                continue; // reflex (or flat) vertex
            }
            if idx
                .iter()
                .any(|&k| k != ia && k != ib && k != ic && inside(poly[k], a, b, c))
            {
                continue;
            }
            out.push([ia, ib, ic]);
            idx.remove(i);
            clipped = true;
            break;
        }
        if !clipped {
            break;
        }
    }
    if idx.len() == 3 {
        out.push([idx[0], idx[1], idx[2]]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(p: &[Vec2], t: &[[usize; 3]]) -> f32 {
        t.iter()
            .map(|k| 0.5 * (p[k[1]] - p[k[0]]).perp_dot(p[k[2]] - p[k[0]]))
            .sum()
    }

    #[test]
    fn ear_clipping_covers_a_concave_polygon_in_either_orientation() {
        let mut p = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(2.0, 0.0),
            Vec2::new(2.0, 2.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.0, 2.0),
        ];
        for _ in 0..2 {
            for rule in [OnEdge::Blocks, OnEdge::Allowed] {
                let t = ear_clip(&p, rule);
                assert_eq!(t.len(), 3);
                assert!((area(&p, &t) - 3.0).abs() < 1e-5, "{rule:?}");
            }
            p.reverse();
        }
    }

    #[test]
    fn a_vertex_on_an_ear_edge_blocks_that_ear_only_when_asked() {
        // Vertex 4 (2, 2) lies on the edge from (0, 4) to (4, 0) of the first ear, (5, 0, 1).
        let q = [
            Vec2::new(0.0, 0.0),
            Vec2::new(4.0, 0.0),
            Vec2::new(4.0, 4.0),
            Vec2::new(3.0, 3.0),
            Vec2::new(2.0, 2.0),
            Vec2::new(0.0, 4.0),
        ];
        let strict = ear_clip(&q, OnEdge::Allowed);
        let inclusive = ear_clip(&q, OnEdge::Blocks);
        assert_eq!(strict[0], [5, 0, 1], "{strict:?}");
        assert!(!inclusive.contains(&[5, 0, 1]), "{inclusive:?}");
        for t in [&strict, &inclusive] {
            assert_eq!(t.len(), 4, "{t:?}");
            assert!((area(&q, t) - 12.0).abs() < 1e-5, "{t:?}");
        }
    }
}
