//! The physical test rig, host side: the turntable driver speaking `firmware-protocol` over any
//! [`Transport`] — a real serial port ([`SerialTransport`]), the simulator's pseudo-terminal, or its
//! in-memory link (`crate::sim`) — camera frame sources (a V4L2 webcam checked with [`camera_check`]), the calibrated lens, the rig file, the
//! one camera model of the rig ([`rig_camera`]), the digital twin, ground-truth boxes, capture sessions with their manifest, and
//! the whole capture run on a real rig ([`capture`]; on the simulated rig: `crate::sim::rig`), and
//! printer calibration from a photographed chart ([`print_calib`]).
//!
//! Crate `cac-physical`: this module (`cac::physical`), with [`sim`] (the simulated firmware and
//! the simulated rig around it) beside it.

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
