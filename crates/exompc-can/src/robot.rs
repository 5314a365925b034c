//! The CAN robot: AK motors and strap-force nodes on one bus behind
//! [`exompc::runtime::RobotInterface`], with the runtime's lifecycle and a protective stop on
//! any bus or device fault.
//!
//! ```text
//!  unconfigured --configure--> inactive --activate: enter motor mode; every motor answers and
//!                                 ^            every strap force arrives (ready timeout)--> active
//!                                 |                                                          |
//!                        configure (restart,                      a motor's reply or a force frame
//!                        on command only)                         older than the reply timeout, a
//!                                 |                               drive error code, error-passive,
//!                                 |                               bus-off, a failed send
//!                                 |                                                          v
//!                                 '---------- error (protective stop: the torque ramped to zero
//!                                             at the rate limit, then exit motor mode) <------'
//! ```
//!
//! No torque is sent before every device reported ready. Each period, [`CanRobot::read`]
//! polls every motor with the torque it applies (an AK motor answers a command, never by
//! itself), waits for the answers and takes the newest strap forces; [`CanRobot::write`] sends
//! the new torques. Sample timestamps are the robot's own grid (`t_0 + k·dt`): the robot is the
//! time master, as a drive without a clock of its own requires.

use crate::ak::{AkDrive, JointReading};
use crate::bus::{BusState, CanBus};
use crate::config::{RawForceSensor, Strap};
use crate::frame::{CanFrame, CanId};
use exompc::control::TorqueLimits;
use exompc::runtime::frame::{command_flags, robot_flags};
use exompc::runtime::{Clock, Lifecycle, LinkStats, RobotCommand, RobotInterface, RobotSample};
use nalgebra::SVector;
use serde::Serialize;
use std::time::Duration;

/// Timing and safety of a [`CanRobot`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CanRobotSettings {
    /// Control period.
    pub dt: Duration,
    /// Longest time every device has to report ready in [`RobotInterface::activate`].
    pub ready_timeout: Duration,
    /// Longest age of a motor's reply or a strap force while active.
    pub reply_timeout: Duration,
    /// Longest duration of the protective stop's ramp (the torque-rate limit may make it
    /// shorter).
    pub stop_ramp: Duration,
    /// Torque limits the robot applies to what it sends (and its ramp).
    pub limits: TorqueLimits,
    /// Phase of the first poll after activation within the period (fraction of `dt`, from
    /// bus time 0): with the in-process virtual leg, whose plant steps at multiples of `dt`,
    /// 0.5 puts the polls mid-period. Ignored (`None`) for real hardware.
    pub phase: Option<f64>,
}

/// Why a [`CanRobot`] made a protective stop.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CanStopCause {
    /// A motor's reply or a strap force did not arrive in time (the device named).
    DeviceTimeout(String),
    /// A motor reported an error code (joint, code).
    DriveFault(String, u8),
    /// The bus controller went error-passive.
    ErrorPassive,
    /// The bus controller went bus-off.
    BusOff,
    /// A frame could not be sent.
    SendFailed(String),
}

/// A protective stop of a CAN robot (robot clock, s): the AK robot's cause is a
/// [`CanStopCause`], the CiA 402 robot's a text naming the device and its fault.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CanStopEvent<C = CanStopCause> {
    /// Why.
    pub cause: C,
    /// When it began.
    pub at: f64,
    /// When the last ramp frame was sent (`None`: the ramp could not be sent).
    pub zero_at: Option<f64>,
    /// Ramp periods whose frames could not all be sent (the bus no longer listening).
    pub ramp_send_failures: u64,
}

/// Counters of a [`CanRobot`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct CanRobotStats {
    /// Samples delivered.
    pub samples: u64,
    /// Periods whose read ended without every motor's answer.
    pub missing_samples: u64,
    /// Motor replies decoded.
    pub replies: u64,
    /// Strap-force frames decoded.
    pub force_frames: u64,
    /// Frames received that belong to no configured device.
    pub foreign_frames: u64,
    /// Protective stops made.
    pub protective_stops: u64,
    /// Activations (sessions).
    pub sessions: u64,
}

/// A robot of `N` AK motors (hip, knee or knee) and raw-frame force nodes on bus `B`, timed by
/// clock `K`.
pub struct CanRobot<const N: usize, B: CanBus, K: Clock> {
    bus: B,
    clock: K,
    drives: [AkDrive; N],
    names: [&'static str; N],
    sensors: Vec<RawForceSensor>,
    s: CanRobotSettings,
    state: Lifecycle,
    activating_since: Option<Duration>,
    t0: Option<Duration>,
    k: u64,
    readings: [Option<JointReading>; N],
    fresh: [bool; N],
    last_reply: [Duration; N],
    force: SVector<f64, N>,
    last_force: [Option<Duration>; N],
    applied: SVector<f64, N>,
    stats: CanRobotStats,
    link: LinkStats,
    stops: Vec<CanStopEvent>,
}

impl<const N: usize, B: CanBus, K: Clock> CanRobot<N, B, K> {
    /// A robot on `bus` with the drives `drives` (named `names` in messages) and the force
    /// nodes `sensors` (thigh → joint 0, shank → joint `N−1`; a thigh channel is ignored with
    /// `N = 1`).
    pub fn new(
        bus: B,
        clock: K,
        drives: [AkDrive; N],
        names: [&'static str; N],
        sensors: Vec<RawForceSensor>,
        settings: CanRobotSettings,
    ) -> Self {
        CanRobot {
            bus,
            clock,
            drives,
            names,
            sensors,
            s: settings,
            state: Lifecycle::Unconfigured,
            activating_since: None,
            t0: None,
            k: 0,
            readings: [None; N],
            fresh: [false; N],
            last_reply: [Duration::ZERO; N],
            force: SVector::zeros(),
            last_force: [None; N],
            applied: SVector::zeros(),
            stats: CanRobotStats::default(),
            link: LinkStats::default(),
            stops: Vec::with_capacity(16),
        }
    }

    /// Counters.
    pub fn stats(&self) -> &CanRobotStats {
        &self.stats
    }

    /// Protective stops made.
    pub fn stop_events(&self) -> &[CanStopEvent] {
        &self.stops
    }

    /// The bus.
    pub fn bus(&self) -> &B {
        &self.bus
    }

    /// The torques sent last (joint side, N·m).
    pub fn applied(&self) -> SVector<f64, N> {
        self.applied
    }

    fn strap_index(&self, strap: Strap) -> Option<usize> {
        match strap {
            Strap::Thigh if N >= 2 => Some(0),
            Strap::Thigh => None,
            Strap::Shank => Some(N - 1),
        }
    }

    fn handle(&mut self, f: &CanFrame, now: Duration) {
        self.link.received += 1;
        for i in 0..N {
            if let Some(r) = self.drives[i].decode(f) {
                self.readings[i] = Some(r);
                self.fresh[i] = true;
                self.last_reply[i] = now;
                self.stats.replies += 1;
                return;
            }
        }
        let mut matched = false;
        for si in 0..self.sensors.len() {
            let sensor = &self.sensors[si];
            let id = if sensor.extended {
                CanId::Extended(sensor.can_id)
            } else {
                CanId::Standard(sensor.can_id as u16)
            };
            if f.id() != id || f.is_remote() {
                continue;
            }
            matched = true;
            for ci in 0..self.sensors[si].channels.len() {
                let c = &self.sensors[si].channels[ci];
                if let (Some(j), Some(v)) = (self.strap_index(c.strap), c.decode(f.data())) {
                    self.force[j] = v;
                    self.last_force[j] = Some(now);
                }
            }
        }
        if matched {
            self.stats.force_frames += 1;
        } else {
            self.stats.foreign_frames += 1;
        }
    }

    fn drain(&mut self) {
        while let Ok(Some(f)) = self.bus.recv(Duration::ZERO) {
            let now = self.clock.now();
            self.handle(&f, now);
        }
    }

    /// Receive until `until` (clock time), handling what arrives; stops early once `done`.
    fn receive_until(&mut self, until: Duration, done: impl Fn(&Self) -> bool) {
        loop {
            if done(self) {
                return;
            }
            let now = self.clock.now();
            if now >= until {
                return;
            }
            match self.bus.recv(until - now) {
                Ok(Some(f)) => {
                    let now = self.clock.now();
                    self.handle(&f, now);
                }
                Ok(None) => {}
                Err(_) => return,
            }
        }
    }

    fn send(&mut self, f: &CanFrame) -> bool {
        match self.bus.send(f) {
            Ok(()) => {
                self.link.sent += 1;
                true
            }
            Err(_) => {
                self.link.send_errors += 1;
                false
            }
        }
    }

    /// The bus's error state as a stop cause.
    fn bus_fault(&self) -> Option<CanStopCause> {
        match self.bus.state() {
            BusState::ErrorActive => None,
            BusState::ErrorPassive => Some(CanStopCause::ErrorPassive),
            BusState::BusOff => Some(CanStopCause::BusOff),
        }
    }

    /// A device fault while active: a drive error code, or a reply/force older than the
    /// timeout.
    fn device_fault(&self, now: Duration) -> Option<CanStopCause> {
        for i in 0..N {
            if let Some(code) = self.readings[i].and_then(|r| r.error).filter(|&c| c != 0) {
                return Some(CanStopCause::DriveFault(self.names[i].into(), code));
            }
            if now.saturating_sub(self.last_reply[i]) > self.s.reply_timeout {
                return Some(CanStopCause::DeviceTimeout(format!(
                    "{} motor (CAN ID {})",
                    self.names[i],
                    self.drives[i].can_id()
                )));
            }
        }
        for j in 0..N {
            if N == 1 || j < 2 {
                let stale =
                    self.last_force[j].is_none_or(|t| now.saturating_sub(t) > self.s.reply_timeout);
                if stale {
                    let strap = if j == N - 1 { "shank" } else { "thigh" };
                    return Some(CanStopCause::DeviceTimeout(format!(
                        "{strap} strap-force node"
                    )));
                }
            }
        }
        None
    }

    /// Protective stop: ramp the torque to zero (at the rate limit, within the stop ramp),
    /// one frame per motor per period, then exit motor mode. Counted and logged.
    pub fn protective_stop(&mut self, cause: CanStopCause) {
        if self.state == Lifecycle::Error {
            return;
        }
        self.state = Lifecycle::Error;
        self.stats.protective_stops += 1;
        let at = self.clock.now();
        let steps = stop_ramp_steps(&self.applied, &self.s.limits, self.s.stop_ramp, self.s.dt);
        let (failures, zero_at) = ramp_to_zero(self, steps);
        for i in 0..N {
            let f = self.drives[i].exit();
            self.send(&f);
        }
        // Let the exits reach the motors that still listen.
        let until = self.clock.now() + self.s.reply_timeout.min(self.s.dt);
        self.receive_until(until, |_| false);
        self.applied = SVector::zeros();
        if self.stops.len() < self.stops.capacity() {
            self.stops.push(CanStopEvent {
                cause,
                at: at.as_secs_f64(),
                zero_at,
                ramp_send_failures: failures,
            });
        }
    }

    fn sample(&self, flags: u32) -> RobotSample<N> {
        let mut q = SVector::zeros();
        let mut qd = SVector::zeros();
        for i in 0..N {
            let r = self.readings[i].unwrap_or_default();
            q[i] = r.q;
            qd[i] = r.qd;
        }
        let t0 = self.t0.unwrap_or_default();
        let stamp = t0 + self.s.dt * (self.k as u32);
        RobotSample {
            seq: (self.k as u32).wrapping_add(1),
            stamp_ns: stamp.as_nanos() as u64,
            flags,
            q,
            qd,
            force: self.force,
            // What the robot commanded (before the MIT quantisation): the controller's own
            // torque when nothing intervened, so the loop resynchronises only after a stop.
            effort: self.applied,
        }
    }

    /// Time from a sample's stamp to its poll.
    fn poll_offset(&self) -> Duration {
        self.s
            .phase
            .map_or(Duration::ZERO, |p| self.s.dt.mul_f64(p.clamp(0.0, 0.99)))
    }

    fn all_ready(&self, since: Duration) -> bool {
        self.fresh.iter().all(|&f| f)
            && (0..N)
                .filter(|&j| N == 1 || j < 2)
                .all(|j| self.last_force[j].is_some_and(|t| t >= since))
    }
}

/// Periods of a protective stop's ramp from `applied` to zero (at least one): the periods of
/// the `stop_ramp` time, or more where the torque-rate limit needs them, so no step of the ramp
/// changes a joint's torque by more than `limits.rate` (paper eq. 9, a hard guarantee on every
/// output; `stop_ramp` can only make the ramp gentler).
pub fn stop_ramp_steps<const N: usize>(
    applied: &SVector<f64, N>,
    limits: &TorqueLimits,
    stop_ramp: Duration,
    dt: Duration,
) -> u32 {
    let dt = dt.as_secs_f64().max(1e-6);
    let biggest = applied.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    // A non-finite torque is refused before it is applied; should one get here, ramp from the
    // torque limit instead of scheduling an endless ramp.
    let biggest = if biggest.is_finite() {
        biggest
    } else {
        limits.max
    };
    let by_rate = (biggest / limits.rate.max(1e-9)).ceil();
    let by_time = (stop_ramp.as_secs_f64() / dt).ceil();
    by_rate.max(by_time).clamp(1.0, f64::from(u32::MAX)) as u32
}

/// What a protective stop's ramp needs of a CAN robot (AK or CiA 402).
pub(crate) trait RampPeriods<const N: usize> {
    /// The torques applied now (the ramp's start).
    fn applied_torque(&self) -> SVector<f64, N>;
    /// Send one period's torques (every joint, and the SYNC where the protocol has one) and
    /// take them as applied; false when a send failed.
    fn send_torques(&mut self, torque: &SVector<f64, N>) -> bool;
    /// Handle what arrives for one period.
    fn wait_period(&mut self);
    /// Bus time now.
    fn bus_now(&self) -> Duration;
}

/// The ramp of a protective stop: from the applied torques to zero in `steps` periods (see
/// [`stop_ramp_steps`]), one [`RampPeriods::send_torques`] per period. Returns the periods whose
/// sends failed and the bus time (s) zero was sent, `None` when any send failed.
pub(crate) fn ramp_to_zero<const N: usize, R: RampPeriods<N>>(
    r: &mut R,
    steps: u32,
) -> (u64, Option<f64>) {
    let start = r.applied_torque();
    let mut failures = 0u64;
    for n in 1..=steps {
        let torque = start * (1.0 - f64::from(n) / f64::from(steps));
        if !r.send_torques(&torque) {
            failures += 1;
        }
        if n == steps {
            break;
        }
        r.wait_period();
    }
    (failures, (failures == 0).then(|| r.bus_now().as_secs_f64()))
}

impl<const N: usize, B: CanBus, K: Clock> RampPeriods<N> for CanRobot<N, B, K> {
    fn applied_torque(&self) -> SVector<f64, N> {
        self.applied
    }

    fn send_torques(&mut self, torque: &SVector<f64, N>) -> bool {
        let mut ok = true;
        for i in 0..N {
            let f = self.drives[i].torque_frame(torque[i]);
            ok &= self.send(&f);
        }
        self.applied = *torque;
        ok
    }

    fn wait_period(&mut self) {
        let next = self.clock.now() + self.s.dt;
        self.receive_until(next, |_| false);
    }

    fn bus_now(&self) -> Duration {
        self.clock.now()
    }
}

/// An I/O error with a message, for the robot interface's `Result`s.
pub(crate) fn io_err(msg: String) -> std::io::Error {
    std::io::Error::other(msg)
}

impl<const N: usize, B: CanBus, K: Clock> RobotInterface<N> for CanRobot<N, B, K> {
    fn state(&self) -> Lifecycle {
        self.state
    }

    /// Unconfigured or error → inactive (after a protective stop: the restart, which only a
    /// deliberate new run makes).
    fn configure(&mut self) -> std::io::Result<()> {
        self.state = Lifecycle::Inactive;
        self.activating_since = None;
        self.readings = [None; N];
        self.fresh = [false; N];
        self.last_force = [None; N];
        self.applied = SVector::zeros();
        Ok(())
    }

    fn activate(&mut self, timeout: Duration) -> std::io::Result<bool> {
        match self.state {
            Lifecycle::Active => return Ok(true),
            Lifecycle::Inactive => {}
            s => return Err(io_err(format!("cannot activate the CAN robot from {s:?}"))),
        }
        if let Some(c) = self.bus_fault() {
            return Err(io_err(format!("the CAN bus is not usable: {c:?}")));
        }
        let now = self.clock.now();
        let since = match self.activating_since {
            Some(t) => t,
            None => {
                self.drain();
                self.fresh = [false; N];
                for i in 0..N {
                    let f = self.drives[i].enter();
                    if !self.send(&f) {
                        return Err(io_err(format!(
                            "cannot send enter-motor-mode to the {} motor",
                            self.names[i]
                        )));
                    }
                }
                self.activating_since = Some(now);
                now
            }
        };
        let until = (now + timeout).min(since + self.s.ready_timeout);
        self.receive_until(until, |r| r.all_ready(since));
        if !self.all_ready(since) {
            if self.clock.now() >= since + self.s.ready_timeout {
                let mut missing = Vec::new();
                for i in 0..N {
                    if !self.fresh[i] {
                        missing.push(format!(
                            "{} motor (CAN ID {})",
                            self.names[i],
                            self.drives[i].can_id()
                        ));
                    }
                }
                if missing.is_empty() {
                    missing.push("the strap-force node(s)".into());
                }
                self.activating_since = None;
                return Err(io_err(format!(
                    "not ready within {:.0} ms: no answer from {}",
                    self.s.ready_timeout.as_secs_f64() * 1e3,
                    missing.join(", ")
                )));
            }
            return Ok(false);
        }
        if let Some(code) =
            (0..N).find_map(|i| self.readings[i].and_then(|r| r.error).filter(|&c| c != 0))
        {
            return Err(io_err(format!("a motor reports error code {code}")));
        }
        // Every device answered: active. Start the polls at the configured phase.
        if let Some(phase) = self.s.phase {
            let dt = self.s.dt.as_nanos().max(1);
            let now = self.clock.now().as_nanos();
            let target = (now / dt + 1) * dt + (phase.clamp(0.0, 0.99) * dt as f64) as u128;
            let target = Duration::from_nanos(target as u64);
            self.receive_until(target, |_| false);
        }
        self.state = Lifecycle::Active;
        self.activating_since = None;
        self.t0 = None;
        self.k = 0;
        let now = self.clock.now();
        self.last_reply = [now; N];
        self.stats.sessions += 1;
        Ok(true)
    }

    fn deactivate(&mut self) -> std::io::Result<()> {
        if self.state == Lifecycle::Active {
            for i in 0..N {
                let f = self.drives[i].torque_frame(0.0);
                self.send(&f);
                let f = self.drives[i].exit();
                self.send(&f);
            }
            self.applied = SVector::zeros();
            self.state = Lifecycle::Inactive;
        }
        Ok(())
    }

    fn error(&mut self) {
        self.protective_stop(CanStopCause::SendFailed(
            "the controller abandoned the session".into(),
        ));
    }

    fn read(&mut self, timeout: Duration) -> std::io::Result<Option<RobotSample<N>>> {
        if self.state == Lifecycle::Error {
            return Ok((self.k > 0).then(|| self.sample(robot_flags::PROTECTIVE_STOP)));
        }
        if self.state != Lifecycle::Active {
            return Ok(None);
        }
        if let Some(c) = self.bus_fault() {
            self.protective_stop(c);
            return Ok(Some(self.sample(robot_flags::PROTECTIVE_STOP)));
        }
        // Poll on the robot's own grid t_0 + k·dt (a drive has no clock to sample by): the
        // loop's clock sync then settles with its wake-up `lead` before the poll.
        let woke = self.clock.now();
        if let Some(t0) = self.t0 {
            let due = t0 + self.poll_offset() + self.s.dt * (self.k as u32);
            if due > woke {
                self.receive_until(due.min(woke + timeout), |_| false);
            }
        }
        let start = self.clock.now();
        let timeout = timeout.saturating_sub(start - woke);
        self.drain();
        self.fresh = [false; N];
        let mut sent = true;
        for i in 0..N {
            let f = self.drives[i].torque_frame(self.applied[i]);
            sent &= self.send(&f);
        }
        if !sent {
            let c = self
                .bus_fault()
                .unwrap_or_else(|| CanStopCause::SendFailed("poll".into()));
            self.protective_stop(c);
            return Ok(Some(self.sample(robot_flags::PROTECTIVE_STOP)));
        }
        self.receive_until(start + timeout, |r| r.fresh.iter().all(|&f| f));
        let now = self.clock.now();
        if let Some(c) = self.bus_fault().or_else(|| self.device_fault(now)) {
            self.protective_stop(c);
            return Ok(Some(self.sample(robot_flags::PROTECTIVE_STOP)));
        }
        if !self.fresh.iter().all(|&f| f) {
            self.stats.missing_samples += 1;
            return Ok(None);
        }
        if self.t0.is_none() {
            // With a phase (the in-process virtual leg), the stamps are the plant's step
            // times that the replies report: the poll's grid point minus the phase.
            self.t0 = Some(start.saturating_sub(self.poll_offset()));
        }
        let s = self.sample(0);
        self.k += 1;
        self.stats.samples += 1;
        self.link.accepted += 1;
        Ok(Some(s))
    }

    fn write(&mut self, cmd: &RobotCommand<N>) -> std::io::Result<()> {
        if self.state != Lifecycle::Active {
            return Ok(());
        }
        if cmd.flags & command_flags::STOP != 0 {
            return self.deactivate();
        }
        if cmd.flags & command_flags::HELLO != 0 {
            return Ok(());
        }
        let target = self.s.limits.admissible(&cmd.torque);
        let torque = self.s.limits.clamp(&self.applied, &target);
        let mut ok = true;
        for i in 0..N {
            let lim = self.drives[i].torque_limit();
            let t = torque[i].clamp(-lim, lim);
            let f = self.drives[i].torque_frame(t);
            ok &= self.send(&f);
            self.applied[i] = t;
        }
        if !ok {
            let c = self
                .bus_fault()
                .unwrap_or_else(|| CanStopCause::SendFailed("torque command".into()));
            self.protective_stop(c);
        }
        Ok(())
    }

    fn link_stats(&self) -> LinkStats {
        self.link
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Every step of the ramp (`applied / steps`) stays within the rate limit, and the ramp
        /// takes at least the `stop_ramp` time.
        #[test]
        fn the_stop_ramp_never_exceeds_the_rate_limit(
            a in -60.0f64..60.0,
            b in -60.0f64..60.0,
            rate in 0.01f64..20.0,
            ramp_ms in 0u64..5000,
            dt_us in 100u64..20_000,
        ) {
            let applied = SVector::<f64, 2>::new(a, b);
            let limits = TorqueLimits { max: 60.0, rate };
            let (ramp, dt) = (Duration::from_millis(ramp_ms), Duration::from_micros(dt_us));
            let steps = stop_ramp_steps(&applied, &limits, ramp, dt);
            let step = a.abs().max(b.abs()) / f64::from(steps);
            prop_assert!(step <= rate * (1.0 + 1e-12), "{step} > {rate} in {steps} steps");
            prop_assert!(f64::from(steps) * dt.as_secs_f64() >= ramp.as_secs_f64() - 1e-9);
            prop_assert!(steps >= 1);
        }
    }

    #[test]
    fn a_non_finite_torque_ramps_from_the_limit() {
        let limits = TorqueLimits {
            max: 30.0,
            rate: 10.0,
        };
        let dt = Duration::from_millis(10);
        let applied = SVector::<f64, 1>::new(f64::INFINITY);
        assert_eq!(stop_ramp_steps(&applied, &limits, Duration::ZERO, dt), 3);
        let applied = SVector::<f64, 1>::new(f64::NAN);
        assert_eq!(stop_ramp_steps(&applied, &limits, Duration::ZERO, dt), 1);
    }
}
