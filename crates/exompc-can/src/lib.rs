//! CAN for exompc: classic CAN frames ([`CanFrame`]), the transport trait every bus implements
//! ([`CanBus`]: send and receive with timeouts, error counters, the controller's error state),
//! and on top of it the drives and sensor nodes that `exompc run --config` talks to.
//!
//! The numerical core of `exompc` knows nothing of CAN; this crate meets it at the runtime's
//! robot boundary ([`exompc::runtime::RobotInterface`]).

pub mod ak;
mod bus;
pub mod canopen;
pub mod cia402;
pub mod config;
pub mod emulator;
pub mod force_node;
mod frame;
pub mod robot;
#[cfg(unix)]
pub mod serial;
pub mod slcan;
pub mod slcan_adapter;
#[cfg(all(target_os = "linux", feature = "socketcan"))]
pub mod socketcan_bus;
pub mod timing;
pub mod virtual_bus;

pub use bus::{BusCounters, BusError, BusState, CanBus};
pub use frame::{CanFrame, CanId, FrameError, MAX_EXTENDED_ID, MAX_STANDARD_ID};
#[cfg(unix)]
pub use serial::{FdPort, Pty};
pub use slcan::{Port, SlcanBus};
pub use slcan_adapter::{AdapterCounters, SlcanAdapter};
pub use timing::{frame_bits, frame_time, Stuffing};
pub use virtual_bus::{
    BusLoad, NodeTx, TimeBase, VirtualBus, VirtualBusSettings, VirtualClock, VirtualEndpoint,
    VirtualNode,
};
