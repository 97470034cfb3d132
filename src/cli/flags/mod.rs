//! The command line's flags for the libraries' plain settings: each flags struct names the
//! settings' flags, their help and defaults (taken from the settings' own `Default` where it
//! has one) and maps onto the settings with `From`. The libraries know nothing of clap.

pub mod attack;
pub mod eval;
pub mod export;
pub mod physical;

#[cfg(test)]
mod tests {
    use clap::{Args, FromArgMatches, Parser};

    /// A command line of one flags struct.
    #[derive(Parser)]
    struct Line<F: Args> {
        #[command(flatten)]
        flags: F,
    }

    /// The settings `args` give through flags `F`.
    fn parsed<F: Args + FromArgMatches, T: From<F>>(args: &[&str]) -> T {
        let line = Line::<F>::try_parse_from(std::iter::once("cac").chain(args.iter().copied()));
        T::from(line.unwrap_or_else(|e| panic!("{args:?}: {e}")).flags)
    }

    /// Flags `F` given nothing are `T::default()` (compared as printed: not every setting
    /// compares).
    fn defaults_agree<F: Args + FromArgMatches, T: From<F> + Default + std::fmt::Debug>() {
        let t: T = parsed::<F, T>(&[]);
        assert_eq!(
            format!("{t:?}"),
            format!("{:?}", T::default()),
            "{}",
            std::any::type_name::<T>()
        );
    }

    #[test]
    fn every_flags_default_is_its_settings_default() {
        use cac::{attack, eval, physical, study};
        defaults_agree::<super::attack::AttackFlags, attack::AttackConfig>();
        defaults_agree::<super::eval::BatchFlags, eval::slurm::Batch>();
        defaults_agree::<super::eval::RealismFlags, eval::realism::RealismJob>();
        defaults_agree::<super::eval::DemoFlags, study::demo::DemoJob>();
        defaults_agree::<super::eval::SourceFlags, study::Source>();
        defaults_agree::<super::eval::TopnFlags, study::topn::TopnJob>();
        defaults_agree::<super::eval::MethodsFlags, study::methods::MethodsJob>();
        defaults_agree::<
            super::physical::CalibrationBenchFlags,
            cac::bench::calibration::CalibrationBench,
        >();
        defaults_agree::<super::physical::CalibrateFlags, physical::print_calib::CalibrateOptions>(
        );
        defaults_agree::<super::export::ExportBenchFlags, cac::bench::export::ExportBench>();
        defaults_agree::<crate::cli::bench::video::BenchFlags, cac::bench::video::VideoBench>();
        defaults_agree::<crate::cli::score_video::OpenFlags, cac::video::OpenOptions>();
    }

    #[test]
    fn flags_reach_their_settings() {
        use cac::attack::{baselines::Method, loss::ProposalRule, AttackConfig, LrDecay};
        use cac::environment::ViewpointSet;
        let c: AttackConfig = parsed::<super::attack::AttackFlags, _>(&[
            "--lr",
            "0.04",
            "--front-back-share",
            "0.5",
            "--method",
            "upc",
            "--proposals",
            "topn",
            "--lr-decay",
            "cosine",
            "--models",
            "nanodet,centernet",
        ]);
        assert_eq!((c.lr, c.front_back_share), (0.04, Some(0.5)));
        assert_eq!(
            (c.method, c.proposals, c.lr_decay),
            (Method::Upc, ProposalRule::TopN, LrDecay::Cosine)
        );
        assert_eq!(c.models, ["nanodet", "centernet"]);
        // Settings without a flag keep their defaults.
        assert_eq!((c.nms_iou, c.viewpoints), (0.7, ViewpointSet::Free));
        let m: cac::study::methods::MethodsJob =
            parsed::<super::eval::MethodsFlags, _>(&["--methods", "cac,camou", "--sets", "rv"]);
        assert_eq!(m.methods, [Method::Cac, Method::Camou]);
        assert_eq!(m.sets, [ViewpointSet::Restricted]);
        // A name that is not a value is refused, listing the values.
        let e = Line::<super::attack::AttackFlags>::try_parse_from(["cac", "--method", "cacc"])
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("cac, advpat, shapeshifter, upc, camou"), "{e}");
        let b: cac::bench::video::VideoBench =
            parsed::<crate::cli::bench::video::BenchFlags, _>(&[
                "--codecs", "mjpeg", "--frames", "3",
            ]);
        assert_eq!((b.codecs, b.frames), (vec!["mjpeg".to_string()], 3));
        let o: cac::video::OpenOptions =
            parsed::<crate::cli::score_video::OpenFlags, _>(&["--rotate", "90", "--any-codec"]);
        assert_eq!((o.rotate_ccw, o.allow_any_codec), (Some(90), true));
        // An alias is accepted.
        let r: cac::eval::realism::RealismJob =
            parsed::<super::eval::RealismFlags, _>(&["--sets", "restricted"]);
        assert_eq!(r.sets, [cac::eval::realism::ViewSet::Restricted]);
    }
}
