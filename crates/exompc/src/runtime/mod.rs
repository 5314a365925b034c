//! Real-time runtime: the robot interface, the binary frame of the UDP link, the periodic
//! controller loop, and injectable network faults.
//!
//! * [`RobotInterface`] is the hardware boundary, shaped like ros2_control's hardware
//!   interface: a lifecycle ([`Lifecycle`]: configure, activate, deactivate, error), then
//!   [`RobotInterface::read`] a state sample and [`RobotInterface::write`] a torque command
//!   once per period. A UDP link ([`UdpRobot`]) is the one implementation here; a CAN or
//!   EtherCAT drive, or a ROS 2 bridge, implements the same calls.
//! * [`frame`]: the versioned little-endian frame (magic, version, sequence number, timestamp,
//!   payload, MAC); decoding rejects every malformed, truncated, wrong-version, forged,
//!   altered, duplicate, out-of-order or stale frame with a counted reason, never a panic.
//! * [`session`]: the pre-shared key, the handshake (fresh nonces of both sides) and the
//!   session key, and the protocol state of both ends ([`ControllerLink`], [`RobotLink`]).
//! * [`ControlLoop`]: the controller side of one period on absolute-time deadlines synchronised
//!   to the robot's sample timestamps (wake at `T_k`, read the newest sample with a timeout,
//!   filter, supervised controller step, write the torque), written against the [`Clock`] and [`RobotInterface`] traits so that it runs
//!   in tests without sockets or real time.
//! * The virtual robot to test against (the simulated human + exoskeleton behind the robot side
//!   of the protocol) is [`crate::scenario::VirtualRobot`], where simulator and runtime meet:
//!   the runtime does not import the simulator.
//! * [`stream`]: frames over a byte stream (a UART or serial port), delimited by their own
//!   header ([`Deframer`]).
//! * [`NetFaults`]: packet loss, delay spikes, duplication, reordering and a disconnection,
//!   injected into a stream of frames.
//!
//! Without the `std` feature only [`frame`], [`session`] (keys, handshake, both ends' protocol
//! state), [`stream`] and [`LinkStats`] build (`no_std` + `alloc`: the firmware's serial link
//! runs this same code); the rest needs `std`.

pub mod frame;
mod key;
#[cfg(feature = "std")]
mod loop_ctl;
#[cfg(feature = "std")]
mod netfault;
pub mod session;
pub mod stream;
#[cfg(feature = "std")]
mod timing;
#[cfg(feature = "std")]
mod udp;

pub use frame::{
    decode, encode_command, encode_sample, Frame, FrameError, RejectCounts, RobotCommand,
    RobotSample, SeqTracker, PLAN_LEN,
};
#[cfg(feature = "std")]
pub use loop_ctl::{ControlLoop, LoopSettings, LoopStats, PeriodRecord};
#[cfg(feature = "std")]
pub use netfault::{NetFaultCounts, NetFaultSettings, NetFaults};
pub use session::{ControllerLink, Key, KeyError, Psk, RobotLink, RobotRx};
pub use stream::Deframer;
#[cfg(feature = "std")]
pub use timing::{
    Clock, MonotonicClock, Percentiles, Schedule, TestClock, TimingStats, TimingSummary,
};
#[cfg(feature = "std")]
pub use udp::{UdpPeer, UdpRobot};

use serde::Serialize;
#[cfg(feature = "std")]
use std::time::Duration;

/// Counters of one end of a link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LinkStats {
    /// Datagrams received.
    pub received: u64,
    /// Frames accepted (authenticated, right direction, newer than the last one).
    pub accepted: u64,
    /// Accepted frames dropped unused because a newer one was read in the same call.
    pub superseded: u64,
    /// Sequence numbers skipped between accepted frames (lost or late frames).
    pub gaps: u64,
    /// Rejected frames by reason.
    pub rejected: RejectCounts,
    /// Frames sent.
    pub sent: u64,
    /// Sends that failed (e.g. no listener yet on the loopback).
    pub send_errors: u64,
}

/// The lifecycle of a robot (ros2_control's hardware lifecycle): unconfigured → inactive
/// (configured, zero torque) → active (a session applies commands); error is the protective
/// stop (torque ramped to zero and held), left only by a deliberate restart to inactive.
///
/// ```text
///  unconfigured --configure--> inactive --activate (authenticated session)--> active
///                                 ^  ^------------------deactivate--------------'  |
///                                 |                                                 | lost controller, invalid
///                              restart                                              | stream, fault, stop request
///                                 |                                                 v
///                                 '--------------------------------------------- error
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Lifecycle {
    /// Not configured: no link, no torque.
    #[default]
    Unconfigured,
    /// Configured, zero torque, ready for a session.
    Inactive,
    /// A session applies commands.
    Active,
    /// Protective stop: torque ramped to zero and held until a restart.
    Error,
}

/// The robot side of the controller, once per period (the read()/write() cycle of a
/// ros2_control hardware interface), with its lifecycle. Implementations count what they
/// reject in [`LinkStats`] and never panic on bad input. The lifecycle methods have defaults
/// for an interface that is always active (an in-process test double).
#[cfg(feature = "std")]
pub trait RobotInterface<const N: usize> {
    /// The interface's lifecycle state.
    fn state(&self) -> Lifecycle {
        Lifecycle::Active
    }

    /// Unconfigured → inactive: prepare the link (for the UDP link: a fresh handshake nonce).
    fn configure(&mut self) -> std::io::Result<()> {
        Ok(())
    }

    /// Inactive → active: open a session with the robot, waiting at most `timeout`; `true`
    /// once active (the robot's first sample is then ready for [`RobotInterface::read`]).
    /// Call again after `false` to go on waiting.
    fn activate(&mut self, _timeout: std::time::Duration) -> std::io::Result<bool> {
        Ok(true)
    }

    /// Active → inactive: the session is over (after the stop was sent).
    fn deactivate(&mut self) -> std::io::Result<()> {
        Ok(())
    }

    /// Any state → error: the session is abandoned (the robot stops itself when it hears
    /// nothing more).
    fn error(&mut self) {}

    /// The newest valid state sample, waiting at most `timeout` for one; `None` when none
    /// arrived in time. Older valid samples read in the same call are counted as superseded.
    fn read(&mut self, timeout: Duration) -> std::io::Result<Option<RobotSample<N>>>;

    /// Send one torque command.
    fn write(&mut self, cmd: &RobotCommand<N>) -> std::io::Result<()>;

    /// The link's counters so far.
    fn link_stats(&self) -> LinkStats;
}
