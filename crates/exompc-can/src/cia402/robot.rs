//! The CiA 402 robot: CANopen drives and a CANopen strap-force node on one bus behind
//! [`exompc::runtime::RobotInterface`], with the runtime's lifecycle and a protective stop on
//! any bus or device fault.
//!
//! ```text
//!  unconfigured --configure--> inactive --activate: configure every node by SDO, start it,
//!                                 ^        walk each drive to operation enabled--> active
//!                                 |                                                  |
//!                      configure (restart, on command only)   a drive fault (statusword,
//!                                 |                           EMCY), a missed heartbeat, a
//!                                 |                           sample older than the timeout,
//!                                 |                           error-passive, bus-off, a failed send
//!                                 |                                                  v
//!                                 '--- error (protective stop: target torque ramped to zero
//!                                      at the rate limit, SYNC by SYNC; then quick stop) <--'
//! ```
//!
//! No torque is sent before every drive reports operation enabled and the force node runs.
//! Each period, [`Cia402Robot::read`] sends the SYNC (the drives apply the target torque
//! received since the last one and sample their actual values), waits for every drive's two
//! TPDOs and the force node's TPDO, and checks every device; [`Cia402Robot::write`] sends each
//! drive's RPDO (controlword and target torque) for the next SYNC.

use super::master::{Cia402Master, DriveSample};
use crate::bus::{BusState, CanBus};
use crate::canopen::sync::SyncProducer;
use crate::force_node::{ForceSample, ForceSensor};
use crate::robot::{io_err, ramp_to_zero, stop_ramp_steps, CanStopEvent, RampPeriods};
use crate::CanFrame;
use exompc::control::TorqueLimits;
use exompc::runtime::frame::{command_flags, robot_flags};
use exompc::runtime::{Clock, Lifecycle, LinkStats, RobotCommand, RobotInterface, RobotSample};
use nalgebra::SVector;
use serde::Serialize;
use std::time::Duration;

/// Timing and safety of a [`Cia402Robot`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cia402RobotSettings {
    /// Control period (the SYNC period).
    pub dt: Duration,
    /// Longest age of a drive's or the force node's sample while active.
    pub sample_timeout: Duration,
    /// Longest duration of the protective stop's ramp (the torque-rate limit may make it
    /// shorter).
    pub stop_ramp: Duration,
    /// Torque limits applied to what is sent (and to the ramp).
    pub limits: TorqueLimits,
    /// Phase of the SYNCs within the period (fraction of `dt`, from bus time 0) for the
    /// in-process virtual leg, whose plant steps at multiples of `dt`; `None` for hardware.
    pub phase: Option<f64>,
}

/// A protective stop: its cause names the device and its fault, or the bus state.
pub type Cia402StopEvent = CanStopEvent<String>;

/// Counters of a [`Cia402Robot`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Cia402RobotStats {
    /// Samples delivered.
    pub samples: u64,
    /// Periods whose read ended without every device's TPDOs.
    pub missing_samples: u64,
    /// SYNCs sent.
    pub syncs: u64,
    /// Protective stops made.
    pub protective_stops: u64,
    /// Activations (sessions).
    pub sessions: u64,
    /// Frames received that belong to no configured device.
    pub foreign_frames: u64,
}

/// `N` CiA 402 drives (hip, knee or knee) and one CANopen force node on bus `B`, clock `K`.
pub struct Cia402Robot<const N: usize, B: CanBus, K: Clock> {
    bus: B,
    clock: K,
    drives: Vec<Cia402Master>,
    names: [&'static str; N],
    force: ForceSensor,
    s: Cia402RobotSettings,
    sync: SyncProducer,
    state: Lifecycle,
    t0: Option<Duration>,
    k: u64,
    samples: [Option<DriveSample>; N],
    fresh: [bool; N],
    last_seen: [Duration; N],
    force_sample: Option<ForceSample>,
    force_fresh: bool,
    applied: SVector<f64, N>,
    stats: Cia402RobotStats,
    link: LinkStats,
    stops: Vec<Cia402StopEvent>,
    heartbeat_buf: Vec<CanFrame>,
}

impl<const N: usize, B: CanBus, K: Clock> Cia402Robot<N, B, K> {
    /// A robot on `bus` with the drives `drives` (joint order, named `names`) and the force
    /// node `force` (thigh → joint 0, shank → joint `N−1`).
    pub fn new(
        bus: B,
        clock: K,
        drives: [Cia402Master; N],
        names: [&'static str; N],
        force: ForceSensor,
        settings: Cia402RobotSettings,
    ) -> Self {
        Self {
            bus,
            clock,
            drives: drives.into_iter().collect(),
            names,
            force,
            sync: SyncProducer::new(settings.dt, 0),
            s: settings,
            state: Lifecycle::Unconfigured,
            t0: None,
            k: 0,
            samples: [None; N],
            fresh: [false; N],
            last_seen: [Duration::ZERO; N],
            force_sample: None,
            force_fresh: false,
            applied: SVector::zeros(),
            stats: Cia402RobotStats::default(),
            link: LinkStats::default(),
            stops: Vec::with_capacity(16),
            heartbeat_buf: Vec::with_capacity(N),
        }
    }

    /// Counters.
    pub fn stats(&self) -> &Cia402RobotStats {
        &self.stats
    }

    /// Protective stops made.
    pub fn stop_events(&self) -> &[Cia402StopEvent] {
        &self.stops
    }

    /// The bus.
    pub fn bus(&self) -> &B {
        &self.bus
    }

    /// The torques sent last (joint side, N·m, before the per-mille quantisation).
    pub fn applied(&self) -> SVector<f64, N> {
        self.applied
    }

    fn handle(&mut self, f: &CanFrame, now: Duration) {
        self.link.received += 1;
        for i in 0..N {
            if self.drives[i].on_frame(f, now) {
                if let Some(s) = self.drives[i].take_sample() {
                    self.samples[i] = Some(s);
                    self.fresh[i] = true;
                    self.last_seen[i] = now;
                }
                return;
            }
        }
        if self.force.on_frame(f, now) {
            if let Some(s) = self.force.take_sample() {
                self.force_sample = Some(s);
                self.force_fresh = true;
            }
            return;
        }
        self.stats.foreign_frames += 1;
    }

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

    fn all_fresh(&self) -> bool {
        self.fresh.iter().all(|&f| f) && self.force_fresh
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

    /// SYNC, preceded by the master heartbeats due (one per distinct frame).
    fn send_sync(&mut self) -> bool {
        let now = self.clock.now();
        self.heartbeat_buf.clear();
        for d in &mut self.drives {
            if let Some(hb) = d.heartbeat_frame(now) {
                if !self.heartbeat_buf.contains(&hb) {
                    self.heartbeat_buf.push(hb);
                }
            }
        }
        let mut ok = true;
        for i in 0..self.heartbeat_buf.len() {
            let hb = self.heartbeat_buf[i];
            ok &= self.send(&hb);
        }
        let sync = self.sync.emit();
        ok &= self.send(&sync);
        self.stats.syncs += 1;
        ok
    }

    fn bus_fault(&self) -> Option<String> {
        match self.bus.state() {
            BusState::ErrorActive => None,
            BusState::ErrorPassive => Some("the CAN controller is error-passive".into()),
            BusState::BusOff => Some("the CAN controller is bus-off".into()),
        }
    }

    fn device_fault(&mut self, now: Duration) -> Option<String> {
        for i in 0..N {
            if let Err(e) = self.drives[i].check(now) {
                return Some(format!("{} {e}", self.names[i]));
            }
            if now.saturating_sub(self.last_seen[i]) > self.s.sample_timeout {
                return Some(format!(
                    "{} drive (node {}): no TPDOs for {:.0} ms",
                    self.names[i],
                    self.drives[i].node(),
                    now.saturating_sub(self.last_seen[i]).as_secs_f64() * 1e3
                ));
            }
        }
        if let Err(e) = self.force.check(now) {
            return Some(e.to_string());
        }
        let age = self
            .force_sample
            .map_or(Duration::MAX, |s| now.saturating_sub(s.at));
        if age > self.s.sample_timeout {
            return Some("strap-force node: no TPDO within the sample timeout".into());
        }
        None
    }

    /// Protective stop: ramp the target torque to zero (at the rate limit, within the stop
    /// ramp), one RPDO per drive and a SYNC per period, then quick stop. Counted and logged.
    pub fn protective_stop(&mut self, cause: String) {
        if self.state == Lifecycle::Error {
            return;
        }
        self.state = Lifecycle::Error;
        self.stats.protective_stops += 1;
        let at = self.clock.now();
        let steps = stop_ramp_steps(&self.applied, &self.s.limits, self.s.stop_ramp, self.s.dt);
        let (failures, zero_at) = ramp_to_zero(self, steps);
        for i in 0..N {
            let f = self.drives[i].stop();
            self.send(&f);
        }
        self.send_sync();
        let until = self.clock.now() + self.s.dt;
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
            let s = self.samples[i].unwrap_or_default();
            q[i] = s.position;
            qd[i] = s.velocity;
        }
        let mut force = SVector::zeros();
        if let Some(f) = self.force_sample {
            if N >= 2 {
                force[0] = f.thigh;
            }
            force[N - 1] = f.shank;
        }
        let stamp = self.t0.unwrap_or_default() + self.s.dt * (self.k as u32);
        RobotSample {
            seq: (self.k as u32).wrapping_add(1),
            stamp_ns: stamp.as_nanos() as u64,
            flags,
            q,
            qd,
            force,
            effort: self.applied,
        }
    }

    fn sync_offset(&self) -> Duration {
        self.s
            .phase
            .map_or(Duration::ZERO, |p| self.s.dt.mul_f64(p.clamp(0.0, 0.99)))
    }
}

impl<const N: usize, B: CanBus, K: Clock> RampPeriods<N> for Cia402Robot<N, B, K> {
    fn applied_torque(&self) -> SVector<f64, N> {
        self.applied
    }

    fn send_torques(&mut self, torque: &SVector<f64, N>) -> bool {
        let mut ok = true;
        for i in 0..N {
            let f = self.drives[i].command(torque[i]);
            ok &= self.send(&f);
        }
        ok &= self.send_sync();
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

impl<const N: usize, B: CanBus, K: Clock> RobotInterface<N> for Cia402Robot<N, B, K> {
    fn state(&self) -> Lifecycle {
        self.state
    }

    fn configure(&mut self) -> std::io::Result<()> {
        self.state = Lifecycle::Inactive;
        self.samples = [None; N];
        self.fresh = [false; N];
        self.force_sample = None;
        self.force_fresh = false;
        self.applied = SVector::zeros();
        Ok(())
    }

    /// Configure every node by SDO and enable every drive (blocking, bounded by the SDO and
    /// enable timeouts); then one SYNC whose TPDOs must all arrive within `timeout`.
    fn activate(&mut self, timeout: Duration) -> std::io::Result<bool> {
        match self.state {
            Lifecycle::Active => return Ok(true),
            Lifecycle::Inactive => {}
            s => {
                return Err(io_err(format!(
                    "cannot activate the CiA 402 robot from {s:?}"
                )))
            }
        }
        if let Some(c) = self.bus_fault() {
            return Err(io_err(format!("the CAN bus is not usable: {c}")));
        }
        {
            let Self {
                bus, clock, force, ..
            } = self;
            let now = || clock.now();
            force
                .configure(bus, &now)
                .map_err(|e| io_err(e.to_string()))?;
        }
        for i in 0..N {
            let Self {
                bus, clock, drives, ..
            } = self;
            let now = || clock.now();
            drives[i]
                .configure_and_enable(bus, &now)
                .map_err(|e| io_err(format!("{}: {e}", self.names[i])))?;
        }
        // Align the SYNCs with the virtual leg's grid.
        if let Some(phase) = self.s.phase {
            let dt = self.s.dt.as_nanos().max(1);
            let now = self.clock.now().as_nanos();
            let target = (now / dt + 1) * dt + (phase.clamp(0.0, 0.99) * dt as f64) as u128;
            self.receive_until(Duration::from_nanos(target as u64), |_| false);
        }
        // Every device answers one SYNC before any torque.
        self.fresh = [false; N];
        self.force_fresh = false;
        for i in 0..N {
            let f = self.drives[i].zero();
            self.send(&f);
        }
        let start = self.clock.now();
        if !self.send_sync() {
            return Err(io_err("cannot send the first SYNC".into()));
        }
        self.receive_until(start + timeout.max(self.s.dt), |r| r.all_fresh());
        if !self.all_fresh() {
            let mut missing: Vec<String> = (0..N)
                .filter(|&i| !self.fresh[i])
                .map(|i| format!("{} drive (node {})", self.names[i], self.drives[i].node()))
                .collect();
            if !self.force_fresh {
                missing.push("the strap-force node".into());
            }
            return Err(io_err(format!(
                "no TPDOs after the first SYNC from {}",
                missing.join(", ")
            )));
        }
        self.state = Lifecycle::Active;
        self.t0 = Some(start.saturating_sub(self.sync_offset()));
        self.k = 0;
        let now = self.clock.now();
        self.last_seen = [now; N];
        self.stats.sessions += 1;
        Ok(true)
    }

    fn deactivate(&mut self) -> std::io::Result<()> {
        if self.state == Lifecycle::Active {
            for i in 0..N {
                let f = self.drives[i].zero();
                self.send(&f);
            }
            self.send_sync();
            for i in 0..N {
                let f = self.drives[i].stop();
                self.send(&f);
            }
            self.send_sync();
            self.applied = SVector::zeros();
            self.state = Lifecycle::Inactive;
        }
        Ok(())
    }

    fn error(&mut self) {
        self.protective_stop("the controller abandoned the session".into());
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
        let woke = self.clock.now();
        // The first sample is the activation's SYNC; later ones come from a SYNC on the
        // robot's own grid t_0 + phase + k·dt.
        if self.k > 0 {
            if let Some(t0) = self.t0 {
                let due = t0 + self.sync_offset() + self.s.dt * (self.k as u32);
                if due > woke {
                    self.receive_until(due.min(woke + timeout), |_| false);
                }
            }
            self.fresh = [false; N];
            self.force_fresh = false;
            if !self.send_sync() {
                let c = self
                    .bus_fault()
                    .unwrap_or_else(|| "the SYNC could not be sent".into());
                self.protective_stop(c);
                return Ok(Some(self.sample(robot_flags::PROTECTIVE_STOP)));
            }
            let start = self.clock.now();
            let left = timeout.saturating_sub(start - woke);
            self.receive_until(start + left, |r| r.all_fresh());
        }
        let now = self.clock.now();
        if let Some(c) = self.bus_fault().or_else(|| self.device_fault(now)) {
            self.protective_stop(c);
            return Ok(Some(self.sample(robot_flags::PROTECTIVE_STOP)));
        }
        if !self.all_fresh() {
            self.stats.missing_samples += 1;
            // The next read still waits for its own grid point.
            self.k += 1;
            return Ok(None);
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
            let lim = self.drives[i].config().max_torque;
            let t = torque[i].clamp(-lim, lim);
            let f = self.drives[i].command(t);
            ok &= self.send(&f);
            self.applied[i] = t;
        }
        if !ok {
            let c = self
                .bus_fault()
                .unwrap_or_else(|| "a torque RPDO could not be sent".into());
            self.protective_stop(c);
        }
        Ok(())
    }

    fn link_stats(&self) -> LinkStats {
        self.link
    }
}
