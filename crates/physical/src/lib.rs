//! The physical test rig, host side (crate `cac-physical`: `cac::physical`, with [`sim`] as
//! `cac::sim`).
//!
//! - The turntable: [`Turntable`] drives the firmware of `firmware-protocol` over any
//!   [`Transport`] — a real serial port ([`SerialTransport`], [`serial`]), the simulator's
//!   pseudo-terminal, or its in-memory link ([`sim`]); [`turntable`] holds its errors, retries
//!   and statistics.
//! - The camera: frame sources ([`camera`]: a V4L2 webcam, an image folder), checked as a session
//!   will use them ([`camera_check`]); the calibrated lens ([`calib`]), the rig file ([`rig`]),
//!   the rig's one camera model ([`rig_camera`]), the digital twin ([`twin`]) and the
//!   ground-truth boxes it projects ([`truth`]).
//! - The session: what it moves ([`stage`]: the table angle, and the distance by the rail or
//!   an operator), a capture run on a real rig ([`capture`]; on the simulated rig:
//!   [`sim::rig`]), its folder and manifest ([`session`], [`manifest`]), and its scoring with
//!   the evaluation's scoring core ([`score`]: P@0.5 ± std per distance ratio and angle).
//! - The printer: calibration from a photographed chart ([`print_calib`]: the chart, the
//!   calibration, its simulation and its benchmark).
//! - [`sim`]: the simulated firmware and the simulated rig around it.

pub mod sim;

pub mod calib;
pub mod camera;
pub mod camera_check;
pub mod capture;
pub mod manifest;
pub mod print_calib;
pub mod rig;
pub mod rig_camera;
pub mod score;
pub mod serial;
pub mod session;
pub mod stage;
pub mod transport;
pub mod truth;
pub mod turntable;
pub mod twin;

pub use camera::{CameraError, FolderSource, Frame, FrameSource};
pub use firmware_protocol::{Axis, FaultCode, StatusInfo};
pub use serial::SerialTransport;
pub use transport::Transport;
pub use turntable::{
    DeviceInfo, DriverStats, MoveReport, Turntable, TurntableConfig, TurntableError,
};
