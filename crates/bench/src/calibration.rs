//! `cac bench calibration`: the chart's patch count against the calibration's error and time. For
//! each count and seed, the simulated printer prints a paper chart, the twin photographs it
//! ([`super::simulate`]), and [`super::calibrate`] fits it; reported are the held-out ΔE2000 it
//! writes in the profile, the truth (the fitted response against the simulated printer on 2000
//! fresh random colours), the time to find and read the chart and the fit's own time. A last
//! row repeats the largest count on a printer with strong tone curves (dot gain), which the
//! root-polynomial response cannot follow along the grey axis. Asserts nothing.

use anyhow::Result;
use cac_core::colour;
use cac_core::printer::Response;
use cac_core::report::timer::Stopwatch;
use cac_core::report::Table;
use cac_physical::print_calib::calibrate::{calibrate, CalibrateOptions};
use cac_physical::print_calib::chart::{Chart, ChartSpec, PrinterKind};
use cac_physical::print_calib::fit::mean_p95;
use cac_physical::print_calib::simulate::{photograph, Shot, SimulatedPrinter};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The benchmark's settings (`cac bench calibration`'s flags but the output).
#[derive(Clone, Debug)]
pub struct CalibrationBench {
    /// Patch counts, comma separated.
    pub patches: Vec<usize>,
    /// Charts (seeds) per count; their figures are averaged.
    pub seeds: u64,
}

impl Default for CalibrationBench {
    /// 24, 48, 96 and 192 patches, three charts (seeds) each.
    fn default() -> Self {
        CalibrationBench {
            patches: vec![24, 48, 96, 192],
            seeds: 3,
        }
    }
}

/// Mean ΔE2000 and its 95th percentile of a response against a printer on `n` random colours.
pub fn truth(response: &Response, printer: &SimulatedPrinter, n: usize, seed: u64) -> [f32; 2] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let de: Vec<f32> = (0..n)
        .map(|_| {
            let c: [f32; 3] = std::array::from_fn(|_| rng.random::<f32>());
            colour::delta_e2000_srgb(printer.print(c), response.apply(c))
        })
        .collect();
    mean_p95(&de)
}

impl CalibrationBench {
    /// Runs the benchmark: one table row per patch count (and the dot-gain row).
    pub fn run(&self) -> Result<Table> {
        let mut table = Table::new([
            "printer",
            "patches",
            "patch mm",
            "charts",
            "held-out ΔE mean",
            "held-out ΔE p95",
            "truth ΔE mean",
            "truth ΔE p95",
            "find+read ms",
            "fit ms",
        ]);
        let largest = self.patches.iter().copied().max().unwrap_or(192);
        let mut runs: Vec<(&str, SimulatedPrinter, usize)> = self
            .patches
            .iter()
            .map(|&n| ("simulated", SimulatedPrinter::default(), n))
            .collect();
        runs.push(("dot gain", SimulatedPrinter::dot_gain(), largest));
        let shot = Shot::default();
        for (name, printer, n) in runs {
            let mut sums = [0.0f64; 7];
            let seeds = self.seeds.max(1);
            let mut patch_mm = 0.0;
            for seed in 1..=seeds {
                let chart = Chart::new(&ChartSpec {
                    kind: PrinterKind::FullColour,
                    patches: n,
                    seed,
                    checker_pitch_mm: 13.0,
                    filaments: vec![],
                })?;
                patch_mm = chart.patches.last().map_or(0.0, |p| p.size_mm);
                let side = shot.atlas as u32;
                let page = printer.printed_page(&chart, side, side, seed);
                let photo = photograph(
                    &page,
                    &chart,
                    &Shot {
                        seed,
                        ..shot.clone()
                    },
                )?;
                let opts = CalibrateOptions {
                    seed,
                    ..Default::default()
                };
                let t = Stopwatch::start();
                let cal = calibrate(&chart, &photo, &opts, Some(&shot.lens), "twin")?;
                let total = t.ms();
                let resp = &cal
                    .profile
                    .full_colour
                    .as_ref()
                    .expect("full colour")
                    .response;
                let [hm, hp] = cal.held_out_de2000.unwrap_or_default();
                let [tm, tp] = truth(resp, &printer, 2000, 1000 + seed);
                for (s, v) in sums.iter_mut().zip([
                    hm as f64,
                    hp as f64,
                    tm as f64,
                    tp as f64,
                    total - cal.fit_ms,
                    cal.fit_ms,
                    1.0,
                ]) {
                    *s += v;
                }
            }
            let k = sums[6];
            let f = |i: usize, digits: usize| format!("{:.*}", digits, sums[i] / k);
            table.row([
                name.to_string(),
                n.to_string(),
                format!("{patch_mm:.1}"),
                seeds.to_string(),
                f(0, 2),
                f(1, 2),
                f(2, 2),
                f(3, 2),
                f(4, 1),
                f(5, 2),
            ]);
        }
        Ok(table)
    }
}
