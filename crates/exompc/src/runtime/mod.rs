//! Real-time runtime: the robot interface, the binary frame of the UDP link, the periodic
//! controller loop, a virtual robot to test against, and injectable network faults.
//!
//! * [`RobotInterface`] is the hardware boundary, shaped like ros2_control's hardware
//!   interface: [`RobotInterface::read`] a state sample, [`RobotInterface::write`] a torque
//!   command, once per period. A UDP link ([`UdpRobot`]) is the one implementation here; a CAN
//!   or EtherCAT drive, or a ROS 2 bridge, implements the same two calls.
//! * [`frame`]: the versioned little-endian frame (magic, version, sequence number, timestamp,
//!   payload, CRC-32); decoding rejects every malformed, truncated, wrong-version, duplicate,
//!   out-of-order or stale frame with a counted reason, never a panic.
//! * [`ControlLoop`]: the controller side of one period on absolute-time deadlines synchronised
//!   to the robot's sample timestamps (wake at `T_k`, read the newest sample with a timeout,
//!   filter, supervised controller step, write the torque), written against the [`Clock`] and [`RobotInterface`] traits so that it runs
//!   in tests without sockets or real time.
//! * [`VirtualRobot`]: the simulated human + exoskeleton of `exompc simulate` (the same
//!   [`Plant`](crate::sim::Plant) and [`Sensors`](crate::sim::Sensors)) behind the robot side of
//!   the protocol, with a command watchdog.
//! * [`NetFaults`]: packet loss, delay spikes, duplication, reordering and a disconnection,
//!   injected into a stream of frames.

pub mod frame;
mod loop_ctl;
mod netfault;
mod robot;
mod timing;
mod udp;

pub use frame::{
    decode, encode_command, encode_sample, Frame, FrameError, RejectCounts, RobotCommand,
    RobotSample, SeqTracker,
};
pub use loop_ctl::{ControlLoop, LoopSettings, LoopStats, PeriodRecord};
pub use netfault::{NetFaultCounts, NetFaultSettings, NetFaults};
pub use robot::{RobotStats, RobotStep, VirtualRobot, WatchdogEvent};
pub use timing::{
    Clock, MonotonicClock, Percentiles, Schedule, TestClock, TimingStats, TimingSummary,
};
pub use udp::{UdpPeer, UdpRobot};

use serde::Serialize;
use std::time::Duration;

/// Counters of one end of a link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LinkStats {
    /// Datagrams received.
    pub received: u64,
    /// Frames accepted (decoded, right direction, newer than the last one).
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

/// The robot side of the controller, once per period (the read()/write() cycle of a
/// ros2_control hardware interface). Implementations count what they reject in
/// [`LinkStats`] and never panic on bad input.
pub trait RobotInterface<const N: usize> {
    /// The newest valid state sample, waiting at most `timeout` for one; `None` when none
    /// arrived in time. Older valid samples read in the same call are counted as superseded.
    fn read(&mut self, timeout: Duration) -> std::io::Result<Option<RobotSample<N>>>;

    /// Send one torque command.
    fn write(&mut self, cmd: &RobotCommand<N>) -> std::io::Result<()>;

    /// The link's counters so far.
    fn link_stats(&self) -> LinkStats;
}
