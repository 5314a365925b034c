//! The closed loop and its typed log.

use super::plant::Plant;
use super::trajectory::Trajectory;
use super::Sensors;
#[cfg(not(feature = "std"))]
use crate::clock::Instant;
use crate::control::{Controller, StepStatus, TorqueLimits};
use crate::model::JointState;
use alloc::{vec, vec::Vec};
use nalgebra::SVector;
#[cfg(feature = "std")]
use std::time::Instant;

/// The error of a [`Recorder`]: an I/O error with `std`; without `std` (no files) a message.
#[cfg(feature = "std")]
pub type RecordError = std::io::Error;
/// The error of a [`Recorder`]: an I/O error with `std`; without `std` (no files) a message.
#[cfg(not(feature = "std"))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct RecordError(pub &'static str);

/// What [`Recorder::record`] returns (`std::io::Result<()>` with `std`).
pub type RecordResult = Result<(), RecordError>;

/// A recorder error with the message `msg`.
pub fn record_error(msg: &'static str) -> RecordError {
    #[cfg(feature = "std")]
    return std::io::Error::other(msg);
    #[cfg(not(feature = "std"))]
    return RecordError(msg);
}

/// Everything known about one control period, handed to each [`Recorder`].
#[derive(Clone, Copy, Debug)]
pub struct StepRecord<'a, const N: usize> {
    /// Step index `k`.
    pub k: usize,
    /// Time `t_k` (s).
    pub t: f64,
    /// Robot state at `t_k`.
    pub robot: JointState<f64, N>,
    /// Human state at `t_k`.
    pub human: JointState<f64, N>,
    /// Human desired angles `q_d(t_k)`.
    pub desired: SVector<f64, N>,
    /// Robot torque `T_R(k)` applied over the period (N·m).
    pub torque_robot: SVector<f64, N>,
    /// Previous robot torque `T_R(k−1)` (N·m).
    pub torque_prev: SVector<f64, N>,
    /// Human torque `T_H(t_k)` (N·m).
    pub torque_human: SVector<f64, N>,
    /// True strap forces at `t_k` (N).
    pub force_true: SVector<f64, N>,
    /// Filtered measured strap forces the controller saw (N).
    pub force_measured: SVector<f64, N>,
    /// Scenario probabilities, if the controller has scenarios.
    pub probabilities: Option<&'a [f64]>,
    /// Scenario disturbance estimates (N·m), if the controller has scenarios.
    pub disturbances: Option<&'a [SVector<f64, N>]>,
    /// Controller outcome.
    pub status: StepStatus,
    /// SQP iterations this step.
    pub iterations: u32,
    /// Wall time of the controller's `step` alone (µs).
    pub step_time_us: f64,
    /// Whether the torque satisfied both limits (checked independently of the controller).
    pub within_limits: bool,
}

/// Receives every step of a closed loop (a CSV writer, the metrics, an in-memory log ...).
pub trait Recorder<const N: usize> {
    /// Record one step; an error stops the run and is returned to the caller (a
    /// [`StopRequested`] error ends it early with the results so far instead, see
    /// [`stop_requested`]).
    fn record(&mut self, r: &StepRecord<'_, N>) -> RecordResult;
}

/// The error a [`Recorder`] returns to end a run early on purpose (a user's Ctrl-C): the
/// experiment drivers ([`crate::scenario::run_experiment`]) then return the summary of the
/// steps run so far (its `steps` below the planned count) instead of an error.
#[cfg(feature = "std")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StopRequested;

#[cfg(feature = "std")]
impl std::fmt::Display for StopRequested {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("run stopped on request")
    }
}

#[cfg(feature = "std")]
impl std::error::Error for StopRequested {}

/// The I/O error carrying [`StopRequested`], for a [`Recorder`] to return.
#[cfg(feature = "std")]
pub fn stop_requested() -> std::io::Error {
    std::io::Error::other(StopRequested)
}

/// Whether `e` is the [`stop_requested`] error.
#[cfg(feature = "std")]
pub fn is_stop_requested(e: &std::io::Error) -> bool {
    e.get_ref()
        .is_some_and(|inner| inner.downcast_ref::<StopRequested>().is_some())
}

/// A recorder that ends the run between two control steps once `stop()` returns true (checked
/// once per step, before the plant advances), with the [`stop_requested`] error (the
/// experiment drivers then return the summary of the steps run): the hook to cancel a long run from outside (Ctrl-C, a
/// cancel button, a deadline), e.g. `StopWhen(|| flag.load(Ordering::Relaxed))`.
#[cfg(feature = "std")]
pub struct StopWhen<F: Fn() -> bool>(pub F);

#[cfg(feature = "std")]
impl<const N: usize, F: Fn() -> bool> Recorder<N> for StopWhen<F> {
    fn record(&mut self, _r: &StepRecord<'_, N>) -> std::io::Result<()> {
        if (self.0)() {
            Err(stop_requested())
        } else {
            Ok(())
        }
    }
}

/// One owned row of an in-memory trace.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceRow<const N: usize> {
    /// Time (s).
    pub t: f64,
    /// Robot state.
    pub robot: JointState<f64, N>,
    /// Human state.
    pub human: JointState<f64, N>,
    /// Human desired angles.
    pub desired: SVector<f64, N>,
    /// Robot torque (N·m).
    pub torque_robot: SVector<f64, N>,
    /// Human torque (N·m).
    pub torque_human: SVector<f64, N>,
    /// True strap forces (N).
    pub force_true: SVector<f64, N>,
    /// Filtered measured strap forces (N).
    pub force_measured: SVector<f64, N>,
    /// Scenario probabilities (empty without scenarios).
    pub probabilities: Vec<f64>,
    /// Controller outcome.
    pub status: StepStatus,
    /// Controller step time (µs).
    pub step_time_us: f64,
}

/// An in-memory trace, for tests and small runs.
#[derive(Clone, Debug, Default)]
pub struct TraceLog<const N: usize> {
    /// Rows in time order.
    pub rows: Vec<TraceRow<N>>,
}

impl<const N: usize> Recorder<N> for TraceLog<N> {
    fn record(&mut self, r: &StepRecord<'_, N>) -> RecordResult {
        self.rows.push(TraceRow {
            t: r.t,
            robot: r.robot,
            human: r.human,
            desired: r.desired,
            torque_robot: r.torque_robot,
            torque_human: r.torque_human,
            force_true: r.force_true,
            force_measured: r.force_measured,
            probabilities: r.probabilities.map(|p| p.to_vec()).unwrap_or_default(),
            status: r.status,
            step_time_us: r.step_time_us,
        });
        Ok(())
    }
}

/// Run `steps` control periods: sample the sensors at `t_k`, call the controller, record, and
/// advance the plant with the torque held (MODEL.md §7). `limits` are checked on every output
/// independently of the controller (a violation is recorded, never silently fixed).
pub fn run_closed_loop<const N: usize, Tr: Trajectory<N>, C: Controller<N> + ?Sized>(
    plant: &mut Plant<N, Tr>,
    sensors: &mut Sensors<N>,
    controller: &mut C,
    limits: &TorqueLimits,
    steps: usize,
    recorders: &mut [&mut dyn Recorder<N>],
) -> RecordResult {
    let mut dist =
        vec![SVector::<f64, N>::zeros(); controller.probabilities().map_or(0, |p| p.len())];
    for k in 0..steps {
        let t = plant.time();
        let s = *plant.state();
        let force_true = plant.strap_force();
        let (_raw, meas) = sensors.read(t, &s.robot.q, &s.robot.qd, &force_true);
        let prev = controller.previous_torque();
        let start = Instant::now();
        let out = controller.step(&meas);
        let step_time_us = start.elapsed().as_secs_f64() * 1e6;
        for (i, d) in dist.iter_mut().enumerate() {
            *d = controller.disturbance(i).unwrap_or_else(SVector::zeros);
        }
        let rec = StepRecord {
            k,
            t,
            robot: s.robot,
            human: s.human,
            desired: plant.trajectory().eval(t).0,
            torque_robot: out.torque,
            torque_prev: prev,
            torque_human: plant.human_torque(),
            force_true,
            force_measured: meas.force,
            probabilities: controller.probabilities(),
            disturbances: if dist.is_empty() { None } else { Some(&dist) },
            status: out.status,
            iterations: out.iterations,
            step_time_us,
            within_limits: limits.admits(&prev, &out.torque),
        };
        for r in recorders.iter_mut() {
            r.record(&rec)?;
        }
        plant.step(&out.torque);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;

    fn record(k: usize) -> StepRecord<'static, 1> {
        let z = SVector::<f64, 1>::zeros();
        let js = JointState { q: z, qd: z };
        StepRecord {
            k,
            t: k as f64 * 0.01,
            robot: js,
            human: js,
            desired: z,
            torque_robot: z,
            torque_prev: z,
            torque_human: z,
            force_true: z,
            force_measured: z,
            probabilities: None,
            disturbances: None,
            status: StepStatus::Ok,
            iterations: 0,
            step_time_us: 0.0,
            within_limits: true,
        }
    }

    #[test]
    fn stop_when_ends_the_run_once_asked() {
        let calls = Cell::new(0);
        let mut stop = StopWhen(|| {
            calls.set(calls.get() + 1);
            calls.get() > 3
        });
        for k in 0..3 {
            assert!(Recorder::<1>::record(&mut stop, &record(k)).is_ok());
        }
        let e = Recorder::<1>::record(&mut stop, &record(3)).unwrap_err();
        assert!(is_stop_requested(&e));
        assert_eq!(calls.get(), 4, "checked exactly once per step");
    }
}
