//! The benchmarks (crate `cac-bench`: `cac::bench`, run by `cac bench ...`): each stage's speed,
//! and its error against run time where a knob trades one for the other, measured beside the
//! peer that does the same job where one exists. They live here, after every stage, so that no
//! library starts a peer (Python, Embree, Cycles) for a measurement. Each returns a
//! `report::Table` (or rows of one) that the command prints and writes as CSV; none asserts.
//!
//! - [`render`]: BVH build and primary-ray throughput beside Embree; [`anti_aliasing`]: samples
//!   per pixel against error and time (`cac bench render`).
//! - [`detect`]: detectors' forward and backward times beside their references (TFJS, PyTorch,
//!   onnxruntime) and the activation kernels' (`cac bench detect`, `frcnn`, `kernels`).
//! - [`eval`]: images scored per second (`cac bench eval`); [`ibl`]: image-based lighting's
//!   knobs against Cycles (`cac bench ibl`).
//! - [`attack`]: the attack's iteration time split and white-box error against training time
//!   (`cac bench attack`).
//! - [`video`]: decoding and scoring throughput per codec (`cac bench video`).
//! - [`export`]: the bake's and the solidifier's error against run time (`cac bench export`).
//! - [`calibration`]: the print chart's patch count against the calibration's error and time
//!   (`cac bench calibration`).

pub mod anti_aliasing;
pub mod attack;
pub mod calibration;
pub mod detect;
pub mod eval;
pub mod export;
pub mod ibl;
pub mod render;
pub mod video;
