//! Controllers: the human-intent estimate (paper eqs. 5-6), torque limits (eqs. 8-9), the
//! baseline PD, the non-robust NMPC (eq. 7) and the multi-stage NMPC (eqs. 12-13).
//!
//! Every controller implements [`Controller`]: one call per control period, filtered
//! measurements in, a torque out that always satisfies the torque and torque-rate limits.
//!
//! # The controllers
//!
//! * [`PdController`]: a joint PD on the human-intent estimate, the baseline.
//! * [`Nmpc`]: the non-robust NMPC of paper eq. 7 on one prediction model (by default the
//!   nominal robot without payload and without disturbance estimate). [`NmpcProblem`] is the
//!   optimisation problem of one step, [`NmpcCore`] its solver with all buffers preallocated.
//! * [`MultiStage`]: the multi-stage robust NMPC (paper eqs. 10-13): one scenario per candidate
//!   payload, each with its own model and the disturbance estimate of its EKF; the scenario
//!   probabilities of the EKF bank ([`crate::estimate::EkfBank`]) weight the scenarios, in the
//!   paper's decoupled form or the coupled scenario-tree form ([`Formulation`]).
//! * [`Supervisor`]: wraps any controller with sensor plausibility checks, safety monitors and
//!   a safe fallback torque; every output passes the limits ([`TorqueLimits`]).
//!
//! [`crate::scenario::build_controller`] and [`crate::scenario::build_supervised`] build them from a
//! [`crate::config::Experiment`]; `docs/MODEL.md` §8 gives the equations and default values.

mod fallback;
mod heavy;
mod hessian;
mod highpass;
mod intent;
mod lag;
mod limits;
mod multistage;
mod nmpc;
mod nmpc_problem;
mod ocp;
mod ocp_tree;
mod pd;
mod prediction;
mod ride_through;
mod robust;
mod safety;
mod strap_intent;
mod weights;

pub use fallback::{FallbackSettings, FallbackSettingsError, Transparent};
pub use heavy::inertia_ratios;
pub use hessian::StepHessian;
pub use highpass::HighPass;
pub use intent::{GainSetting, IntentGain, AUTO_K1_PER_STIFFNESS, AUTO_K2_PER_STIFFNESS};
pub use lag::{ForceLag, HfShareDetector};
pub use limits::{LimitsError, TorqueLimits};
pub use multistage::{CoupledProblem, Formulation, MultiStage, MultiStageError, MultiStageOptions};
pub use nmpc::{classify, horizon_inputs, Nmpc, NmpcCore, NmpcError};
pub use nmpc_problem::{
    velocity_metric, HessianSetting, NmpcProblem, NmpcSettings, QpBackend, SolverChoice,
    VelocityTracking, AUTO_STRUCTURED_MIN_VARS,
};
pub use ocp::StructuredSqp;
pub use ocp_tree::{TreeSqp, AUTO_TREE_MIN_VARS};
pub use pd::PdController;
pub use prediction::{HorizonInputs, Interaction, PredictionModel, StepJacobian};
pub use ride_through::{
    ChannelGuard, EstimatedChannels, Repaired, TorqueExtrapolation, ACCEPT_GATES,
    ADAPTIVE_GATE_SIGMAS, ANCHORED_LIMIT_FACTOR, EXTRAPOLATION_ANGLE_S, EXTRAPOLATION_FADE_STEPS,
    EXTRAPOLATION_FIT_S, EXTRAPOLATION_MAX_HZ, EXTRAPOLATION_MIN_HZ, EXTRAPOLATION_MIN_S,
    FORCE_BIAS_RATE, FORCE_FIT_S, FORCE_GATE, FORCE_RANGE_MARGIN, FORCE_REPLAY_WEIGHT,
    FORCE_RESYNC_S, JOINT_LOST_LIMIT_FACTOR, JUMP_ACCEL, PARTIAL_SLOPE_SPAN, PERIOD_MATCH_EVERY,
    PERIOD_MATCH_SPAN, PERIOD_MATCH_STEPS, RESIDUAL_TAU_S, SLOPE_ACCEPT_GATES, STUCK_SPEED,
    UNVERIFIED_S, VELOCITY_GATE,
};
pub use robust::{
    removed_robust_key, FilterAware, IntentEstimate, Method, RobustIntentGains, RobustSettings,
    RobustTuning, PAPER_STRAP_STIFFNESS, REMOVED_ROBUST_KEYS,
};
pub use safety::{
    GaitFrequency, MonitorAction, MonitorEvent, MonitorKind, MonitorResponse, Monitors,
    OscillationDetector, SafetyReport, SafetySettings, StrapAngleEstimate, Supervisor,
    COAST_FORCE_GAIN, FALLBACK_DEMAND_BEYOND, FALLBACK_DEMAND_JUMP,
    FALLBACK_OSCILLATION_GAIT_RATIO, GAIT_BAND_RAD, GAIT_MAX_HZ, GAIT_MEAN_TAU_S,
    OSCILLATION_MIN_HALF_CYCLES, REPLAY_BLEND_IN_STEPS, REPLAY_HANDBACK_STEPS, RESPONSE_ESCALATE_S,
    STOP_HANDBACK_STEPS, STOP_RAMP_NM_PER_S,
};

use nalgebra::SVector;
use serde::Serialize;

/// What the controller receives each period: encoder angles and the filtered velocities and
/// strap forces (MODEL.md §5, §8).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measurement<const N: usize> {
    /// Time of the sample (s).
    pub t: f64,
    /// Robot joint angles (rad), exact encoders.
    pub q: SVector<f64, N>,
    /// Filtered robot joint velocities (rad/s).
    pub qd: SVector<f64, N>,
    /// Filtered strap forces (N), thigh then shank (1-DOF: shank only).
    pub force: SVector<f64, N>,
}

impl<const N: usize> Measurement<N> {
    /// True when every value is finite.
    pub fn is_finite(&self) -> bool {
        self.t.is_finite()
            && self.q.iter().all(|v| v.is_finite())
            && self.qd.iter().all(|v| v.is_finite())
            && self.force.iter().all(|v| v.is_finite())
    }
}

/// The outcome of one control step, reported beside the torque. This enum is the one table of
/// status codes: [`StepStatus::code`] is the runtime frame's wire code and the index of
/// Python's `STATUS_NAMES`, [`StepStatus::name`] the trace CSV's `status` column and the JSON
/// form.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum StepStatus {
    /// The optimisation converged (or the controller needs none).
    Ok = 0,
    /// The solver hit its iteration cap; its best feasible iterate was used.
    MaxIterations = 1,
    /// The solver hit its time budget; its best feasible iterate was used.
    MaxTime = 2,
    /// The solver failed (QP failure, line search failure, non-finite model values); the
    /// previous torque was held.
    SolverFailed = 3,
    /// A measurement was not finite or implausible; the previous torque was held.
    BadMeasurement = 4,
    /// A safety monitor fired; its configured response set the torque.
    MonitorTripped = 5,
}

impl StepStatus {
    /// Every status, in the order of its code.
    pub const ALL: [StepStatus; 6] = [
        StepStatus::Ok,
        StepStatus::MaxIterations,
        StepStatus::MaxTime,
        StepStatus::SolverFailed,
        StepStatus::BadMeasurement,
        StepStatus::MonitorTripped,
    ];

    /// The status's code (0..=5, its index in [`StepStatus::ALL`]).
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The status of a code (`None` for an unknown code).
    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.get(usize::from(code)).copied()
    }

    /// The status's name, as in the trace CSV and JSON (`"ok"`, `"max_iterations"`, ...).
    pub const fn name(self) -> &'static str {
        match self {
            StepStatus::Ok => "ok",
            StepStatus::MaxIterations => "max_iterations",
            StepStatus::MaxTime => "max_time",
            StepStatus::SolverFailed => "solver_failed",
            StepStatus::BadMeasurement => "bad_measurement",
            StepStatus::MonitorTripped => "monitor_tripped",
        }
    }

    /// True for outcomes that count as solver failures in the summary.
    pub fn is_solver_failure(self) -> bool {
        matches!(
            self,
            StepStatus::MaxIterations | StepStatus::MaxTime | StepStatus::SolverFailed
        )
    }
}

/// A torque command and how it was obtained.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlOutput<const N: usize> {
    /// Robot joint torque `T_R(k)` (N·m), within the limits.
    pub torque: SVector<f64, N>,
    /// Outcome of the step.
    pub status: StepStatus,
    /// SQP iterations used this step (summed over scenarios).
    pub iterations: u32,
}

/// A feedback controller called once per control period.
pub trait Controller<const N: usize> {
    /// Compute the torque for this period from the filtered measurement. Never panics, never
    /// allocates on the hot path, and always returns a torque within the limits.
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N>;

    /// Short name: the name of the controller's registry entry (`msnmpc`, `nmpc`, `pd`, ...;
    /// [`crate::scenario::ControllerInfo`]), used in summaries and folder names.
    fn name(&self) -> &'static str;

    /// Scenario probabilities `μ_i(k)` (paper eqs. 10-11), if the controller has scenarios.
    fn probabilities(&self) -> Option<&[f64]> {
        None
    }

    /// Scenario `i`'s disturbance estimate (N·m), if the controller has scenarios.
    fn disturbance(&self, _i: usize) -> Option<SVector<f64, N>> {
        None
    }

    /// The torque applied in the previous period, `T_R(k−1)`.
    fn previous_torque(&self) -> SVector<f64, N>;

    /// Overwrite `T_R(k−1)` with the torque actually applied (a supervisor that held or ramped
    /// the output keeps the controller in sync, so it resumes from the real torque). Values are
    /// made admissible with [`TorqueLimits::admissible`] (clamped to `±T_max`, NaN → 0). Default: no-op (stateless).
    fn set_previous_torque(&mut self, _t: SVector<f64, N>) {}

    /// The safety supervisor's counters and event log, if this controller is supervised.
    fn safety_report(&self) -> Option<&SafetyReport> {
        None
    }

    /// The torques planned for the periods after the last step's, from its solve: writes
    /// `out[j]` for period `k+1+j` (each within both limits of the one before, the first of
    /// the last output) for up to `out.len()` entries and returns how many it wrote. A robot
    /// plays them out while no newer command reaches it. Default: none (0).
    fn planned_torques(&self, _out: &mut [SVector<f64, N>]) -> usize {
        0
    }

    /// The controller's own model prediction of the next measurement's joint angles and
    /// velocities `(q, qd)` under the torque it applied, if it has a model-based estimator
    /// (MS-NMPC: its EKF bank); the supervisor uses it for rejected encoder channels.
    /// Default: `None`.
    fn predicted_state(&self) -> Option<(SVector<f64, N>, SVector<f64, N>)> {
        None
    }

    /// [`step`](Self::step) on a measurement whose `estimated` channels are the supervisor's
    /// estimates of rejected channels: a model-based estimator should not update on them
    /// (MS-NMPC: its EKF bank updates with the measured rows only) and re-synchronise on the
    /// next full measurement. Default: `step`.
    fn step_estimated(
        &mut self,
        m: &Measurement<N>,
        _estimated: &EstimatedChannels<N>,
    ) -> ControlOutput<N> {
        self.step(m)
    }
}

/// Fill `out` with the torques `T(k+j) = T(k+j−1) + dT(k+j)`, `j = 1, 2, …`, from the applied
/// `T(k)` = `prev` and the increments `inc(j)` (`None` past the control horizon), each clamped
/// to `limits`; returns the entries written.
pub(crate) fn plan_from<const N: usize>(
    prev: &SVector<f64, N>,
    limits: &TorqueLimits,
    out: &mut [SVector<f64, N>],
    inc: impl Fn(usize) -> Option<SVector<f64, N>>,
) -> usize {
    let mut t = *prev;
    let mut n = 0;
    for (j, o) in out.iter_mut().enumerate() {
        let Some(d) = inc(j + 1) else { break };
        t = limits.clamp(&t, &(t + d));
        *o = t;
        n += 1;
    }
    n
}

/// Human-intent estimate of paper eqs. 5-6: `q̂_H = q_R + K1 F`, `q̂d_H = qd_R + K2 F`, with
/// fixed gains `K = k·I` (the paper's) or gains derived from the strap model ([`IntentGain`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntentEstimator {
    /// `K1`: fixed (rad/N, default 0.005) or `κ1 (ks J)⁻¹`.
    pub k1: IntentGain,
    /// `K2`: fixed (rad/(N·s), default 0.05) or `κ2 (ks J)⁻¹`.
    pub k2: IntentGain,
}

impl IntentEstimator {
    /// The paper's diagonal gains `K1 = k1·I`, `K2 = k2·I`.
    pub fn fixed(k1: f64, k2: f64) -> Self {
        IntentEstimator {
            k1: IntentGain::Fixed(k1),
            k2: IntentGain::Fixed(k2),
        }
    }

    /// `(q̂_H, q̂d_H)` from a filtered measurement; `straps` (the prediction model's) give the
    /// derived gains.
    #[inline]
    pub fn estimate<const N: usize>(
        &self,
        m: &Measurement<N>,
        straps: &crate::model::Straps<N>,
    ) -> (SVector<f64, N>, SVector<f64, N>) {
        (
            m.q + self.k1.apply(straps, &m.force),
            m.qd + self.k2.apply(straps, &m.force),
        )
    }
}

#[cfg(test)]
mod status_table {
    use super::StepStatus;

    /// The one status table: codes are the indices of `ALL`, names are the serde names.
    #[test]
    fn codes_and_names_are_one_table() {
        for (i, s) in StepStatus::ALL.iter().enumerate() {
            assert_eq!(usize::from(s.code()), i);
            assert_eq!(StepStatus::from_code(s.code()), Some(*s));
            assert_eq!(
                serde_json::to_value(s).unwrap(),
                serde_json::Value::from(s.name())
            );
        }
        assert_eq!(StepStatus::from_code(StepStatus::ALL.len() as u8), None);
        let mut names: Vec<&str> = StepStatus::ALL.iter().map(|s| s.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), StepStatus::ALL.len());
    }
}
