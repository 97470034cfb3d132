//! Simulated turntable firmware for tests and dry runs: the device state machine
//! ([`SimDevice`]), the link and clock around it ([`SimWorld`]) with seeded fault injection
//! ([`FaultConfig`]), and two ways to reach it — an in-memory transport on virtual time
//! ([`MemoryTransport`]) and a pseudo-terminal pair on real time ([`PtySim`], Unix only); and
//! the whole rig simulated for `physical`'s real driver and capture session ([`rig`], Unix only).

pub mod device;
pub mod faults;
pub mod memory;
pub mod motion;
#[cfg(unix)]
pub mod pty;
#[cfg(unix)]
pub mod rig;
pub mod world;

pub use device::{DeviceConfig, DeviceCounters, MotionKind, MotionRecord, SimDevice};
pub use faults::{FaultConfig, FaultCounts, FaultInjector};
pub use memory::MemoryTransport;
#[cfg(unix)]
pub use pty::PtySim;
pub use world::{LinkConfig, SimHandle, SimWorld};
