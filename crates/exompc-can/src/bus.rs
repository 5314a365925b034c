//! The transport trait: one classic-CAN bus, whatever carries it (SocketCAN, slcan, the
//! in-process virtual bus).

use crate::frame::CanFrame;
use std::time::Duration;
use thiserror::Error;

/// The error state of the CAN controller (ISO 11898-1 fault confinement).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BusState {
    /// Normal operation (error counters below 128).
    #[default]
    ErrorActive,
    /// An error counter reached 128: the node may still send, but something is wrong.
    ErrorPassive,
    /// The transmit error counter passed 255: the node is off the bus.
    BusOff,
}

/// Counters of one bus endpoint since it was opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusCounters {
    /// Frames sent.
    pub sent: u64,
    /// Frames received.
    pub received: u64,
    /// Sends that failed (buffer full, timeout, adapter error).
    pub send_errors: u64,
    /// Received data that could not be decoded into a frame (e.g. a malformed slcan line).
    pub receive_errors: u64,
    /// Error frames seen on the bus.
    pub error_frames: u64,
    /// Frames lost (receive overrun, or dropped by an injected fault of the virtual bus).
    pub dropped: u64,
}

/// Why a bus operation failed.
#[derive(Debug, Error)]
pub enum BusError {
    /// The operating system or the adapter reported an error.
    #[error("CAN I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// The controller is bus-off: nothing can be sent until it recovers.
    #[error("the CAN controller is bus-off")]
    BusOff,
    /// The other end of the transport is gone (closed port, dropped virtual bus).
    #[error("the CAN transport is closed")]
    Closed,
    /// A send did not complete in time.
    #[error("sending a CAN frame timed out")]
    SendTimeout,
}

/// One classic-CAN bus endpoint. Implementations never panic on what they receive: what they
/// cannot decode is counted in [`BusCounters::receive_errors`].
pub trait CanBus {
    /// Queue one frame for sending.
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError>;

    /// The next received frame, waiting at most `timeout`; `Ok(None)` when none arrived.
    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError>;

    /// The counters so far.
    fn counters(&self) -> BusCounters;

    /// The controller's error state.
    fn state(&self) -> BusState {
        BusState::ErrorActive
    }
}
