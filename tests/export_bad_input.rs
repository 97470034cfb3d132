//! `cac export` on bad input: each case is a clear error naming the file and the problem, and
//! nothing (no half-written file, no temporary) is left in the output folder.

mod export_common;

use cac::export::{self, ExportOptions, Format, RepairMode, Scale};
use std::path::Path;

/// A closed tetrahedron as OBJ lines (object `body_paint`, with UVs), plus `extra` face lines.
fn tetra_obj(dir: &Path, name: &str, uvs: bool, extra: &str) -> std::path::PathBuf {
    let mut s = String::from("o body_paint\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\n");
    if uvs {
        s += "vt 0.1 0.1\nvt 0.9 0.1\nvt 0.1 0.9\n";
    }
    let faces = [[1, 3, 2], [1, 2, 4], [1, 4, 3], [2, 3, 4]];
    for f in faces {
        if uvs {
            s += &format!("f {}/1 {}/2 {}/3\n", f[0], f[1], f[2]);
        } else {
            s += &format!("f {} {} {}\n", f[0], f[1], f[2]);
        }
    }
    s += extra;
    let p = dir.join(name);
    std::fs::write(&p, s).unwrap();
    p
}

fn err(mesh: &Path, tex: &Path, out: &Path, opts: &ExportOptions) -> String {
    format!(
        "{:#}",
        export::export(mesh, tex, out, opts).expect_err("export should fail")
    )
}

fn assert_empty(out: &Path) {
    if out.exists() {
        let left: Vec<_> = std::fs::read_dir(out)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert!(left.is_empty(), "files left behind: {left:?}");
    }
}

#[test]
fn closed_tetrahedron_exports() {
    let d = tempfile::tempdir().unwrap();
    let mesh = tetra_obj(d.path(), "tetra.obj", true, "");
    let tex = export_common::camo_png(d.path(), 16);
    let opts = ExportOptions {
        scale: "1:10".parse().unwrap(),
        ..Default::default()
    };
    let s = export::export(&mesh, &tex, &d.path().join("out"), &opts).unwrap();
    assert!(s.report.is_closed());
    // 1 m tetra at 1:10 → volume 100³ / 6 mm³.
    assert!(
        (s.report.volume_mm3 - 1e6 / 6.0).abs() < 1.0,
        "{}",
        s.report.volume_mm3
    );
    assert!(
        s.files.len() >= 9 && s.files.iter().all(|f| f.exists()),
        "{:?}",
        s.files
    );
}

#[test]
fn non_manifold_mesh_is_refused_naming_file_and_edges() {
    let d = tempfile::tempdir().unwrap();
    // A fin: a third triangle on the edge 1-2 (vertex 5 outside).
    let mesh = tetra_obj(d.path(), "fin.obj", true, "f 1/1 2/2 5/3\n");
    let tex = export_common::camo_png(d.path(), 16);
    let out = d.path().join("out");
    let no_repair = ExportOptions {
        repair: RepairMode::Off,
        ..Default::default()
    };
    let e = err(&mesh, &tex, &out, &no_repair);
    assert!(e.contains("fin.obj") && e.contains("non-manifold"), "{e}");
    assert!(e.contains("refusing"), "{e}");
    assert_empty(&out);
}

#[test]
fn open_mesh_is_refused_unless_allowed() {
    let d = tempfile::tempdir().unwrap();
    let s = "o body_paint\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 3/3 2/2\nf 1/1 2/2 4/3\nf 1/1 4/3 3/2\n";
    let mesh = d.path().join("open.obj");
    std::fs::write(&mesh, s).unwrap();
    let tex = export_common::camo_png(d.path(), 16);
    let out = d.path().join("out");
    let no_repair = ExportOptions {
        repair: RepairMode::Off,
        ..Default::default()
    };
    let e = err(&mesh, &tex, &out, &no_repair);
    assert!(e.contains("open.obj") && e.contains("3 open edges"), "{e}");
    assert_empty(&out);
    let opts = ExportOptions {
        allow_open: true,
        formats: vec![Format::ThreeMfTexture],
        ..Default::default()
    };
    let s = export::export(&mesh, &tex, &out, &opts).unwrap();
    assert!(s.notes.iter().any(|n| n.contains("written anyway")));
    assert!(out.join("open_texture.3mf").exists());
    // With repair (the default), a missing face up to --max-hole-mm is filled and the mesh closed.
    let opts = ExportOptions {
        formats: vec![Format::ThreeMfTexture],
        scale: "1:10".parse().unwrap(),
        max_hole_mm: 500.0,
        ..Default::default()
    };
    let s = export::export(&mesh, &tex, &out, &opts).unwrap();
    assert!(s.report.is_closed() && s.solid.is_none(), "{:?}", s.notes);
    assert!(
        s.notes.iter().any(|n| n.contains("small holes filled: 1")),
        "{:?}",
        s.notes
    );
}

#[test]
fn painted_part_without_uvs_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let mesh = tetra_obj(d.path(), "nouv.obj", false, "");
    let tex = export_common::camo_png(d.path(), 16);
    let out = d.path().join("out");
    let e = err(&mesh, &tex, &out, &ExportOptions::default());
    assert!(
        e.contains("nouv.obj") && e.contains("body_paint") && e.contains("no texture coordinates"),
        "{e}"
    );
    assert_empty(&out);
}

#[test]
fn huge_texture_is_refused_before_decoding() {
    let d = tempfile::tempdir().unwrap();
    let mesh = tetra_obj(d.path(), "t.obj", true, "");
    let tex = d.path().join("huge.png");
    let img = image::GrayImage::new(20_000, 4);
    img.save(&tex).unwrap();
    let out = d.path().join("out");
    let e = err(&mesh, &tex, &out, &ExportOptions::default());
    assert!(
        e.contains("huge.png") && e.contains("20000x4") && e.contains("16384"),
        "{e}"
    );
    assert_empty(&out);
}

#[test]
fn zero_scale_is_refused() {
    for s in ["1:0", "0", "1:-24"] {
        let e = format!("{:#}", s.parse::<Scale>().unwrap_err());
        assert!(e.contains(s) && e.contains("N > 0"), "{e}");
    }
    // Through the command line too.
    let d = tempfile::tempdir().unwrap();
    let tex = export_common::camo_png(d.path(), 16);
    let out = d.path().join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_cac"))
        .args(["export", "--mesh", "barrel", "--scale", "1:0", "--out"])
        .arg(&out)
        .arg("--texture")
        .arg(&tex)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("1:0"), "{err}");
    assert!(!out.exists());
}

#[test]
fn unwritable_output_folder_is_refused_naming_it() {
    let d = tempfile::tempdir().unwrap();
    let mesh = tetra_obj(d.path(), "t.obj", true, "");
    let tex = export_common::camo_png(d.path(), 16);
    // A regular file where a folder is needed (root ignores permission bits, so not chmod).
    let blocker = d.path().join("blocker");
    std::fs::write(&blocker, b"x").unwrap();
    let out = blocker.join("out");
    let e = err(&mesh, &tex, &out, &ExportOptions::default());
    assert!(
        e.contains("blocker/out") && e.contains("output folder"),
        "{e}"
    );
}

#[test]
fn unreadable_texture_and_missing_mesh_are_named() {
    let d = tempfile::tempdir().unwrap();
    let mesh = tetra_obj(d.path(), "t.obj", true, "");
    let bad = d.path().join("bad.png");
    std::fs::write(&bad, b"not an image").unwrap();
    let out = d.path().join("out");
    let e = err(&mesh, &bad, &out, &ExportOptions::default());
    assert!(e.contains("bad.png"), "{e}");
    let e = err(
        &d.path().join("missing.glb"),
        &bad,
        &out,
        &ExportOptions::default(),
    );
    assert!(
        e.contains("missing.glb") && e.contains("does not exist"),
        "{e}"
    );
    assert_empty(&out);
}
