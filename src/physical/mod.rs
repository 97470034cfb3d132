//! The physical test rig, host side: the turntable driver speaking `firmware-protocol` over any
//! [`Transport`] — a real serial port ([`SerialTransport`]), the simulator's pseudo-terminal, or its
//! in-memory link (`crate::sim`).

pub mod camera;
pub mod serial;
pub mod transport;
pub mod turntable;

pub use camera::{CameraError, FolderSource, Frame, FrameSource};
pub use firmware_protocol::{Axis, FaultCode, StatusInfo};
pub use serial::SerialTransport;
pub use transport::Transport;
pub use turntable::{
    DeviceInfo, DriverStats, MoveReport, Turntable, TurntableConfig, TurntableError,
};
