//! Printer calibration on the digital twin (docs/physical.md, "Calibrating a printer"): a
//! simulated printer (per-channel tone curves, ink crosstalk, gamut compression, paper white and
//! seeded per-patch noise; not a root-polynomial) prints the chart, the rig's twin photographs
//! it turned 30° away and looked down on by 10°, under a warm lamp, through the webcam's barrel
//! distortion, and `calibrate` must recover the printer: mean ΔE2000 ≤ 2 on the held-out patches
//! and against the simulated printer itself on fresh colours. Bad photos are refused naming what
//! is wrong. Seeded throughout.

use cac::bench::calibration::truth;
use cac::physical::print_calib::{
    calibrate, photograph, CalibrateOptions, Chart, ChartSpec, PrinterKind, Role, Shot,
    SimulatedPrinter,
};
use cac::physical::rig::Rig;
use cac::physical::twin::{DigitalTwin, Pose};
use cac::printer::Profile;
use image::RgbImage;
use std::path::Path;
use std::sync::Arc;

fn chart(kind: PrinterKind, patches: usize, seed: u64) -> Chart {
    Chart::new(&ChartSpec {
        kind,
        patches,
        seed,
        checker_pitch_mm: 13.0,
        filaments: vec![],
    })
    .unwrap()
}

fn shoot(chart: &Chart, printer: &SimulatedPrinter, shot: &Shot) -> RgbImage {
    let side = shot.atlas as u32;
    let page = printer.printed_page(chart, side, side, chart.seed);
    photograph(&page, chart, shot).unwrap()
}

fn err(r: anyhow::Result<impl std::fmt::Debug>) -> String {
    format!("{:#}", r.expect_err("refused"))
}

#[test]
fn the_twin_photo_of_a_printed_chart_recovers_the_printer() {
    let c = chart(PrinterKind::FullColour, 192, 7);
    let dir = tempfile::tempdir().unwrap();
    c.write(dir.path()).unwrap();
    assert_eq!(Chart::load(&dir.path().join("chart.json")).unwrap(), c);
    let png = image::open(dir.path().join("chart.png")).unwrap();
    assert_eq!((png.width(), png.height()), (3508, 2480), "300 dpi A4");

    let printer = SimulatedPrinter::default();
    let shot = Shot::default();
    assert!(shot.angle_deg >= 20.0);
    let photo = shoot(&c, &printer, &shot);
    let opts = CalibrateOptions::default();
    let cal = calibrate(&c, &photo, &opts, Some(&shot.lens), "twin.png").unwrap();
    eprintln!("{}", cal.summary());
    let [held_mean, held_p95] = cal.held_out_de2000.unwrap();
    let response = &cal.profile.full_colour.as_ref().unwrap().response;
    assert_eq!(response.held_out_de2000, Some([held_mean, held_p95]));
    let [true_mean, true_p95] = truth(response, &printer, 2000, 99);
    eprintln!("truth on 2000 fresh colours: ΔE2000 mean {true_mean:.2}, p95 {true_p95:.2}");
    assert!(held_mean <= 2.0, "held-out ΔE2000 {held_mean}");
    assert!(
        true_mean <= 2.0,
        "ΔE2000 against the simulated printer {true_mean}"
    );
    assert!(
        cal.checker_de2000[0] < 1.0,
        "camera correction {:?}",
        cal.checker_de2000
    );
    assert_eq!(cal.fitted + cal.held_out, 192);
    assert_eq!(cal.held_out, 38);

    // The profile written is the one read back.
    let path = dir.path().join("printer.toml");
    cal.write(&path).unwrap();
    let back = Profile::load(&path).unwrap();
    assert_eq!(back.kind(), "full-colour");
    assert_eq!(back, cal.profile);

    // The same photo read as a paper chart of the same layout: a [paper] profile, which needs
    // the media's width.
    let mut paper = c.clone();
    paper.printer = PrinterKind::Paper;
    assert!(
        err(calibrate(&paper, &photo, &opts, Some(&shot.lens), "p")).contains("--media-width-mm")
    );
    let with_width = CalibrateOptions {
        media_width_mm: Some(610.0),
        ..opts.clone()
    };
    let p = calibrate(&paper, &photo, &with_width, Some(&shot.lens), "p").unwrap();
    assert_eq!(p.profile.paper.as_ref().unwrap().media_width_mm, 610.0);
    assert_eq!(p.profile.kind(), "paper");
}

#[test]
fn bad_photos_are_refused_saying_what_is_wrong() {
    let c = chart(PrinterKind::FullColour, 96, 3);
    let printer = SimulatedPrinter::default();
    let shot = Shot::default();
    let lens = Some(&shot.lens);
    let opts = CalibrateOptions::default();
    let good = shoot(&c, &printer, &shot);

    // A chart of another printer kind than the profile asked for.
    let paper = CalibrateOptions {
        printer: Some(PrinterKind::Paper),
        media_width_mm: Some(600.0),
        ..opts.clone()
    };
    let e = err(calibrate(&c, &good, &paper, lens, "x"));
    assert!(
        e.contains("full-colour chart") && e.contains("--printer"),
        "{e}"
    );

    // A photo of another chart (another seed).
    let e = err(calibrate(
        &chart(PrinterKind::FullColour, 96, 4),
        &good,
        &opts,
        lens,
        "x",
    ));
    assert!(e.contains("do not follow this chart"), "{e}");

    // A photo too small.
    let small = image::imageops::resize(&good, 200, 150, image::imageops::FilterType::Triangle);
    let e = err(calibrate(&c, &small, &opts, lens, "x"));
    assert!(e.contains("too small"), "{e}");

    // Overexposed: the paper and the light patches clip.
    let bright = shoot(
        &c,
        &printer,
        &Shot {
            exposure: 1.8,
            ..shot.clone()
        },
    );
    let e = err(calibrate(&c, &bright, &opts, lens, "x"));
    assert!(e.contains("overexposed") && e.contains("clipped"), "{e}");

    // No chart at all: the rig's usual photo of the pickup.
    let rig = Rig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("calib/rig.toml")).unwrap();
    let pose = Pose {
        angle_deg: 40.0,
        horizontal_m: rig.horizontal_distance(2.0).unwrap(),
    };
    let atlas = rig.renderer.scene.initial_atlas(64);
    let twin = DigitalTwin::new(Arc::new(rig), &atlas, Box::new(move || Ok(pose)), 5);
    let pickup = twin.render(pose, 0).unwrap().image;
    let e = err(calibrate(&c, &pickup, &opts, lens, "x"));
    assert!(e.contains("fiducials not found"), "{e}");
}

#[test]
fn an_fdm_chart_measures_the_filament_swatches_laid_on_it() {
    let spec = ChartSpec {
        kind: PrinterKind::Fdm,
        patches: 0,
        seed: 1,
        checker_pitch_mm: 13.0,
        filaments: [
            "white=#F2F2F0",
            "black=#1A1A1A",
            "red=#C12E1F",
            "blue=#0A2989",
        ]
        .map(String::from)
        .to_vec(),
    };
    let c = Chart::new(&spec).unwrap();
    let shot = Shot::default();
    let photo = shoot(&c, &SimulatedPrinter::default(), &shot);
    let opts = CalibrateOptions::default();
    assert!(err(calibrate(&c, &photo, &opts, Some(&shot.lens), "f")).contains("--object-size-mm"));
    let opts = CalibrateOptions {
        object_size_mm: Some(220.0),
        ..opts
    };
    let cal = calibrate(&c, &photo, &opts, Some(&shot.lens), "f.png").unwrap();
    eprintln!("{}", cal.summary());
    let fdm = cal.profile.fdm.as_ref().unwrap();
    assert_eq!(fdm.filaments.len(), 4);
    for (f, (_, p)) in fdm.filaments.iter().zip(c.of(Role::Filament)) {
        assert_eq!(f.name, p.name);
        let de = cac::colour::delta_e2000_srgb(
            cac::colour::from_hex(&f.srgb).unwrap(),
            cac::colour::from_hex(&p.srgb).unwrap(),
        );
        assert!(
            de <= 2.0,
            "{}: measured {} for {} (ΔE2000 {de})",
            f.name,
            f.srgb,
            p.srgb
        );
    }
    assert_eq!(cal.profile.printer().unwrap().palette().len(), 4);
}
