//! Runtime safety supervision around any controller: see [`Supervisor`].

use super::{ControlOutput, Controller, Measurement, StepStatus, TorqueLimits};
use crate::config::{MonitorResponse, Monitors, Scenario};
use nalgebra::SVector;
use serde::Serialize;

/// Thresholds and responses of a [`Supervisor`].
#[derive(Clone, Debug, PartialEq)]
pub struct SafetySettings {
    /// Torque limits enforced on every output.
    pub limits: TorqueLimits,
    /// Control period (s), the supervisor's clock.
    pub dt: f64,
    /// Intent gain `K1` (rad/N) of the tracking-error estimate `|K1·F|`.
    pub k1: f64,
    /// Force sensor range (N): `|F| ≥ saturation_n` is implausible.
    pub saturation_n: f64,
    /// Plausible joint angles `|q| ≤ angle_max` (rad).
    pub angle_max: f64,
    /// Plausible joint velocities `|qd| ≤ velocity_max` (rad/s).
    pub velocity_max: f64,
    /// The `[monitors]` thresholds and response.
    pub monitors: Monitors,
    /// A tripped monitor clears after its condition has been absent this long (s).
    pub clear_after_s: f64,
    /// Capacity of the event log (events beyond it are counted only).
    pub max_events: usize,
}

impl SafetySettings {
    /// Plausibility limit on joint angles (rad).
    pub const ANGLE_MAX: f64 = std::f64::consts::PI;
    /// Plausibility limit on joint velocities (rad/s).
    pub const VELOCITY_MAX: f64 = 30.0;
    /// Default hold-off before a monitor clears (s).
    pub const CLEAR_AFTER_S: f64 = 0.1;

    /// The settings of scenario `s` (`[monitors]`, `[faults] saturation_n`, limits, K1, dt).
    pub fn from_scenario(s: &Scenario) -> Self {
        SafetySettings {
            limits: TorqueLimits {
                max: s.controller.torque_max,
                rate: s.rate_limit_per_step(),
            },
            dt: s.timing.dt,
            k1: s.controller.k1,
            saturation_n: s.faults.saturation_n,
            angle_max: Self::ANGLE_MAX,
            velocity_max: Self::VELOCITY_MAX,
            monitors: s.monitors.clone(),
            clear_after_s: Self::CLEAR_AFTER_S,
            max_events: 4096,
        }
    }
}

/// A runtime safety monitor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MonitorKind {
    /// `|K1·F| > tracking_error_max_rad` on some joint.
    TrackingError,
    /// `|F| > force_max_n` on some strap.
    StrapForce,
    /// A channel without a fresh valid sample for longer than `sensor_timeout_s`.
    SensorTimeout,
}

const MONITORS: [MonitorKind; 3] = [
    MonitorKind::TrackingError,
    MonitorKind::StrapForce,
    MonitorKind::SensorTimeout,
];

/// A monitor tripping or clearing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MonitorAction {
    /// The monitor tripped; its response now sets the torque.
    Trip,
    /// The monitor cleared; the controller resumed.
    Clear,
}

/// One logged monitor event.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MonitorEvent {
    /// Supervisor time (s): first measurement time plus steps × dt.
    pub t: f64,
    /// Which monitor.
    pub monitor: MonitorKind,
    /// Trip or clear.
    pub action: MonitorAction,
    /// The offending value at a trip (rad, N or s), 0 at a clear.
    pub value: f64,
}

/// Counters and the event log of a [`Supervisor`].
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SafetyReport {
    /// Steps supervised.
    pub steps: u64,
    /// Steps whose measurement was rejected (non-finite or implausible).
    pub bad_measurement_steps: u64,
    /// Monitor trips (all monitors).
    pub monitor_trips: u64,
    /// Steps on which a monitor's response set the torque.
    pub monitor_steps: u64,
    /// Logged events, in time order (at most `max_events`).
    pub events: Vec<MonitorEvent>,
    /// Events not stored because the log was full.
    pub events_dropped: u64,
}

/// Runtime safety supervision (exoskeleton-firmware style): measurement plausibility checks
/// with a safe fallback, and the `[monitors]` of the scenario, wrapped around any controller.
///
/// [`Supervisor`] implements [`Controller`] around an inner controller:
///
/// * **Plausibility.** A measurement with a non-finite value, `|q| > angle_max` (π),
///   `|qd| > velocity_max` (30 rad/s) or `|F| ≥ saturation_n` (the force sensor's range) is
///   rejected: the inner controller is *not* stepped (it is never fed garbage) and the previous
///   torque is held (status [`StepStatus::BadMeasurement`]). When the data is good again the
///   inner controller resumes from the torque actually applied (kept in sync through
///   [`Controller::set_previous_torque`]).
/// * **Monitors.** Human-robot tracking error estimated as `|K1·F|` (q_H is not measured)
///   above `tracking_error_max_rad`, strap force above `force_max_n`, and any sensor channel
///   without a fresh valid sample (non-finite, implausible, or bit-for-bit repeated) for longer
///   than `sensor_timeout_s`. A tripped monitor applies the configured response (`hold` the
///   last torque, or `ramp_to_zero` at the rate limit; status
///   [`StepStatus::MonitorTripped`]); it clears after its condition has been absent for
///   `clear_after_s`, and the inner controller resumes from the applied torque. Trips and
///   clears are logged with their time in a bounded event list ([`SafetyReport`]).
/// * **Limits.** Every output passes through [`TorqueLimits::clamp`] relative to the previous
///   output, so `|T| ≤ T_max` and `|T − T_prev| ≤ ΔT_max` hold whatever the inner controller
///   returns (NaN included).
///
/// The hot path does not allocate (the event list is preallocated; events beyond its capacity
/// are counted, not stored).
#[derive(Clone, Debug)]
pub struct Supervisor<const N: usize, C> {
    inner: C,
    s: SafetySettings,
    prev: SVector<f64, N>,
    k: u64,
    t0: f64,
    /// Last fresh valid sample time per signal (q, qd, F) and joint.
    fresh_t: [SVector<f64, N>; 3],
    /// Previous raw value per signal and joint (bit-exact staleness check).
    last: [SVector<f64, N>; 3],
    tripped: [bool; 3],
    ok_since: [Option<f64>; 3],
    report: SafetyReport,
}

impl<const N: usize, C: Controller<N>> Supervisor<N, C> {
    /// Wrap `inner`; the supervisor starts from the inner controller's previous torque.
    pub fn new(inner: C, settings: SafetySettings) -> Self {
        let cap = settings.max_events;
        let prev = settings.limits.admissible(&inner.previous_torque());
        let mut sup = Supervisor {
            inner,
            s: settings,
            prev,
            k: 0,
            t0: 0.0,
            fresh_t: [SVector::zeros(); 3],
            last: [SVector::zeros(); 3],
            tripped: [false; 3],
            ok_since: [None; 3],
            report: SafetyReport {
                events: Vec::with_capacity(cap),
                ..Default::default()
            },
        };
        sup.inner.set_previous_torque(prev);
        sup
    }

    /// The wrapped controller.
    pub fn inner(&self) -> &C {
        &self.inner
    }

    /// The settings.
    pub fn settings(&self) -> &SafetySettings {
        &self.s
    }

    /// Counters and logged events so far.
    pub fn report(&self) -> &SafetyReport {
        &self.report
    }

    /// True while any monitor is tripped.
    pub fn is_tripped(&self) -> bool {
        self.tripped.iter().any(|&t| t)
    }

    fn log(&mut self, e: MonitorEvent) {
        if self.report.events.len() < self.s.max_events {
            self.report.events.push(e);
        } else {
            self.report.events_dropped += 1;
        }
    }

    /// Updates the channel freshness; returns (all valid, longest silence in s).
    fn check_channels(&mut self, m: &Measurement<N>, now: f64) -> (bool, f64) {
        let first = self.k == 1;
        let bounds = [self.s.angle_max, self.s.velocity_max, self.s.saturation_n];
        let mut all_valid = m.t.is_finite();
        let mut silent: f64 = 0.0;
        for (sig, vals) in [&m.q, &m.qd, &m.force].into_iter().enumerate() {
            for j in 0..N {
                let v = vals[j];
                let valid = v.is_finite()
                    && if sig == 2 {
                        v.abs() < bounds[sig]
                    } else {
                        v.abs() <= bounds[sig]
                    };
                let fresh = valid && (first || v.to_bits() != self.last[sig][j].to_bits());
                if first || fresh {
                    self.fresh_t[sig][j] = now;
                }
                self.last[sig][j] = v;
                all_valid &= valid;
                silent = silent.max(now - self.fresh_t[sig][j]);
            }
        }
        (all_valid, silent)
    }

    /// Evaluates the monitors; returns true while any is tripped.
    fn update_monitors(&mut self, m: &Measurement<N>, silent: f64, now: f64) -> bool {
        let mo = self.s.monitors.clone();
        let mut track: f64 = 0.0;
        let mut force: f64 = 0.0;
        for j in 0..N {
            let f = m.force[j];
            if f.is_finite() {
                track = track.max((self.s.k1 * f).abs());
                force = force.max(f.abs());
            }
        }
        let values = [track, force, silent];
        let cond = [
            track > mo.tracking_error_max_rad,
            force > mo.force_max_n,
            silent > mo.sensor_timeout_s + 1e-9,
        ];
        for i in 0..3 {
            if cond[i] {
                self.ok_since[i] = None;
                if !self.tripped[i] {
                    self.tripped[i] = true;
                    self.report.monitor_trips += 1;
                    self.log(MonitorEvent {
                        t: now,
                        monitor: MONITORS[i],
                        action: MonitorAction::Trip,
                        value: values[i],
                    });
                }
            } else if self.tripped[i] {
                let since = *self.ok_since[i].get_or_insert(now);
                if now - since >= self.s.clear_after_s - 1e-9 {
                    self.tripped[i] = false;
                    self.ok_since[i] = None;
                    self.log(MonitorEvent {
                        t: now,
                        monitor: MONITORS[i],
                        action: MonitorAction::Clear,
                        value: 0.0,
                    });
                }
            }
        }
        self.is_tripped()
    }
}

impl<const N: usize, C: Controller<N>> Controller<N> for Supervisor<N, C> {
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N> {
        if self.k == 0 && m.t.is_finite() {
            self.t0 = m.t;
        }
        self.k += 1;
        let dt = if self.s.dt.is_finite() && self.s.dt > 0.0 {
            self.s.dt
        } else {
            0.01
        };
        let now = self.t0 + (self.k - 1) as f64 * dt;
        self.report.steps += 1;
        let (valid, silent) = self.check_channels(m, now);
        let tripped = self.update_monitors(m, silent, now);
        let prev = self.prev;
        let response = match self.s.monitors.response {
            MonitorResponse::Hold => prev,
            MonitorResponse::RampToZero => SVector::zeros(),
        };
        let (desired, mut status, iterations) = if valid {
            // The inner controller keeps estimating while a monitor holds the output.
            let out = self.inner.step(m);
            (out.torque, out.status, out.iterations)
        } else {
            self.report.bad_measurement_steps += 1;
            (prev, StepStatus::BadMeasurement, 0)
        };
        let desired = if tripped {
            self.report.monitor_steps += 1;
            status = StepStatus::MonitorTripped;
            response
        } else {
            desired
        };
        let torque = self.s.limits.clamp(&prev, &desired);
        self.prev = torque;
        if self.inner.previous_torque() != torque {
            self.inner.set_previous_torque(torque);
        }
        ControlOutput {
            torque,
            status,
            iterations,
        }
    }

    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn probabilities(&self) -> Option<&[f64]> {
        self.inner.probabilities()
    }

    fn disturbance(&self, i: usize) -> Option<SVector<f64, N>> {
        self.inner.disturbance(i)
    }

    fn previous_torque(&self) -> SVector<f64, N> {
        self.prev
    }

    fn set_previous_torque(&mut self, t: SVector<f64, N>) {
        self.prev = self.s.limits.admissible(&t);
        self.inner.set_previous_torque(self.prev);
    }

    fn safety_report(&self) -> Option<&SafetyReport> {
        Some(&self.report)
    }
}

impl<const N: usize, C: Controller<N> + ?Sized> Controller<N> for Box<C> {
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N> {
        (**self).step(m)
    }
    fn name(&self) -> &'static str {
        (**self).name()
    }
    fn probabilities(&self) -> Option<&[f64]> {
        (**self).probabilities()
    }
    fn disturbance(&self, i: usize) -> Option<SVector<f64, N>> {
        (**self).disturbance(i)
    }
    fn previous_torque(&self) -> SVector<f64, N> {
        (**self).previous_torque()
    }
    fn set_previous_torque(&mut self, t: SVector<f64, N>) {
        (**self).set_previous_torque(t)
    }
    fn safety_report(&self) -> Option<&SafetyReport> {
        (**self).safety_report()
    }
}
