//! The painted multi-material 3MF (`cac export --printer fdm.toml`): the painting encoder against
//! hand-worked strings and its own decoder, the export of a textured cube painted with four
//! filaments, and the real slicer: Debian's PrusaSlicer slices the 3MF with no flags (the file
//! carries its extruders, colours and wipe tower) into G-code whose tools and wall lengths follow
//! the painted areas. Under `CI=true` a missing `prusa-slicer` fails the test.

mod export_common;

use cac::export::painted::{child_corners, decode, encode, state_areas, Node};
use cac::export::{self, ExportOptions, Format};
use cac::printer::Profile;
use export_common::*;
use glam::Vec3;
use rand::{Rng, SeedableRng};
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

fn leaf(s: u8) -> Node {
    Node::Leaf(s)
}

/// Hand-worked strings: nibble = `sides | special << 2` for a split, `state << 2` for a leaf
/// below 3, `0xC` then `state − 3` above; children last-first; the hex digits reversed.
#[test]
fn encoder_matches_hand_worked_strings() {
    let leaves = [
        "0", "4", "8", "0C", "1C", "2C", "3C", "4C", "5C", "6C", "7C", "8C", "9C", "AC", "BC",
        "CC", "DC",
    ];
    for (s, want) in leaves.iter().enumerate() {
        assert_eq!(encode(&leaf(s as u8)), *want, "leaf of state {s}");
        assert_eq!(decode(want).unwrap(), leaf(s as u8));
    }
    // Split in four, leaves 1, 2, 3, 4: nibbles [3, (C,1), (C,0), 8, 4] → reversed.
    let q = Node::quad([leaf(1), leaf(2), leaf(3), leaf(4)]);
    assert_eq!(encode(&q), "480C1C3");
    assert_eq!(
        encode(&Node::quad([leaf(0), leaf(2), leaf(3), leaf(4)])),
        "080C1C3"
    );
    // One side (the side opposite corner 2), leaves 1 and 5: nibbles [1|2<<2 = 9, (C,2), 4].
    let one = Node::Split {
        sides: 1,
        special: 2,
        children: vec![leaf(1), leaf(5)],
    };
    assert_eq!(encode(&one), "42C9");
    // Two sides (side 1 kept), leaves 0, 2, 1: nibbles [2|1<<2 = 6, 4, 8, 0].
    let two = Node::Split {
        sides: 2,
        special: 1,
        children: vec![leaf(0), leaf(2), leaf(1)],
    };
    assert_eq!(encode(&two), "0846");
    // Two levels: nibbles [3, 4, 0, (C,0), 3, 8, 8, 4, 4] → "44883" "0C" "0" "4" "3".
    let nested = Node::quad([
        Node::quad([leaf(1), leaf(1), leaf(2), leaf(2)]),
        leaf(3),
        leaf(0),
        leaf(1),
    ]);
    assert_eq!(encode(&nested), "448830C043");
    for n in [&q, &one, &two, &nested] {
        assert_eq!(&decode(&encode(n)).unwrap(), n);
    }
    // Malformed strings are refused, saying why.
    for (bad, why) in [
        ("", "empty"),
        ("4g", "hex digit"),
        ("3", "ends inside"),
        ("C", "ends inside"),
        ("44", "left after"),
        ("0D", "special side 3"),
        ("4447", "3-side split names side 1"),
        ("EC", "above 16"),
    ] {
        let e = format!("{:#}", decode(bad).unwrap_err());
        assert!(e.contains(why), "{bad:?}: {e}");
    }
}

fn random_tree(rng: &mut impl Rng, depth: u32) -> Node {
    if depth == 0 || rng.random_bool(0.3) {
        return leaf(rng.random_range(0..=16));
    }
    let sides = rng.random_range(1..=3u8);
    let special = if sides == 3 {
        0
    } else {
        rng.random_range(0..3)
    };
    Node::Split {
        sides,
        special,
        children: (0..=sides).map(|_| random_tree(rng, depth - 1)).collect(),
    }
}

#[test]
fn random_trees_round_trip_and_splits_keep_the_area() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(50);
    for _ in 0..2000 {
        let t = random_tree(&mut rng, 5);
        t.check().unwrap();
        let s = encode(&t);
        assert!(s
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'A'..=b'F').contains(&b)));
        assert_eq!(decode(&s).unwrap(), t, "{s}");
        // The leaves tile the triangle: their areas add up to its area.
        let p = [
            Vec3::ZERO,
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(0.5, 2.0, 1.0),
        ];
        let mut a = vec![];
        state_areas(&t, p, &mut a);
        let whole = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length() as f64;
        assert!((a.iter().sum::<f64>() - whole).abs() < 1e-5 * whole);
    }
    // The slicers' children: a 4-way split into quarters around the midpoints; a 1-side split
    // with special side 1 halves the side opposite corner 1 (corners taken from corner 1 on).
    let c = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let q = child_corners(3, 0, c);
    assert_eq!(
        q[3],
        [Vec3::X * 0.5, Vec3::new(0.5, 0.5, 0.0), Vec3::Y * 0.5]
    );
    assert_eq!(q[0], [Vec3::ZERO, Vec3::X * 0.5, Vec3::Y * 0.5]);
    let h = child_corners(1, 1, c);
    assert_eq!(h[0], [Vec3::X, Vec3::Y, Vec3::new(0.0, 0.5, 0.0)]);
    assert_eq!(h[1], [Vec3::new(0.0, 0.5, 0.0), Vec3::ZERO, Vec3::X]);
}

/// The four filaments: measured colours of basic PLA as the printer profile states them.
const FILAMENTS: [(&str, &str); 4] = [
    ("white", "#F2F2F0"),
    ("black", "#1A1A1A"),
    ("red", "#C12E1F"),
    ("blue", "#0A2989"),
];

fn profile_toml(object_size_mm: f32) -> String {
    let mut s = format!(
        "name = \"four PLA\"\n[fdm]\nnozzle_mm = 0.4\nlayer_mm = 0.2\nobject_size_mm = {object_size_mm}\n"
    );
    for (n, c) in FILAMENTS {
        s += &format!("[[fdm.filaments]]\nname = \"{n}\"\nsrgb = \"{c}\"\nsource = \"test\"\n");
    }
    s
}

fn write_profile(dir: &Path, name: &str, text: &str) -> Profile {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    Profile::load(&p).unwrap()
}

/// A 64-texel texture in four quadrants of the filaments' colours: white top-left, black
/// top-right, red bottom-left, blue bottom-right (row 0 is `v = 1`).
fn quadrant_png(dir: &Path) -> PathBuf {
    let rgb = |h: &str| {
        let v = u32::from_str_radix(&h[1..], 16).unwrap();
        image::Rgb([(v >> 16) as u8, (v >> 8) as u8, v as u8])
    };
    let img = image::RgbImage::from_fn(64, 64, |x, y| {
        rgb(FILAMENTS[(y >= 32) as usize * 2 + (x >= 32) as usize].1)
    });
    let p = dir.join("quadrants.png");
    img.save(&p).unwrap();
    p
}

/// A 1 m cube (scene frame, Y up; `body_paint`), each face mapped onto a rectangle of the
/// quadrant texture. In the print frame (+Z up, scene −Z → print +Y): +X white, −X black, −Y half
/// white half black (split vertically), +Y upper half white and lower half red, top blue,
/// bottom red. Sides: white 2 faces, black 1.5, red 0.5 → 50 / 37.5 / 12.5 %.
fn cube_obj(dir: &Path) -> PathBuf {
    // (normal, up-ish tangent, uv rectangle u0 u1 v0 v1)
    let faces: [(Vec3, Vec3, [f32; 4]); 6] = [
        (Vec3::X, Vec3::Y, [0.05, 0.45, 0.55, 0.95]),
        (-Vec3::X, Vec3::Y, [0.55, 0.95, 0.55, 0.95]),
        (Vec3::Z, Vec3::Y, [0.25, 0.75, 0.55, 0.95]),
        (-Vec3::Z, Vec3::Y, [0.05, 0.45, 0.25, 0.75]),
        (Vec3::Y, Vec3::Z, [0.55, 0.95, 0.05, 0.45]),
        (-Vec3::Y, Vec3::Z, [0.05, 0.45, 0.05, 0.45]),
    ];
    let mut s = String::from("o body_paint\n");
    let mut f = String::new();
    for (k, (n, e2, r)) in faces.iter().enumerate() {
        let e1 = e2.cross(*n); // e1 × e2 = n: corners counter-clockwise seen from outside
        for (a, b) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            let p = *n * 0.5 + e1 * (a - 0.5) + *e2 * (b - 0.5) + Vec3::Y * 0.5;
            s += &format!("v {} {} {}\n", p.x, p.y, p.z);
            s += &format!(
                "vt {} {}\n",
                r[0] + a * (r[1] - r[0]),
                r[2] + b * (r[3] - r[2])
            );
        }
        let i = 4 * k + 1;
        f += &format!("f {0}/{0} {1}/{1} {2}/{2}\n", i, i + 1, i + 2);
        f += &format!("f {0}/{0} {1}/{1} {2}/{2}\n", i, i + 2, i + 3);
    }
    let p = dir.join("cube.obj");
    std::fs::write(&p, s + &f).unwrap();
    p
}

/// What the painted 3MF holds: vertices, triangles with their two painting attributes, and the
/// package's files.
struct Painted3mf {
    vertices: Vec<Vec3>,
    tris: Vec<([usize; 3], String, String)>,
    files: HashMap<String, String>,
}

fn read_painted(path: &Path) -> Painted3mf {
    let mut zip = zip::ZipArchive::new(std::fs::File::open(path).unwrap()).unwrap();
    let mut files = HashMap::new();
    for i in 0..zip.len() {
        let mut f = zip.by_index(i).unwrap();
        let mut s = String::new();
        f.read_to_string(&mut s).unwrap();
        files.insert(f.name().to_string(), s);
    }
    let xml = &files["3D/3dmodel.model"];
    let mut rd = quick_xml::Reader::from_str(xml);
    let (mut vertices, mut tris) = (vec![], vec![]);
    loop {
        match rd.read_event().unwrap() {
            quick_xml::events::Event::Empty(e) => {
                let a: HashMap<String, String> = e
                    .attributes()
                    .map(|a| {
                        let a = a.unwrap();
                        let v = a
                            .normalized_value(quick_xml::XmlVersion::Explicit1_0)
                            .unwrap()
                            .into_owned();
                        (String::from_utf8_lossy(a.key.as_ref()).into_owned(), v)
                    })
                    .collect();
                match e.name().as_ref() {
                    b"vertex" => {
                        let c = |k: &str| a[k].parse::<f32>().unwrap();
                        vertices.push(Vec3::new(c("x"), c("y"), c("z")));
                    }
                    b"triangle" => {
                        assert!(!a.contains_key("pid"), "no colour properties: {a:?}");
                        let v = |k: &str| a[k].parse::<usize>().unwrap();
                        tris.push((
                            [v("v1"), v("v2"), v("v3")],
                            a["slic3rpe:mmu_segmentation"].clone(),
                            a["paint_color"].clone(),
                        ));
                    }
                    _ => {}
                }
            }
            quick_xml::events::Event::Eof => break,
            _ => {}
        }
    }
    Painted3mf {
        vertices,
        tris,
        files,
    }
}

/// Area per extruder (index 0 = extruder 1) of the painting, on the triangles `keep` selects
/// by unit normal.
fn painted_areas(m: &Painted3mf, keep: impl Fn(Vec3) -> bool) -> Vec<f64> {
    let mut by_state = vec![0.0; 5];
    for (v, code, _) in &m.tris {
        let p = v.map(|i| m.vertices[i]);
        if keep((p[1] - p[0]).cross(p[2] - p[0]).normalize()) {
            state_areas(&decode(code).unwrap(), p, &mut by_state);
        }
    }
    assert_eq!(by_state[0], 0.0, "every leaf names an extruder");
    by_state[1..].to_vec()
}

/// Area per extruder of the leaves of vertical triangles whose centre lies between heights
/// `z0` and `z1` (mm).
fn side_areas_between(m: &Painted3mf, z0: f32, z1: f32) -> Vec<f64> {
    fn walk(n: &Node, p: [Vec3; 3], z: (f32, f32), out: &mut [f64]) {
        match n {
            Node::Leaf(s) => {
                let c = (p[0] + p[1] + p[2]) / 3.0;
                if c.z > z.0 && c.z < z.1 {
                    out[*s as usize] += 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length() as f64;
                }
            }
            Node::Split {
                sides,
                special,
                children,
            } => {
                for (k, q) in children.iter().zip(child_corners(*sides, *special, p)) {
                    walk(k, q, z, out);
                }
            }
        }
    }
    let mut out = vec![0.0; 5];
    for (v, code, _) in &m.tris {
        let p = v.map(|i| m.vertices[i]);
        if (p[1] - p[0]).cross(p[2] - p[0]).normalize().z.abs() < 0.1 {
            walk(&decode(code).unwrap(), p, (z0, z1), &mut out);
        }
    }
    out[1..].to_vec()
}

fn shares(v: &[f64]) -> Vec<f64> {
    let t: f64 = v.iter().sum();
    v.iter().map(|x| x / t).collect()
}

/// One tool's outer-wall extrusion: the `External perimeter` segments of the G-code that run
/// along the object's outer faces (both ends within 0.05 mm of the same side of the box the
/// external perimeters span) on layers between heights `z0` and `z1` (mm), summed per tool (mm
/// of path).
fn outer_wall_lengths(gcode: &str, tools: usize, z0: f64, z1: f64) -> Vec<f64> {
    let (mut tool, mut feature, mut pos) = (0usize, String::new(), (0.0f64, 0.0f64));
    let mut z = 0.0f64;
    let mut segs = vec![];
    for line in gcode.lines() {
        if let Some(f) = line.strip_prefix(";TYPE:") {
            feature = f.trim().to_string();
            continue;
        }
        let code = line.split(';').next().unwrap().trim();
        let mut w = code.split_whitespace();
        match w.next() {
            Some(t) if t.starts_with('T') && t[1..].parse::<usize>().is_ok() => {
                tool = t[1..].parse().unwrap()
            }
            Some("G0" | "G1") => {
                let (mut x, mut y, mut e) = (pos.0, pos.1, 0.0);
                for a in w {
                    match &a[..1] {
                        "X" => x = a[1..].parse().unwrap(),
                        "Y" => y = a[1..].parse().unwrap(),
                        "Z" => z = a[1..].parse().unwrap(),
                        "E" => e = a[1..].parse().unwrap(),
                        _ => {}
                    }
                }
                let inside = z > z0 && z < z1;
                if e > 0.0 && feature == "External perimeter" && (x, y) != pos && inside {
                    segs.push((tool, pos, (x, y)));
                }
                pos = (x, y);
            }
            _ => {}
        }
    }
    let (mut lo, mut hi) = ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN));
    for (_, a, b) in &segs {
        for p in [a, b] {
            lo = (lo.0.min(p.0), lo.1.min(p.1));
            hi = (hi.0.max(p.0), hi.1.max(p.1));
        }
    }
    let near = |v: f64, w: f64| (v - w).abs() < 0.05;
    let mut len = vec![0.0; tools];
    for (t, a, b) in segs {
        let on_side = (near(a.0, lo.0) && near(b.0, lo.0))
            || (near(a.0, hi.0) && near(b.0, hi.0))
            || (near(a.1, lo.1) && near(b.1, lo.1))
            || (near(a.1, hi.1) && near(b.1, hi.1));
        if on_side {
            len[t] += ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
        }
    }
    len
}

fn export_cube(dir: &Path, slice: bool) -> (export::ExportSummary, PathBuf) {
    let mesh = cube_obj(dir);
    let tex = quadrant_png(dir);
    let opts = ExportOptions {
        formats: vec![Format::ThreeMfTexture, Format::Obj],
        scale: "1:50".parse().unwrap(),
        printer: Some(write_profile(dir, "four.toml", &profile_toml(20.0))),
        slice,
        ..Default::default()
    };
    let out = dir.join("out");
    (export::export(&mesh, &tex, &out, &opts).unwrap(), out)
}

/// The painted cube as written: both attributes on every triangle, the slicers' settings files,
/// the painting's areas against the faces' colours, and the summary's shares.
#[test]
fn painted_cube_carries_the_painting_and_the_filaments() {
    let d = tempfile::tempdir().unwrap();
    let (s, out) = export_cube(d.path(), false);
    let names: Vec<String> = s
        .files
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert!(names.contains(&"cube_painted.3mf".to_string()), "{names:?}");
    assert!(
        names.contains(&"cube.obj".to_string()),
        "other formats still written"
    );
    assert!(
        !names.iter().any(|n| n.ends_with("_texture.3mf")),
        "{names:?}"
    );
    assert!(s
        .notes
        .iter()
        .any(|n| n.contains("3mf-painted instead of 3mf-texture")));
    let m = read_painted(&out.join("cube_painted.3mf"));
    assert_eq!(m.tris.len(), 12);
    for (_, a, b) in &m.tris {
        assert_eq!(a, b, "slic3rpe:mmu_segmentation and paint_color agree");
    }
    let model = &m.files["3D/3dmodel.model"];
    assert!(model.contains("xmlns:slic3rpe=\"http://schemas.slic3r.org/3mf/2017/06\""));
    assert!(model.contains("<metadata name=\"slic3rpe:MmPaintingVersion\">1</metadata>"));
    let cfg = &m.files["Metadata/Slic3r_PE.config"];
    assert!(cfg.starts_with("; generated by cac export"), "{cfg}");
    for line in [
        "; nozzle_diameter = 0.4,0.4,0.4,0.4",
        "; extruder_colour = #F2F2F0;#1A1A1A;#C12E1F;#0A2989",
        "; filament_colour = #F2F2F0;#1A1A1A;#C12E1F;#0A2989",
        "; wipe_tower = 1",
        "; layer_height = 0.2",
    ] {
        assert!(cfg.lines().any(|l| l == line), "{line} in\n{cfg}");
    }
    let bambu: serde_json::Value =
        serde_json::from_str(&m.files["Metadata/project_settings.config"]).unwrap();
    assert_eq!(bambu["filament_colour"][2], "#C12E1F");
    assert!(m.files["[Content_Types].xml"].contains("Extension=\"config\""));

    // Uniform faces are single leaves; the split faces are split along the colour border.
    let leaves: Vec<usize> = m
        .tris
        .iter()
        .map(|t| decode(&t.1).unwrap().leaves())
        .collect();
    assert_eq!(leaves.iter().filter(|&&n| n == 1).count(), 8, "{leaves:?}");
    let sides = shares(&painted_areas(&m, |n| n.z.abs() < 0.1));
    for (got, want) in sides.iter().zip([0.5, 0.375, 0.125, 0.0]) {
        assert!((got - want).abs() < 0.01, "side shares {sides:?}");
    }
    let p = s.painting.as_ref().unwrap();
    assert_eq!(p.filaments[3], ("blue".to_string(), "#0A2989".to_string()));
    for (got, want) in p
        .shares()
        .iter()
        .zip([2.0 / 6.0, 1.5 / 6.0, 1.5 / 6.0, 1.0 / 6.0])
    {
        assert!((got - want).abs() < 0.01, "{:?}", p.shares());
    }
    let all = shares(&painted_areas(&m, |_| true));
    for (a, b) in all.iter().zip(p.shares()) {
        assert!((a - b).abs() < 1e-6, "the summary is the file's painting");
    }
    let text = s.to_string();
    assert!(
        text.contains("painted for four PLA") && text.contains("red (#C12E1F) 25.0 %"),
        "{text}"
    );
}

/// PrusaSlicer slices the painted cube with no flags. Measured: the tools the G-code selects
/// (T0..T3) are the painted filaments; each tool's `; filament used [mm]` is positive and agrees
/// within 1 % with the extrusion moves we parse (priming excluded, as the slicer does); and the
/// walls follow the painting: each tool's share of the outer-wall extrusion path (`External
/// perimeter` segments lying on the cube's sides) is within 5 % (relative) of its share of the
/// painted side area, both taken between heights 2 and 18 mm. The slicer projects the painted
/// top and bottom down and up through the top and bottom solid layers, walls included, so the
/// walls of the first and last layers take the top's and bottom's colours (over the whole
/// height blue, painted on the top only, has 4 % of the wall); the window leaves them out. The
/// whole `filament used` is not compared with area shares: it includes the wipe tower's purge,
/// and the slicer fills each layer's interior from the nearest painted wall, which no surface
/// share predicts.
#[test]
fn prusaslicer_slices_the_painted_cube_into_the_painted_tools() {
    if !have_prusa() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let (s, out) = export_cube(d.path(), true);
    let cost = s.slice.as_ref().expect("sliced");
    let gcode_path = out.join("cube_painted.gcode");
    assert!(s.files.contains(&gcode_path));
    let gcode = std::fs::read_to_string(&gcode_path).unwrap();
    assert!(cost.slicer.starts_with("PrusaSlicer"), "{cost:?}");
    assert_eq!(cost.tools_used, vec![0, 1, 2, 3], "{cost:?}");
    assert_eq!(
        cost.filament_mm.len(),
        4,
        "four extruders from the 3MF's own settings"
    );
    let total_changes = gcode
        .lines()
        .find_map(|l| l.strip_prefix("; total toolchanges = "))
        .map(|v| v.trim().parse::<usize>().unwrap());
    assert_eq!(
        Some(cost.tool_changes),
        total_changes,
        "our count is the slicer's"
    );
    assert!(cost.tool_changes >= 3);
    for t in 0..4 {
        assert!(cost.filament_mm[t] > 0.0, "{cost:?}");
        let rel = (cost.extruded_mm[t] - cost.filament_mm[t]).abs() / cost.filament_mm[t];
        assert!(
            rel < 0.01,
            "tool {t}: parsed {} vs slicer {}",
            cost.extruded_mm[t],
            cost.filament_mm[t]
        );
        assert!(cost.wipe_tower_mm[t] >= 0.0);
    }
    assert!(
        cost.wipe_tower_mm.iter().sum::<f64>() > 0.0,
        "the wipe tower purges"
    );
    assert!(cost.print_time_s.is_some_and(|t| t > 60.0), "{cost:?}");

    let m = read_painted(&out.join("cube_painted.3mf"));
    let (z0, z1) = (2.0, 18.0);
    let area = shares(&side_areas_between(&m, z0 as f32, z1 as f32));
    let wall = shares(&outer_wall_lengths(&gcode, 4, z0, z1));
    let whole_wall = shares(&outer_wall_lengths(&gcode, 4, 0.0, 99.0));
    eprintln!(
        "whole height: outer-wall shares {whole_wall:.4?} against side-area shares {:.4?}",
        shares(&painted_areas(&m, |n| n.z.abs() < 0.1))
    );
    eprintln!("side-area shares {area:.4?}\nouter-wall shares {wall:.4?}\nfilament used [mm] {:?}\nwipe tower [mm] {:.1?}\n{}", cost.filament_mm, cost.wipe_tower_mm, cost.line());
    for t in 0..4 {
        if area[t] > 0.0 {
            assert!(
                (wall[t] - area[t]).abs() <= 0.05 * area[t],
                "tool {t}: wall share {:.4} vs area share {:.4} (all: {wall:?} vs {area:?})",
                wall[t],
                area[t]
            );
        } else {
            assert!(wall[t] < 0.005, "tool {t} paints no wall: {wall:?}");
        }
    }
    assert!(s.to_string().contains("tool changes"));
}

/// Refusals: a scale that does not match the profile's object size (both numbers named), a
/// full-colour profile with a 3MF format, `3mf-painted` without a printer, `--slice` without
/// the painted 3MF.
#[test]
fn mismatches_are_refused_naming_both_sides() {
    let d = tempfile::tempdir().unwrap();
    let mesh = cube_obj(d.path());
    let tex = quadrant_png(d.path());
    let run = |opts: ExportOptions| {
        format!(
            "{:#}",
            export::export(&mesh, &tex, &d.path().join("x"), &opts).unwrap_err()
        )
    };
    let fdm = write_profile(d.path(), "p.toml", &profile_toml(30.0));
    let e = run(ExportOptions {
        formats: vec![Format::ThreeMfColor],
        scale: "1:50".parse().unwrap(),
        printer: Some(fdm.clone()),
        ..Default::default()
    });
    assert!(
        e.contains("30.0 mm") && e.contains("20.0 mm") && e.contains("1:33.3"),
        "{e}"
    );
    let full = write_profile(
        d.path(),
        "f.toml",
        "name = \"binder\"\n[full_colour.response]\nmatrix = [[1,0,0,0,0,0],[0,1,0,0,0,0],[0,0,1,0,0,0]]\n",
    );
    // A full-colour profile writes the texture as requested, and adds VRML.
    let out = d.path().join("full");
    let sum = export::export(
        &mesh,
        &tex,
        &out,
        &ExportOptions {
            formats: vec![Format::ThreeMfTexture],
            scale: "1:50".parse().unwrap(),
            printer: Some(full),
            ..Default::default()
        },
    )
    .unwrap();
    assert!(out.join("cube_texture.3mf").exists() && out.join("cube.wrl").exists());
    assert!(format!("{sum}").contains("as requested"), "{sum}");
    check_vrml(&out.join("cube.wrl"), 12);
    let e = run(ExportOptions {
        formats: vec![Format::ThreeMfPainted],
        scale: "1:50".parse().unwrap(),
        ..Default::default()
    });
    assert!(e.contains("--printer"), "{e}");
    let e = run(ExportOptions {
        formats: vec![Format::Obj],
        scale: "1:50".parse().unwrap(),
        printer: Some(fdm),
        slice: true,
        ..Default::default()
    });
    assert!(e.contains("--slice"), "{e}");
    assert!(!d.path().join("x").join("cube_painted.3mf").exists());
    assert_eq!(
        "3mf-painted".parse::<Format>().unwrap(),
        Format::ThreeMfPainted
    );
}

/// A VRML 2.0 file as a print service reads it: the header, every face a triangle of points that
/// exist, as many texture corners as face corners, and the textures beside it.
fn check_vrml(path: &Path, triangles: usize) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.starts_with("#VRML V2.0 utf8\n"), "{}", &text[..40]);
    let list = |after: &str, from: usize| -> Vec<f64> {
        let start = text[from..].find(after).unwrap() + from + after.len();
        let end = text[start..].find(']').unwrap() + start;
        text[start..end]
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|t| !t.is_empty())
            .map(|t| t.parse().unwrap())
            .collect()
    };
    let (mut faces, mut from) = (0, 0);
    while let Some(k) = text[from..].find("geometry IndexedFaceSet") {
        let at = from + k;
        let points = list("coord Coordinate { point [", at).len() / 3;
        let index = list("coordIndex [", at);
        for face in index.split(|v| *v == -1.0).filter(|f| !f.is_empty()) {
            assert_eq!(face.len(), 3);
            assert!(face.iter().all(|&i| i >= 0.0 && (i as usize) < points));
            faces += 1;
        }
        if let Some(u) = text[at..].find("texCoordIndex [") {
            let next = text[at + 1..].find("geometry IndexedFaceSet");
            if next.is_none_or(|n| u < n + 1) {
                let uvs = list("TextureCoordinate { point [", at).len() / 2;
                let ui = list("texCoordIndex [", at);
                assert_eq!(ui.len(), index.len(), "a texture corner per face corner");
                assert!(ui.iter().all(|&i| i == -1.0 || (i as usize) < uvs));
            }
        }
        from = at + 1;
    }
    assert_eq!(faces, triangles);
    for url in text.split("url \"").skip(1) {
        let name = &url[..url.find('"').unwrap()];
        assert!(path.with_file_name(name).exists(), "{name}");
    }
}

/// `cac export --printer four.toml [--slice]` from the command line: the painted 3MF instead of
/// the colour 3MF, the painting's line and (with PrusaSlicer) the cost line in the summary; a
/// scale that does not fit the profile is an error naming both sizes.
#[test]
fn command_line_export_with_a_printer_profile() {
    let d = tempfile::tempdir().unwrap();
    let mesh = cube_obj(d.path());
    let tex = quadrant_png(d.path());
    let prof = d.path().join("four.toml");
    std::fs::write(&prof, profile_toml(20.0)).unwrap();
    let out = d.path().join("o");
    let slice = have_prusa();
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "export".as_ref(),
        "--mesh".as_ref(),
        mesh.as_os_str(),
        "--texture".as_ref(),
        tex.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--scale".as_ref(),
        "1:50".as_ref(),
        "--formats".as_ref(),
        "3mf-color,obj-vc".as_ref(),
        "--printer".as_ref(),
        prof.as_os_str(),
    ];
    if slice {
        args.push("--slice".as_ref());
    }
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_cac"))
        .args(&args)
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{text}");
    assert!(
        text.contains("painted for four PLA (4 filaments)"),
        "{text}"
    );
    assert!(out.join("cube_painted.3mf").exists() && out.join("cube_vc.obj").exists());
    assert!(!out.join("cube_color.3mf").exists());
    if slice {
        assert!(
            text.contains("tool changes") && text.contains("estimated print time"),
            "{text}"
        );
        assert!(out.join("cube_painted.gcode").exists());
    }
    let mut wrong = args[..args.len() - slice as usize].to_vec();
    wrong[8] = "1:40".as_ref();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_cac"))
        .args(&wrong)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("20.0 mm") && e.contains("25.0 mm"),
        "{e}"
    );
}
