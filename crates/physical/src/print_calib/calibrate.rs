//! `cac print calibrate`: a printer profile from a photograph of its printed chart. The photo is
//! checked before anything is fitted, and refused naming what is wrong: a chart of another
//! printer kind than `--printer`, a photo too small (short side under 240 pixels, or patches
//! under 8 pixels across), the fiducial markers not found, patches that do not follow the chart
//! (a photo of another chart), clipped patches (overexposed), a ColorChecker grey row out of
//! order (no card on its squares).

use super::chart::{Chart, PrinterKind, Role};
use super::detect::{self, PatchReading, CLIPPED_SHARE, MIN_PATCH_PX, MIN_SIDE_PX};
use super::fit::{self, CameraCorrection};
use crate::calib::CameraModel;
use anyhow::{bail, Context, Result};
use cac_core::colour;
use cac_core::printer::{Fdm, Filament, FullColour, Paper, Profile};
use cac_core::report::timer::Stopwatch;
use image::RgbImage;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};

/// How to calibrate (`cac print calibrate`'s flags but the files).
#[derive(Clone, Debug)]
pub struct CalibrateOptions {
    /// The kind of printer the profile is for (default: the chart's); a photo of a chart made
    /// for another kind is refused.
    pub printer: Option<PrinterKind>,
    /// The profile's name (default: the printer kind and the photo's file name).
    pub name: Option<String>,
    /// Share of the printed patches held out of the fit to judge it (0 to 0.5).
    pub held_out: f32,
    /// Seed of the held-out draw.
    pub seed: u64,
    /// Paper: the printable width of the media (roll or sheet), mm; required for paper.
    pub media_width_mm: Option<f32>,
    /// The camera's calibration (OpenCV or ROS YAML, e.g. calib/camera_opencv.yaml): the chart
    /// is read through its lens distortion (recommended for wide-angle webcams).
    pub intrinsics: Option<PathBuf>,
    /// FDM: nozzle width, mm.
    pub nozzle_mm: f32,
    /// FDM: layer height, mm.
    pub layer_mm: f32,
    /// FDM: the object's longest side as it will be printed, mm; required for fdm.
    pub object_size_mm: Option<f32>,
}

impl Default for CalibrateOptions {
    fn default() -> Self {
        CalibrateOptions {
            printer: None,
            name: None,
            held_out: 0.2,
            seed: 1,
            media_width_mm: None,
            intrinsics: None,
            nozzle_mm: 0.4,
            layer_mm: 0.2,
            object_size_mm: None,
        }
    }
}

/// A calibration: the profile and how it was judged.
#[derive(Clone, Debug)]
pub struct Calibration {
    pub profile: Profile,
    /// The markers in the photo (pixels): top-left, top-right, bottom-right, bottom-left.
    pub markers_px: [[f64; 2]; 4],
    /// The smallest patch's side in the photo, pixels.
    pub smallest_patch_px: f64,
    /// ΔE2000 of the ColorChecker after the camera's correction against its published values:
    /// mean and largest.
    pub checker_de2000: [f32; 2],
    /// Printed patches fitted and held out, and clipped ones left out of both.
    pub fitted: usize,
    pub held_out: usize,
    pub clipped: usize,
    /// ΔE2000 of the response on the fitted patches (mean, 95th percentile).
    pub fit_de2000: Option<[f32; 2]>,
    /// ΔE2000 on the held-out patches (mean, 95th percentile), as written in the profile.
    pub held_out_de2000: Option<[f32; 2]>,
    /// Time of the camera correction and the response's fit (ms), the chart found and read.
    pub fit_ms: f64,
}

impl Calibration {
    /// What `cac print calibrate` prints.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "{} profile {:?}\nchart found: markers at {}; smallest patch {:.1} px\ncamera corrected by the ColorChecker: ΔE2000 mean {:.2}, max {:.2}\n",
            self.profile.kind(),
            self.profile.name,
            self.markers_px
                .iter()
                .map(|p| format!("({:.0}, {:.0})", p[0], p[1]))
                .collect::<Vec<_>>()
                .join(" "),
            self.smallest_patch_px,
            self.checker_de2000[0],
            self.checker_de2000[1],
        );
        if let Some(fdm) = &self.profile.fdm {
            for f in &fdm.filaments {
                s += &format!("filament {:?}: {}\n", f.name, f.srgb);
            }
        }
        if self.clipped > 0 {
            s += &format!("{} clipped patches left out\n", self.clipped);
        }
        if let Some([m, p]) = self.fit_de2000 {
            s += &format!(
                "response fitted on {} patches: ΔE2000 mean {m:.2}, p95 {p:.2}\n",
                self.fitted
            );
        }
        if let Some([m, p]) = self.held_out_de2000 {
            s += &format!(
                "held out {} patches: ΔE2000 mean {m:.2}, p95 {p:.2}\n",
                self.held_out
            );
        }
        s
    }

    /// Writes the profile (TOML), atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        cac_core::io::write_atomic(path, self.profile.to_toml()?.as_bytes())
    }
}

/// Reads the chart, the photo and the lens's calibration named in `opts`, and calibrates.
pub fn calibrate_files(chart: &Path, photo: &Path, opts: &CalibrateOptions) -> Result<Calibration> {
    let c = Chart::load(chart)?;
    let img = cac_core::io::load_rgb(photo)?;
    let lens = match &opts.intrinsics {
        Some(p) => Some(CameraModel::load(p)?),
        None => None,
    };
    let name = photo
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    calibrate(&c, &img, opts, lens.as_ref(), &name)
        .with_context(|| format!("photo {}", photo.display()))
}

/// Calibrates the printer of `chart` from `photo` (`photo_name` names it in the profile).
pub fn calibrate(
    chart: &Chart,
    photo: &RgbImage,
    opts: &CalibrateOptions,
    lens: Option<&CameraModel>,
    photo_name: &str,
) -> Result<Calibration> {
    let kind = chart.printer;
    check_options(kind, opts)?;
    let lens = lens_for_photo(photo, lens)?;
    let seen = read_chart(photo, chart, lens.as_ref())?;
    let clipped = clipped_patches(chart, &seen.readings)?;
    let timer = Stopwatch::start();
    let (camera, checker_de2000) = correct_camera(chart, &seen.readings)?;
    let name = opts
        .name
        .clone()
        .unwrap_or_else(|| format!("{kind} printer calibrated from {photo_name}"));
    let mut out = Calibration {
        profile: Profile {
            name,
            fdm: None,
            full_colour: None,
            paper: None,
        },
        markers_px: seen.markers_px,
        smallest_patch_px: seen.smallest,
        checker_de2000,
        fitted: 0,
        held_out: 0,
        clipped: clipped.len(),
        fit_de2000: None,
        held_out_de2000: None,
        fit_ms: 0.0,
    };
    if kind == PrinterKind::Fdm {
        out.profile.fdm = Some(measure_filaments(
            chart,
            &seen.readings,
            &camera,
            opts,
            photo_name,
        ));
    } else {
        fit_printed(chart, &seen.readings, &camera, &clipped, opts, &mut out)?;
    }
    out.fit_ms = timer.ms();
    out.profile
        .printer()
        .context("the calibrated profile does not check")?;
    Ok(out)
}

/// Refuses options that do not fit the chart's printer kind: another `--printer`, a held-out
/// share out of range, a missing media width (paper) or object size (FDM).
fn check_options(kind: PrinterKind, opts: &CalibrateOptions) -> Result<()> {
    if let Some(k) = opts.printer {
        if k != kind {
            bail!(
                "this is a photo of a {kind} chart, not of a {k} one: print `cac print chart --printer {k}` and photograph it, or calibrate with --printer {kind}"
            );
        }
    }
    if !(0.0..=0.5).contains(&opts.held_out) {
        bail!("--held-out {}: a share from 0 to 0.5", opts.held_out);
    }
    match kind {
        PrinterKind::Paper => match opts.media_width_mm {
            Some(w) if w > 0.0 && w.is_finite() => {}
            _ => bail!("a paper profile needs --media-width-mm (the printable width of the roll or sheet, mm)"),
        },
        PrinterKind::Fdm => match opts.object_size_mm {
            Some(s) if s > 0.0 && s.is_finite() => {}
            _ => bail!("an fdm profile needs --object-size-mm (the object's longest side as it will be printed, mm)"),
        },
        PrinterKind::FullColour => {}
    }
    Ok(())
}

/// Refuses a photo too small to read, and scales the lens's calibration to the photo's size
/// (refusing one made for another aspect ratio: another camera or a cropped photo).
fn lens_for_photo(photo: &RgbImage, lens: Option<&CameraModel>) -> Result<Option<CameraModel>> {
    let (w, h) = photo.dimensions();
    if w.min(h) < MIN_SIDE_PX {
        bail!(
            "the photo is too small: {w}×{h} pixels, at least {MIN_SIDE_PX} on its short side are needed (and each patch {MIN_PATCH_PX} pixels across)"
        );
    }
    Ok(match lens {
        None => None,
        Some(l) => {
            let (a, b) = (w as f64 / h as f64, l.width as f64 / l.height as f64);
            if (a / b - 1.0).abs() > 0.01 {
                bail!(
                    "the photo is {w}×{h} but the camera calibration is for {}×{}: another camera or a cropped photo",
                    l.width,
                    l.height
                );
            }
            Some(l.scaled(w as usize, h as usize))
        }
    })
}

/// The chart as read from the photo.
struct ChartReading {
    /// The markers in the photo (pixels), as in [`Calibration::markers_px`].
    markers_px: [[f64; 2]; 4],
    /// Every patch of the chart, in the chart's order.
    readings: Vec<PatchReading>,
    /// The smallest patch's side, pixels.
    smallest: f64,
}

/// Locates the chart by its markers and reads every patch; refuses patches too small to read.
fn read_chart(photo: &RgbImage, chart: &Chart, lens: Option<&CameraModel>) -> Result<ChartReading> {
    let markers = detect::find_markers(photo);
    let loc = detect::locate(photo, chart, &markers, lens)?;
    let readings: Vec<PatchReading> = chart
        .patches
        .iter()
        .map(|p| detect::read_patch(photo, &loc, p, 7))
        .collect();
    let smallest = readings
        .iter()
        .map(|r| r.size_px)
        .fold(f64::INFINITY, f64::min);
    if smallest < MIN_PATCH_PX {
        bail!(
            "the photo is too small: the chart's patches are only {smallest:.1} pixels across in it (at least {MIN_PATCH_PX}); photograph the chart closer or at a higher resolution"
        );
    }
    Ok(ChartReading {
        markers_px: loc.markers_px,
        readings,
        smallest,
    })
}

/// The clipped patches (indices); refuses an overexposed photo (any ColorChecker square
/// clipped, or more than one patch in 20).
fn clipped_patches(chart: &Chart, readings: &[PatchReading]) -> Result<Vec<usize>> {
    let clipped: Vec<usize> = (0..readings.len())
        .filter(|&i| readings[i].clipped >= CLIPPED_SHARE)
        .collect();
    let checker_clipped = clipped
        .iter()
        .filter(|&&i| chart.patches[i].role == Role::Checker)
        .count();
    let n = chart.patches.len();
    if checker_clipped > 0 || clipped.len() * 20 > n {
        let i = clipped[0];
        bail!(
            "the photo is overexposed: {} of {n} patches are clipped (a channel at 255 in a quarter or more of their samples; {} of them the ColorChecker's), e.g. patch {i} ({}); lower the exposure until the white paper reads below 255",
            clipped.len(),
            checker_clipped,
            chart.patches[i].srgb
        );
    }
    Ok(clipped)
}

/// Fits the camera's correction on the ColorChecker, with the checker's ΔE2000 after it
/// against its published values (mean, largest).
fn correct_camera(
    chart: &Chart,
    readings: &[PatchReading],
) -> Result<(CameraCorrection, [f32; 2])> {
    let checker: Vec<usize> = chart.of(Role::Checker).map(|(i, _)| i).collect();
    let seen: [[f32; 3]; 24] = std::array::from_fn(|k| readings[checker[k]].linear);
    let camera = CameraCorrection::fit(&seen)?;
    let checker_de: Vec<f32> = checker
        .iter()
        .map(|&i| {
            let got = camera.apply(readings[i].linear).map(colour::encode);
            colour::delta_e2000_srgb(chart.srgb(i), got)
        })
        .collect();
    let checker_de2000 = [
        fit::mean_p95(&checker_de)[0],
        checker_de.iter().fold(0.0f32, |a, &b| a.max(b)),
    ];
    Ok((camera, checker_de2000))
}

/// FDM: the filaments' colours as measured through the camera's correction.
fn measure_filaments(
    chart: &Chart,
    readings: &[PatchReading],
    camera: &CameraCorrection,
    opts: &CalibrateOptions,
    photo_name: &str,
) -> Fdm {
    let filaments = chart
        .of(Role::Filament)
        .map(|(i, p)| Filament {
            name: p.name.clone(),
            srgb: colour::to_hex(camera.apply(readings[i].linear).map(colour::encode)),
            source: format!("measured by cac print calibrate from {photo_name}"),
        })
        .collect();
    Fdm {
        filaments,
        nozzle_mm: opts.nozzle_mm,
        layer_mm: opts.layer_mm,
        object_size_mm: opts.object_size_mm.unwrap_or_default(),
    }
}

/// Paper and full colour: draws the held-out patches, fits the response on the rest, judges it
/// on both and puts it in `out`'s profile.
fn fit_printed(
    chart: &Chart,
    readings: &[PatchReading],
    camera: &CameraCorrection,
    clipped: &[usize],
    opts: &CalibrateOptions,
    out: &mut Calibration,
) -> Result<()> {
    let mut usable: Vec<usize> = chart
        .of(Role::Printed)
        .map(|(i, _)| i)
        .filter(|i| !clipped.contains(i))
        .collect();
    usable.shuffle(&mut ChaCha8Rng::seed_from_u64(opts.seed));
    let hold = if opts.held_out > 0.0 {
        ((opts.held_out * usable.len() as f32).round() as usize).max(1)
    } else {
        0
    };
    let (held, fitted) = usable.split_at(hold);
    if fitted.len() < 12 {
        bail!(
            "only {} patches are left to fit the response (at least 12): lower --held-out or print more patches",
            fitted.len()
        );
    }
    let measured = |i: usize| camera.apply(readings[i].linear);
    let req: Vec<[f32; 3]> = fitted.iter().map(|&i| chart.srgb(i)).collect();
    let got: Vec<[f32; 3]> = fitted.iter().map(|&i| measured(i)).collect();
    let Some(mut response) = fit::fit_response(&req, &got) else {
        bail!("the printed patches do not determine a response (too few distinct colours)");
    };
    let de = |set: &[usize]| -> Vec<f32> {
        set.iter()
            .map(|&i| {
                let want = measured(i).map(colour::encode);
                colour::delta_e2000_srgb(response.apply(chart.srgb(i)), want)
            })
            .collect()
    };
    out.fit_de2000 = Some(fit::mean_p95(&de(fitted)));
    if !held.is_empty() {
        out.held_out_de2000 = Some(fit::mean_p95(&de(held)));
    }
    response.held_out_de2000 = out.held_out_de2000;
    out.fitted = fitted.len();
    out.held_out = held.len();
    if chart.printer == PrinterKind::Paper {
        out.profile.paper = Some(Paper {
            response,
            media_width_mm: opts.media_width_mm.unwrap_or_default(),
        });
    } else {
        out.profile.full_colour = Some(FullColour { response });
    }
    Ok(())
}
