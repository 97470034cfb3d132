//! The benchmarks' one timer lives in the library ([`cac::report::timer`]), where the measuring
//! code of the benchmarks is; re-exported for the benchmarks still measured here.

pub use cac::report::timer::*;
