//! Ground-truth boxes of physical frames: the object's silhouette projected through the
//! calibrated lens (distortion included) at the known table angle and camera distance. Every
//! triangle edge is sampled (straight edges bend under distortion), and the box is clipped to the
//! image. Points beyond the radius where the distortion polynomial folds back are outside any
//! real image and push the box to the border on their side.

use super::calib::CameraModel;
use super::rig::Rig;
use anyhow::Result;
use glam::{DVec2, Vec3};

/// Samples per triangle edge (ends included).
const EDGE_SAMPLES: usize = 6;

/// The ground-truth box `[x1, y1, x2, y2]` (pixels, cac convention) of the object with the table
/// at `angle_deg` and the camera `horizontal_m` from the axis; `None` when it is out of view.
pub fn ground_truth_box(rig: &Rig, angle_deg: f64, horizontal_m: f64) -> Result<Option<[f32; 4]>> {
    let cam = rig.camera_at(angle_deg, horizontal_m)?;
    let lens = &rig.lens;
    let r_max = fold_radius(lens);
    let scene = &rig.renderer.scene;
    let rt = cam.rotation.transpose();
    let (w, h) = (lens.width as f64, lens.height as f64);
    let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    let mut add = |p: Vec3| {
        let c = (rt * (p - cam.eye)).as_dvec3();
        if c.z <= 1e-9 {
            return; // behind the camera: not imaged
        }
        let n = DVec2::new(c.x / c.z, c.y / c.z);
        let q = if n.length() > r_max {
            // Far outside the field of view: towards the border on its side.
            DVec2::new(lens.cx, lens.cy) + n.normalize() * 4.0 * (w + h)
        } else {
            let d = lens.distort(n);
            DVec2::new(lens.fx * d.x + lens.cx, lens.fy * d.y + lens.cy)
        };
        b = [b[0].min(q.x), b[1].min(q.y), b[2].max(q.x), b[3].max(q.y)];
    };
    for t in &scene.triangles {
        let v = t.p.map(|i| scene.positions[i as usize]);
        for e in 0..3 {
            let (a, c) = (v[e], v[(e + 1) % 3]);
            for s in 0..EDGE_SAMPLES {
                add(a.lerp(c, s as f32 / (EDGE_SAMPLES - 1) as f32));
            }
        }
    }
    let clip = [b[0].max(0.0), b[1].max(0.0), b[2].min(w), b[3].min(h)];
    Ok((clip[0] < clip[2] && clip[1] < clip[3]).then(|| clip.map(|v| v as f32)))
}

/// The normalised radius where the radial distortion stops growing (the lens model folds back);
/// 10 when it does not within that.
pub(crate) fn fold_radius(lens: &CameraModel) -> f64 {
    let [k1, k2, _, _, k3] = lens.dist;
    let f = |r: f64| {
        let r2 = r * r;
        r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
    };
    let mut prev = 0.0;
    let mut r = 0.0;
    while r < 10.0 {
        r += 1e-3;
        let v = f(r);
        if v <= prev {
            return r - 1e-3;
        }
        prev = v;
    }
    10.0
}
