//! `cac bench …`: the benchmarks (the subcommands are listed in [`super::BenchCmd`]). Each prints
//! a table and writes CSV through [`cac::report::Table`], timed in the library with the one
//! timer (`cac::report::timer`), never in tests. A benchmark asserts nothing. (`cac bench export` lives in
//! `cli/export.rs`.)

pub mod attack;
pub mod detect;
pub mod eval;
pub mod frcnn;
pub mod ibl;
pub mod kernels;
pub mod realism;
pub mod render;
pub mod video;
