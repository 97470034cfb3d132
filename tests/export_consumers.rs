//! Exported files checked by real consumers: lib3mf (strict mode, via `tools/check_3mf.py`) and
//! the PrusaSlicer command line, plus round trips of both 3MF flavours against the texture.

mod export_common;

use cac::export::{self, bake, ExportOptions, Format, Paint, Scale};
use export_common::*;
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use std::io::Read;
use std::path::Path;

fn export_to(mesh: &Path, tex: &Path, out: &Path, formats: &[Format]) -> export::ExportSummary {
    let opts = ExportOptions {
        formats: formats.to_vec(),
        scale: "1:24".parse().unwrap(),
        ..Default::default()
    };
    export::export(mesh, tex, out, &opts).unwrap()
}

#[test]
fn default_objects_pass_lib3mf_strict_mode() {
    if !have_lib3mf() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 256);
    for name in ["jeep", "barrel", "container"] {
        let out = d.path().join(name);
        let s = export_to(
            Path::new(name),
            &tex,
            &out,
            &[Format::ThreeMfTexture, Format::ThreeMfColor],
        );
        let t = lib3mf_check(&out.join(format!("{name}_texture.3mf")));
        assert_eq!(t["warnings"].as_array().unwrap().len(), 0, "{t}");
        assert_eq!(t["unit_mm"], true);
        assert_eq!(t["build_items"], 1);
        let o = &t["objects"][0];
        assert_eq!(o["triangles"], s.report.triangles as u64, "{name}: {t}");
        assert_eq!(o["vertices"], s.report.welded_vertices as u64);
        assert_eq!(o["manifold_and_oriented"], true, "{name}");
        assert_eq!(o["triangles_without_property"], 0);
        assert_eq!(o["triangles_with_bad_property"], 0);
        let groups = t["texture2dgroups"].as_object().unwrap();
        assert_eq!(groups.len(), 1, "{t}");
        let g = groups.values().next().unwrap();
        assert_eq!(g["texture_path"], "/3D/Textures/tex0.png");
        assert!(g["count"].as_u64().unwrap() >= 3);
        assert_eq!(t["textures"].as_array().unwrap().len(), 1);
        // Untextured parts (wheels, trim...) get a colour group.
        assert!(!t["colorgroups"].as_object().unwrap().is_empty());

        let c = lib3mf_check(&out.join(format!("{name}_color.3mf")));
        assert_eq!(c["warnings"].as_array().unwrap().len(), 0, "{c}");
        let o = &c["objects"][0];
        assert_eq!(o["triangles"], s.baked_triangles.unwrap() as u64);
        assert_eq!(o["manifold_and_oriented"], true, "{name}");
        assert_eq!(
            o["triangles_without_property"], 0,
            "every triangle coloured"
        );
        assert_eq!(o["triangles_with_bad_property"], 0);
        assert!(c["textures"].as_array().unwrap().is_empty());
        let cg = c["colorgroups"].as_object().unwrap();
        assert_eq!(cg.len(), 1);
        assert!(cg.values().next().unwrap()["distinct"].as_u64().unwrap() > 50);
    }
}

#[test]
fn prusaslicer_loads_every_geometry_file() {
    if !have_prusa() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 256);
    let out = d.path().join("out");
    let s = export_to(
        Path::new("jeep"),
        &tex,
        &out,
        &[Format::ThreeMfTexture, Format::ThreeMfColor, Format::Obj],
    );
    for (file, facets) in [
        ("jeep_texture.3mf", s.report.triangles),
        ("jeep_color.3mf", s.baked_triangles.unwrap()),
        ("jeep.obj", s.report.triangles),
    ] {
        let info = prusa_info(&out.join(file));
        assert_eq!(
            info.get("manifold").map(String::as_str),
            Some("yes"),
            "{file}: {info:?}"
        );
        assert_eq!(info["number_of_facets"], facets.to_string(), "{file}");
        let vol: f64 = info["volume"].parse().unwrap();
        let rel = (vol - s.report.volume_mm3).abs() / s.report.volume_mm3;
        assert!(
            rel < 1e-3,
            "{file}: PrusaSlicer volume {vol} vs ours {}",
            s.report.volume_mm3
        );
        let sx: f64 = info["size_x"].parse().unwrap();
        assert!((sx - s.report.size_mm[0] as f64).abs() < 0.01, "{file}");
    }
}

/// Finds the triangle of `mesh` that contains `p` (on its plane, inside, facing like `n`),
/// returning its index and the barycentric coordinates of `p`. `None` when no triangle contains
/// it, or when triangles of two different parts do (coplanar overlapping faces, such as the
/// jeep's spare wheel against its back: the point's colour is ambiguous there).
fn locate(mesh: &export::PrintMesh, p: Vec3, n: Vec3) -> Option<(usize, Vec3)> {
    let mut best: Option<(f32, usize, Vec3)> = None;
    let mut parts = vec![];
    for (i, t) in mesh.tris.iter().enumerate() {
        let [a, b, c] = t.v.map(|k| mesh.positions[k as usize]);
        let nn = (b - a).cross(c - a);
        if nn.dot(n) <= 0.0 {
            continue;
        }
        let nn2 = nn.length_squared();
        let dist = (p - a).dot(nn) / nn2.sqrt();
        if dist.abs() > 1e-2 {
            continue;
        }
        let w1 = (p - a).cross(c - a).dot(nn) / nn2;
        let w2 = (b - a).cross(p - a).dot(nn) / nn2;
        let w = Vec3::new(1.0 - w1 - w2, w1, w2);
        let outside = (-w.min_element()).max(0.0);
        if outside < 1e-4 {
            parts.push(t.part);
            if best.is_none_or(|(o, _, _)| outside < o) {
                best = Some((outside, i, w));
            }
        }
    }
    parts.sort();
    parts.dedup();
    if parts.len() > 1 {
        return None;
    }
    best.map(|(_, i, w)| (i, w))
}

/// Round trip of the baked 3MF: random surface points of the file read back, coloured by its
/// corner colours, against the texture at the same point of the original mesh.
#[test]
fn baked_3mf_round_trip_matches_the_texture() {
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 512);
    let out = d.path().join("out");
    export_to(Path::new("jeep"), &tex, &out, &[Format::ThreeMfColor]);
    let m = read_3mf(&out.join("jeep_color.3mf")).unwrap();
    assert_eq!(m.unit, "millimeter");
    let mesh = print_mesh(Path::new("jeep"), &tex, Scale { denominator: 24.0 });
    let areas: Vec<f32> = m
        .triangles
        .iter()
        .map(|(v, _, _)| {
            let [a, b, c] = v.map(|i| m.vertices[i as usize]);
            0.5 * (b - a).cross(c - a).length()
        })
        .collect();
    let total: f32 = areas.iter().sum();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    let (mut se, mut se_tex, mut des, mut n_all) = (0.0f64, 0.0f64, vec![], 0usize);
    let mut skipped = 0;
    let n = 3000;
    for _ in 0..n {
        let mut x = rng.random::<f32>() * total;
        let i = areas.iter().position(|&a| {
            x -= a;
            x <= 0.0
        });
        let i = i.unwrap_or(areas.len() - 1);
        let (v, _, _) = m.triangles[i];
        let [a, b, c] = v.map(|k| m.vertices[k as usize]);
        let (mut u, mut w) = (rng.random::<f32>(), rng.random::<f32>());
        if u + w > 1.0 {
            (u, w) = (1.0 - u, 1.0 - w);
        }
        let p = a + (b - a) * u + (c - a) * w;
        let cc = m.corner_colours(i).expect("every triangle coloured");
        let got: [f32; 3] = std::array::from_fn(|k| {
            (cc[0][k] as f32 * (1.0 - u - w) + cc[1][k] as f32 * u + cc[2][k] as f32 * w) / 255.0
        });
        let Some((ti, bary)) = locate(&mesh, p, (b - a).cross(c - a)) else {
            skipped += 1;
            continue;
        };
        let want = bake::reference_colour(&mesh, ti, bary);
        let textured = matches!(mesh.tris[ti].paint, Paint::Texture { .. });
        n_all += 1;
        let e2: f64 = (0..3)
            .map(|k| ((got[k] - want[k]) as f64 * 255.0).powi(2))
            .sum();
        se += e2;
        if textured {
            se_tex += e2;
            des.push(cac::colour::delta_e76_srgb(got, want));
        }
    }
    // Ambiguous (coplanar overlapping parts) or off-mesh points: few, and counted.
    assert!(skipped < n / 50, "{skipped} of {n} points not located");
    let n_tex = des.len();
    assert!(n_tex > n / 2);
    des.sort_by(|a, b| a.total_cmp(b));
    let rmse = (se / (3 * n_all) as f64).sqrt();
    let rmse_tex = (se_tex / (3 * n_tex) as f64).sqrt();
    let mean_de = des.iter().sum::<f32>() / n_tex as f32;
    let p95 = des[n_tex * 95 / 100];
    eprintln!(
        "round trip: {n_all} points ({n_tex} on the texture, {skipped} ambiguous skipped); \
         RMSE {rmse:.2} (8-bit) on all, on the texture: RMSE {rmse_tex:.2}, mean dE76 {mean_de:.2}, p95 dE76 {p95:.2}"
    );
    // Tolerance stated in docs/export.md for the default bake (2 texels per edge).
    assert!(rmse < 5.0, "RMSE {rmse}");
    assert!(rmse_tex < 5.0, "RMSE on textured parts {rmse_tex}");
    assert!(mean_de < 1.5, "mean dE {mean_de}");
    assert!(p95 < 5.0, "p95 dE {p95}");
}

/// Round trip of the textured 3MF: same positions, the camouflage PNG unchanged, and every
/// painted corner's UV as in the mesh.
#[test]
fn textured_3mf_round_trip_keeps_texture_uvs_and_geometry() {
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 128);
    let out = d.path().join("out");
    export_to(Path::new("jeep"), &tex, &out, &[Format::ThreeMfTexture]);
    let file = out.join("jeep_texture.3mf");
    let m = read_3mf(&file).unwrap();
    let mesh = print_mesh(Path::new("jeep"), &tex, Scale { denominator: 24.0 });
    for want in [
        "[Content_Types].xml",
        "_rels/.rels",
        "3D/_rels/3dmodel.model.rels",
        "3D/Textures/tex0.png",
        "3D/3dmodel.model",
    ] {
        assert!(
            m.files.iter().any(|f| f == want),
            "{want} missing: {:?}",
            m.files
        );
    }
    let mut z = zip::ZipArchive::new(std::fs::File::open(&file).unwrap()).unwrap();
    let mut png = vec![];
    z.by_name("3D/Textures/tex0.png")
        .unwrap()
        .read_to_end(&mut png)
        .unwrap();
    let inside = image::load_from_memory(&png).unwrap().to_rgb8();
    assert_eq!(inside, cac::io::load_rgb(&tex).unwrap(), "texture changed");
    let mut rels = String::new();
    z.by_name("3D/_rels/3dmodel.model.rels")
        .unwrap()
        .read_to_string(&mut rels)
        .unwrap();
    assert!(
        rels.contains("/3D/Textures/tex0.png") && rels.contains("3dtexture"),
        "{rels}"
    );
    assert_eq!(m.vertices.len(), mesh.positions.len());
    for (a, b) in m.vertices.iter().zip(&mesh.positions) {
        assert!(a.distance(*b) < 1e-4);
    }
    let (&gid, (_, coords)) = m.tex_groups.iter().next().unwrap();
    let mut painted = 0;
    for ((v, pid, p), t) in m.triangles.iter().zip(&mesh.tris) {
        assert_eq!(*v, t.v);
        if let Some(uv) = mesh.camo_uv(t) {
            painted += 1;
            assert_eq!(*pid, gid);
            for k in 0..3 {
                let got: Vec2 = coords[p[k] as usize];
                assert!(got.distance(uv[k]) < 1e-6, "{got} vs {}", uv[k]);
            }
        }
    }
    assert!(painted >= 30, "{painted} painted triangles");
}

#[test]
fn vertex_colour_obj_carries_the_bake_and_obj_bundle_is_complete() {
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 64);
    let out = d.path().join("out");
    let opts = ExportOptions {
        formats: vec![Format::Obj, Format::ObjVc],
        scale: "1:24".parse().unwrap(),
        zip_obj: true,
        ..Default::default()
    };
    let s = export::export(Path::new("barrel"), &tex, &out, &opts).unwrap();
    let text = std::fs::read_to_string(out.join("barrel_vc.obj")).unwrap();
    let verts: Vec<Vec<f32>> = text
        .lines()
        .filter(|l| l.starts_with("v "))
        .map(|l| l[2..].split(' ').map(|x| x.parse().unwrap()).collect())
        .collect();
    let faces = text.lines().filter(|l| l.starts_with("f ")).count();
    assert_eq!(faces, s.baked_triangles.unwrap());
    assert!(verts
        .iter()
        .all(|v| v.len() == 6 && v[3..].iter().all(|c| (0.0..=1.0).contains(c))));
    // Seam vertices are duplicated: more vertices than distinct positions.
    let mut pos: Vec<[u32; 3]> = verts
        .iter()
        .map(|v| [v[0], v[1], v[2]].map(f32::to_bits))
        .collect();
    pos.sort();
    pos.dedup();
    assert!(verts.len() > pos.len());
    // The textured OBJ reads back through the scene loader, and the zip holds all its files.
    let back = cac::scene::Scene::load(&out.join("barrel.obj"), &Default::default()).unwrap();
    assert_eq!(back.triangles.len(), s.report.triangles);
    let z = zip::ZipArchive::new(std::fs::File::open(out.join("barrel_obj.zip")).unwrap()).unwrap();
    let names: Vec<&str> = z.file_names().collect();
    for f in ["barrel.obj", "barrel.mtl", "barrel_tex0.png"] {
        assert!(names.contains(&f), "{names:?}");
    }
}

#[test]
fn sheets_are_at_true_physical_size() {
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 256);
    let out = d.path().join("out");
    export_to(Path::new("container"), &tex, &out, &[Format::Sheets]);
    let dir = out.join("sheets");
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("sheets.json")).unwrap()).unwrap();
    let pages = j["pages"].as_u64().unwrap() as usize;
    assert!(pages >= 1);
    let img = image::open(dir.join("page_01.png")).unwrap();
    // A4 at 300 dpi.
    assert_eq!((img.width(), img.height()), (2480, 3508));
    // The scale bar is 100 mm: the longest run of black pixels in the header is 100 mm at 300 dpi.
    let rgb = img.to_rgb8();
    let header_rows = (40.0 / 25.4 * 300.0) as u32;
    let longest = (0..header_rows)
        .map(|y| {
            let (mut best, mut run) = (0, 0);
            for x in 0..rgb.width() {
                run = if rgb.get_pixel(x, y).0 == [0, 0, 0] {
                    run + 1
                } else {
                    0
                };
                best = best.max(run);
            }
            best
        })
        .max()
        .unwrap();
    let want = 100.0 / 25.4 * 300.0;
    assert!(
        (longest as f32 - want).abs() <= 4.0,
        "scale bar {longest} px, want {want}"
    );
    let pdf = std::fs::read(dir.join("sheets.pdf")).unwrap();
    assert!(pdf.starts_with(b"%PDF-"));
    // Poppler reads the PDF: one A4 page per PNG page.
    if have_pdfinfo() {
        let o = std::process::Command::new("pdfinfo")
            .arg(dir.join("sheets.pdf"))
            .output()
            .unwrap();
        let info = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "pdfinfo: {info}{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let field = |k: &str| {
            info.lines()
                .find_map(|l| l.strip_prefix(k))
                .map(|v| v.trim().to_string())
                .unwrap_or_default()
        };
        assert_eq!(field("Pages:"), pages.to_string(), "{info}");
        assert_eq!(field("Page size:"), "595.276 x 841.89 pts (A4)", "{info}");
    }
    // The container's walls: sum of the parts' areas is the painted area at 1:24, and each
    // part's paper size is its texel size times its texel extent.
    let parts = j["parts"].as_array().unwrap();
    let area: f64 = parts.iter().map(|p| p["area_mm2"].as_f64().unwrap()).sum();
    let (l, w, h) = (6060.0 / 24.0, 2440.0 / 24.0, 2590.0 / 24.0);
    let box_area = 2.0 * (l * w + l * h + w * h);
    assert!(
        (area - box_area).abs() / box_area < 0.01,
        "{area} vs {box_area}"
    );
    for p in parts {
        let s = p["mm_per_texel"].as_f64().unwrap();
        assert!(s > 0.0);
        let pieces = p["pieces"].as_array().unwrap();
        let w_sum: f64 = pieces.iter().map(|q| q["width_mm"].as_f64().unwrap()).sum();
        assert!(w_sum >= p["width_mm"].as_f64().unwrap() - 0.01);
    }
}

#[test]
fn truck_glb_is_welded_and_checked() {
    let Some(truck) = truck() else { return };
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 256);
    let out = d.path().join("out");
    let mesh = print_mesh(&truck, &tex, Scale { denominator: 24.0 });
    // glTF splits vertices at UV seams; welding joins them while keeping per-corner UVs.
    assert!(
        mesh.report.welded_vertices < mesh.report.input_vertices / 2,
        "{:?}",
        mesh.report
    );
    let opts = ExportOptions {
        formats: vec![Format::ThreeMfTexture],
        scale: "1:24".parse().unwrap(),
        ..Default::default()
    };
    match export::export(&truck, &tex, &out, &opts) {
        Ok(s) => assert!(s.report.is_closed()),
        Err(e) => {
            let e = format!("{e:#}");
            assert!(
                e.contains("CesiumMilkTruck.glb") && e.contains("open edges"),
                "{e}"
            );
            assert!(!out.join("CesiumMilkTruck_texture.3mf").exists());
            // Written on request, and lib3mf still reads it strictly.
            let opts = ExportOptions {
                allow_open: true,
                ..opts
            };
            export::export(&truck, &tex, &out, &opts).unwrap();
            if have_lib3mf() {
                let t = lib3mf_check(&out.join("CesiumMilkTruck_texture.3mf"));
                assert_eq!(t["warnings"].as_array().unwrap().len(), 0, "{t}");
                assert_eq!(t["objects"][0]["triangles"], mesh.report.triangles as u64);
                assert_eq!(t["objects"][0]["triangles_without_property"], 0);
                assert!(t["texture2dgroups"].as_object().unwrap().len() >= 2, "{t}");
            }
        }
    }
}
