//! Repair, solidification and printability at scale (`cac export --repair`): the third-party
//! milk truck and messy meshes made here, each printable (closed, manifold, accepted by lib3mf in
//! strict mode) or refused with a message saying what and where, in mm at print scale.

mod export_common;

use cac::export::{self, ExportOptions, Format, RepairMode, ThinPolicy};
use export_common::*;
use std::path::{Path, PathBuf};

type Tri = [[f32; 3]; 3];

/// The 12 outward triangles of an axis-aligned box (metres).
fn boxed(lo: [f32; 3], hi: [f32; 3]) -> Vec<Tri> {
    let c = |i: u32| std::array::from_fn(|k| if i >> k & 1 == 0 { lo[k] } else { hi[k] });
    cac::scene::BOX_QUADS
        .iter()
        .flat_map(|q| [[c(q[0]), c(q[1]), c(q[2])], [c(q[0]), c(q[2]), c(q[3])]])
        .collect()
}

/// Writes triangles as an OBJ part `body_paint` with planar UVs (x, z).
fn obj(dir: &Path, name: &str, tris: &[Tri]) -> PathBuf {
    let mut s = String::from("o body_paint\n");
    for t in tris {
        for p in t {
            s += &format!(
                "v {} {} {}\nvt {} {}\n",
                p[0],
                p[1],
                p[2],
                p[0] * 0.7,
                p[2] * 0.7
            );
        }
    }
    for i in 0..tris.len() {
        let b = 3 * i + 1;
        s += &format!("f {b}/{b} {}/{} {}/{}\n", b + 1, b + 1, b + 2, b + 2);
    }
    let p = dir.join(name);
    std::fs::write(&p, s).unwrap();
    p
}

fn opts(scale: &str) -> ExportOptions {
    ExportOptions {
        formats: vec![Format::ThreeMfTexture],
        scale: scale.parse().unwrap(),
        ..Default::default()
    }
}

/// The written textured 3MF is closed and lib3mf reads it strictly.
fn assert_printable(s: &export::ExportSummary, file: &Path) {
    assert!(s.report.is_closed(), "{:?}", s.report);
    assert!(s.report.volume_mm3 > 0.0);
    if have_lib3mf() {
        let t = lib3mf_check(file);
        assert_eq!(t["warnings"].as_array().unwrap().len(), 0, "{t}");
        assert_eq!(t["objects"][0]["manifold_and_oriented"], true, "{t}");
        assert_eq!(t["objects"][0]["triangles_without_property"], 0, "{t}");
    }
}

#[test]
fn messy_meshes_become_printable_solids() {
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 64);
    let unit = boxed([0.0, 0.0, 0.0], [0.5, 0.5, 0.5]);
    // Box volume at 1:10: 50 mm cube.
    let cube = 125_000.0;
    // (name, triangles, expected volume (mm³) or None, expect a rebuilt solid)
    let mut cases: Vec<(&str, Vec<Tri>, Option<f64>, bool)> = vec![];
    // Two intersecting boxes: closed, so printable as they are (auto); --repair solid unites them.
    let mut two = unit.clone();
    two.extend(boxed([0.25, 0.25, 0.25], [0.75, 0.75, 0.75]));
    cases.push(("two_boxes", two, None, false));
    // A box with a missing face (a hole too large to patch): rebuilt, the hole spanned.
    let mut open = unit.clone();
    open.drain(6..8);
    cases.push(("missing_face", open, Some(cube), true));
    // A single-sided quad "window" 0.2 mm in front of a side face: thickened and united.
    let mut win = unit.clone();
    let (z, a, b) = (-0.002, 0.1, 0.4);
    win.push([[a, a, z], [b, a, z], [b, b, z]]);
    win.push([[a, a, z], [b, b, z], [a, b, z]]);
    cases.push(("window", win, None, true));
    // Flipped normals: every triangle reversed.
    let flipped: Vec<Tri> = unit.iter().map(|t| [t[0], t[2], t[1]]).collect();
    cases.push(("flipped", flipped, Some(cube), false));
    // Bow-tie: two boxes sharing one edge (used by four triangles).
    let mut bow = unit.clone();
    bow.extend(boxed([0.5, 0.5, 0.0], [1.0, 1.0, 0.5]));
    cases.push(("bowtie", bow, Some(2.0 * cube), true));
    // One triangle: a sheet, thickened to the minimum wall.
    cases.push((
        "one_triangle",
        vec![[[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.5]]],
        None,
        true,
    ));
    for (name, tris, vol, rebuilt) in cases {
        let mesh = obj(d.path(), &format!("{name}.obj"), &tris);
        let out = d.path().join(name);
        let s = export::export(&mesh, &tex, &out, &opts("1:10"))
            .unwrap_or_else(|e| panic!("{name}: {e:#}"));
        eprintln!("{name}: {:?}\n  {}", s.solid, s.notes.join("\n  "));
        assert_eq!(s.solid.is_some(), rebuilt, "{name}: {:?}", s.notes);
        assert_printable(&s, &out.join(format!("{name}_texture.3mf")));
        if let Some(v) = vol {
            let rel = (s.report.volume_mm3 - v).abs() / v;
            assert!(rel < 0.03, "{name}: volume {} vs {v}", s.report.volume_mm3);
        }
        if rebuilt {
            // The original's visible surface is kept, within half the minimum wall where a sheet
            // was thickened (a spanned hole adds new surface, so the other direction is larger).
            let f = s.fidelity.as_ref().expect("measured");
            let tol = if name == "one_triangle" { 0.45 } else { 0.2 };
            assert!(f.in_mean_mm < tol, "{name}: {f:?}");
        }
        if name == "two_boxes" {
            let o = ExportOptions {
                repair: RepairMode::Solid,
                ..opts("1:10")
            };
            let s = export::export(&mesh, &tex, &out, &o).unwrap();
            assert_eq!(s.report.shells, 1, "{:?}", s.report);
            // What `cac export` prints: the mesh as loaded (two shells) and as written (one).
            let text = s.to_string();
            assert!(
                text.contains(", 2 shells, ") && text.contains(" 1 shells, size "),
                "{text}"
            );
            assert!(
                text.contains("wrote ") && text.contains("two_boxes_texture.3mf"),
                "{text}"
            );
            let union = cube * (2.0 - 0.125);
            assert!((s.report.volume_mm3 - union).abs() / union < 0.02);
            assert_printable(&s, &out.join("two_boxes_texture.3mf"));
        }
        if name == "window" {
            assert!(
                s.notes.iter().any(|n| n.contains("single-sided")),
                "{:?}",
                s.notes
            );
            assert_eq!(s.report.shells, 1, "window united with the box");
        }
    }
}

#[test]
fn thin_fin_is_thickened_dropped_or_refused_with_its_place() {
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 64);
    // A 50 mm box with a fin 0.3 mm thick (at 1:10), 20 mm tall, on top.
    let mut t = boxed([0.0, 0.0, 0.0], [0.5, 0.5, 0.5]);
    t.extend(boxed([0.1, 0.5, 0.25], [0.4, 0.7, 0.253]));
    let mesh = obj(d.path(), "fin.obj", &t);
    let out = d.path().join("out");
    let mut o = opts("1:10");
    o.limits.thin = ThinPolicy::Refuse;
    let e = format!("{:#}", export::export(&mesh, &tex, &out, &o).unwrap_err());
    assert!(
        e.contains("fin.obj") && e.contains("thinner than the 0.80 mm minimum wall"),
        "{e}"
    );
    assert!(e.contains("wall 0.30 mm thick") && e.contains(" mm"), "{e}");
    assert!(!out.join("fin_texture.3mf").exists());
    o.limits.thin = ThinPolicy::Thicken;
    let s = export::export(&mesh, &tex, &out, &o).unwrap();
    assert!(s.solid.as_ref().unwrap().thickened_triangles > 0);
    assert_printable(&s, &out.join("fin_texture.3mf"));
    let thick = s.report.volume_mm3;
    o.limits.thin = ThinPolicy::Drop;
    let s = export::export(&mesh, &tex, &out, &o).unwrap();
    assert!(
        s.notes.iter().any(|n| n.starts_with("warning:")),
        "{:?}",
        s.notes
    );
    assert_printable(&s, &out.join("fin_texture.3mf"));
    assert!(
        (s.report.volume_mm3 - 125_000.0).abs() < 2500.0,
        "{}",
        s.report.volume_mm3
    );
    assert!(thick > s.report.volume_mm3 + 500.0);
}

#[test]
fn extreme_scales_and_inputs_are_refused_clearly() {
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 64);
    let out = d.path().join("out");
    // 1:1000: the jeep is 4 mm long; nearly everything is thinner than the minimum wall.
    let e = format!(
        "{:#}",
        export::export(Path::new("jeep"), &tex, &out, &opts("1:1000")).unwrap_err()
    );
    assert!(e.contains("1:1000") && e.contains("minimum wall"), "{e}");
    // Larger than the build volume: names the size and a scale that fits.
    let e = format!(
        "{:#}",
        export::export(Path::new("container"), &tex, &out, &opts("1:10")).unwrap_err()
    );
    assert!(
        e.contains("build volume") && e.contains("print at 1:"),
        "{e}"
    );
    // No paintable part.
    let p = d.path().join("glass.obj");
    std::fs::write(
        &p,
        "o window_glass\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    let e = format!(
        "{:#}",
        export::export(&p, &tex, &out, &opts("1:10")).unwrap_err()
    );
    assert!(
        e.contains("glass.obj") && e.contains("no part of the mesh is paintable"),
        "{e}"
    );
    assert!(!out.exists() || std::fs::read_dir(&out).unwrap().next().is_none());
}

#[test]
fn milk_truck_exports_printable_without_allow_open() {
    let Some(truck) = truck() else { return };
    let d = tempfile::tempdir().unwrap();
    let tex = camo_png(d.path(), 256);
    let out = d.path().join("out");
    let mut o = ExportOptions {
        formats: vec![Format::ThreeMfTexture, Format::ThreeMfColor],
        scale: "1:24".parse().unwrap(),
        ..Default::default()
    };
    // The default bake (2 texels) makes 5.2 M triangles here because of the truck's own 2048²
    // wheel texture, which lib3mf takes minutes to read: 8 texels keeps the test short.
    o.bake.max_edge_texels = 8.0;
    let t0 = std::time::Instant::now();
    let s = export::export(&truck, &tex, &out, &o).unwrap();
    eprintln!(
        "truck: {:.1} s, {}",
        t0.elapsed().as_secs_f64(),
        s.notes.join("\n  ")
    );
    assert!(s.input_report.open_edges > 0, "the truck has holes");
    assert!(s.report.is_closed());
    // The textured 3MF carries the texture and UVs as they are (no colour error); the 8-texel
    // bake measures mean dE76 5.3 here (the wheels' photo texture has sharp detail): see
    // docs/export.md for the default bake.
    assert!(
        s.bake_mean_delta_e.unwrap() < 7.0,
        "{:?}",
        s.bake_mean_delta_e
    );
    for f in ["CesiumMilkTruck_texture.3mf", "CesiumMilkTruck_color.3mf"] {
        assert_printable(&s, &out.join(f));
        if have_prusa() {
            let info = prusa_info(&out.join(f));
            assert_eq!(
                info.get("manifold").map(String::as_str),
                Some("yes"),
                "{f}: {info:?}"
            );
        }
    }
}

/// The same input exports to the same bytes: a solid rebuilt and baked into a colour 3MF twice
/// (the bake subdivides edges; hash-map order once decided the vertex order).
#[test]
fn the_same_input_exports_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let tex = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/meshes/barrel/cac-stop_sign.png"
    ));
    let mesh = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/meshes/barrel/barrel.obj"
    ));
    let o = ExportOptions {
        formats: vec![Format::ThreeMfColor, Format::ThreeMfTexture],
        repair: RepairMode::Solid,
        voxel_mm: Some(0.8),
        ..opts("1:40")
    };
    let files: Vec<Vec<u8>> = (0..2)
        .map(|k| {
            let out = dir.path().join(format!("run{k}"));
            export::export(mesh, tex, &out, &o).unwrap();
            let mut names: Vec<_> = std::fs::read_dir(&out)
                .unwrap()
                .map(|e| e.unwrap().path())
                .collect();
            names.sort();
            names
                .iter()
                .flat_map(|p| std::fs::read(p).unwrap())
                .collect()
        })
        .collect();
    assert!(files[0].len() > 100_000, "{} bytes", files[0].len());
    assert!(files[0] == files[1], "two exports of the same input differ");
}
