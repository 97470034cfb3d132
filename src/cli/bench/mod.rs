//! `cac bench …`: the benchmarks (the subcommands are listed in [`super::BenchCmd`]). Each prints
//! a table and writes CSV through [`cac::report::Table`], timed with the one [`timer`]; timings
//! are measured here, never in tests. A benchmark asserts nothing. (`cac bench attack` lives in
//! `cli/bench_attack.rs`, `cac bench export` in `cli/export.rs`.)

pub mod detect;
pub mod eval;
pub mod frcnn;
pub mod methods;
pub mod realism;
pub mod render;
pub mod timer;
pub mod video;
