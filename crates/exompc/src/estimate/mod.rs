//! State, disturbance and scenario-probability estimation: parallel extended Kalman filters
//! (paper §3.2, eqs. 10-11; docs/MODEL.md §8).
//!
//! The multi-stage controller runs one EKF per payload scenario on the augmented state
//! `x = [q, qd, d]` (joint angles, joint velocities and a lumped joint torque disturbance `d`
//! that is *added* to the robot's right-hand side, so the model sees
//! `tau = T_R + T_int + d`). The measurement is `y = [q, qd]`. Each filter supplies
//!
//! * its disturbance estimate `d̂ᵢ`, fed to scenario `i`'s prediction model, and
//! * its innovation `vᵢ` and innovation covariance `S̄ᵢ`, from which the scenario probabilities
//!   `μᵢ` of paper eqs. 10-11 are computed ([`update_probabilities`]).
//!
//! The pieces:
//!
//! * [`Ekf`]: a generic, allocation-free extended Kalman filter on fixed-size nalgebra types
//!   (Joseph-form covariance update, symmetric `P`, no panics).
//! * [`ScenarioEkf`]: one payload scenario — RK4 prediction of the robot model with the exact
//!   Jacobian obtained by forward-mode dual numbers (`num-dual`).
//! * [`EkfBank`]: all scenarios plus the probabilities of eqs. 10-11, computed in the log
//!   domain.
//!
//! # Why these noise values (MODEL.md §8)
//!
//! The default [`EkfSettings`] are
//! `Q = diag(1e-8 (angle), 1e-4 (velocity), 1e-2 (disturbance))`,
//! `R = diag(1e-6 (angle), 1 (velocity))`, `P0 = diag(1e-6, 1e-2, 1)` per joint:
//!
//! * **Angles are trusted.** Encoder angles are exact and undelayed (MODEL.md §5), so both their
//!   measurement variance and their process noise are tiny; the filter leans on the angle
//!   channel.
//! * **Velocities are distrusted.** The controller's velocity is the mean of the five most recent
//!   samples (MODEL.md §5), which lags the true velocity by about two samples. Treated as white
//!   noise that lag is a large error, hence `R_velocity = 1`: the velocity estimate is driven
//!   mostly by the (exact) angle sequence through the model.
//! * **The disturbance is a slow random walk.** `Q_d = 1e-2 (N·m)²` per step lets `d̂` absorb the
//!   mismatch between a scenario's payload and the true one (several N·m) within a fraction of a
//!   second without chasing every sample, and `P0_d = 1` N·m² says the initial disturbance is
//!   unknown at the N·m level. The scenario probabilities react to the *innovations*, i.e. to the
//!   part of the mismatch the random walk has not (yet) absorbed — including state-dependent
//!   inertial and gravitational effects that a slowly varying `d` cannot follow.

mod bank;
mod ekf;
mod moving_average;
mod scenario;

pub use bank::{update_probabilities, EkfBank};
pub use ekf::{Ekf, EkfError, InnovationStats};
pub use moving_average::MovingAverage;
pub use scenario::{ScenarioEkf, ScenarioUpdate};

use crate::check::{self, InvalidField, Range};
use nalgebra::{SMatrix, SVector};

/// Which innovation the scenario probabilities (paper eq. 10) are computed from.
///
/// The state correction of every [`ScenarioEkf`] always uses the standard innovation; the mode
/// only selects the `vᵢ(k)` entering eq. 10.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Innovation {
    /// The usual EKF innovation `vᵢ(k) = y(k) − h(x̂ᵢ(k|k−1))` (MODEL.md §8 default).
    #[default]
    Standard,
    /// Paper §3.2: "the predicted output of each scenario is the sum of the output calculated by
    /// dynamic equations of that scenario and the corresponding estimation error at the previous
    /// time step":
    /// `ŷᵢ(k|k−1) = h(x̂ᵢ(k|k−1)) + eᵢ(k−1)`, with the a-posteriori residual
    /// `eᵢ(k−1) = y(k−1) − h(x̂ᵢ(k−1|k−1))` (zero before the first update), so
    /// `vᵢ(k) = y(k) − ŷᵢ(k|k−1)`. Its covariance is approximated by the standard `S̄ᵢ`.
    ///
    /// This innovation is used for the probabilities only: feeding it back into the state
    /// correction would make a constant model mismatch look like an output offset
    /// (`eᵢ → vᵢ`, the correction vanishes), so the disturbance estimate would stop absorbing
    /// the mismatch.
    Paper,
}

/// Error of the estimation module's configuration.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EstimateError {
    /// A setting is out of range (name of the setting and the requirement).
    #[error("invalid estimator setting `{0}`: {1}")]
    InvalidSetting(&'static str, &'static str),
    /// An [`EkfSettings`] value is out of range.
    #[error("EKF settings: {0}")]
    Settings(#[from] InvalidField),
    /// The bank was given no scenario.
    #[error("the EKF bank needs at least one scenario")]
    NoScenario,
}

/// Per-component covariances of each scenario EKF on `[q, qd, d]` (MODEL.md §8).
///
/// Each value applies to every joint. Variances in SI units: rad², (rad/s)², (N·m)². The
/// [`Default`] is the MODEL.md §8 starting point; see the module documentation for the reasons.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EkfSettings {
    /// Process noise variance of each joint angle per step (rad²). Default 1e-8.
    pub q_angle: f64,
    /// Process noise variance of each joint velocity per step ((rad/s)²). Default 1e-4.
    pub q_velocity: f64,
    /// Random-walk variance of each lumped disturbance per step ((N·m)²). Default 1e-2.
    pub q_disturbance: f64,
    /// Measurement noise variance of each angle (rad²). Default 1e-6.
    pub r_angle: f64,
    /// Measurement noise variance of each (filtered) velocity ((rad/s)²). Default 1.
    pub r_velocity: f64,
    /// Initial covariance of each angle (rad²). Default 1e-6.
    pub p0_angle: f64,
    /// Initial covariance of each velocity ((rad/s)²). Default 1e-2.
    pub p0_velocity: f64,
    /// Initial covariance of each disturbance ((N·m)²). Default 1.
    pub p0_disturbance: f64,
}

impl Default for EkfSettings {
    fn default() -> Self {
        Self {
            q_angle: 1e-8,
            q_velocity: 1e-4,
            q_disturbance: 1e-2,
            r_angle: 1e-6,
            r_velocity: 1.0,
            p0_angle: 1e-6,
            p0_velocity: 1e-2,
            p0_disturbance: 1.0,
        }
    }
}

impl EkfSettings {
    /// Checks that every variance is finite and > 0; the error names the key (`q_angle`, ...).
    pub fn validate(&self) -> Result<(), InvalidField> {
        check::reals(&[
            ("q_angle", self.q_angle, Range::Pos),
            ("q_velocity", self.q_velocity, Range::Pos),
            ("q_disturbance", self.q_disturbance, Range::Pos),
            ("r_angle", self.r_angle, Range::Pos),
            ("r_velocity", self.r_velocity, Range::Pos),
            ("p0_angle", self.p0_angle, Range::Pos),
            ("p0_velocity", self.p0_velocity, Range::Pos),
            ("p0_disturbance", self.p0_disturbance, Range::Pos),
        ])
    }

    /// `Q = diag(q_angle·1_N, q_velocity·1_N, q_disturbance·1_N)` for `NA = 3N` states.
    pub fn process_noise<const NA: usize>(&self) -> SMatrix<f64, NA, NA> {
        diag3(self.q_angle, self.q_velocity, self.q_disturbance)
    }

    /// `P0 = diag(p0_angle·1_N, p0_velocity·1_N, p0_disturbance·1_N)` for `NA = 3N` states.
    pub fn initial_covariance<const NA: usize>(&self) -> SMatrix<f64, NA, NA> {
        diag3(self.p0_angle, self.p0_velocity, self.p0_disturbance)
    }

    /// `R = diag(r_angle·1_N, r_velocity·1_N)` for `NY = 2N` outputs.
    pub fn measurement_noise<const NY: usize>(&self) -> SMatrix<f64, NY, NY> {
        let n = NY / 2;
        SMatrix::from_diagonal(&SVector::from_fn(|i, _| {
            if i < n {
                self.r_angle
            } else {
                self.r_velocity
            }
        }))
    }
}

/// Diagonal matrix with three equal blocks of size `NA / 3`.
fn diag3<const NA: usize>(a: f64, b: f64, c: f64) -> SMatrix<f64, NA, NA> {
    let n = NA / 3;
    SMatrix::from_diagonal(&SVector::from_fn(|i, _| match i / n.max(1) {
        0 => a,
        1 => b,
        _ => c,
    }))
}

/// Timing, innovation mode and probability parameters shared by the scenario filters
/// (MODEL.md §7-8, paper eqs. 10-11).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatorOptions {
    /// Control / filter period `dt` (s), > 0. Default 0.01 (MODEL.md §7).
    pub dt: f64,
    /// RK4 steps per period in the filter's prediction, ≥ 1. Default 1 (MODEL.md §7).
    pub substeps: usize,
    /// Innovation entering eq. 10. Default [`Innovation::Standard`] (MODEL.md §8).
    pub innovation: Innovation,
    /// Convergence constant `c1` of eq. 10, > 0. Default 100 (paper Table 1).
    pub c1: f64,
    /// Probability floor of eq. 11, in `[0, 1/N_scenarios)`. Default 1e-4.
    pub floor: f64,
}

impl Default for EstimatorOptions {
    fn default() -> Self {
        Self {
            dt: 0.01,
            substeps: 1,
            innovation: Innovation::Standard,
            c1: 100.0,
            floor: 1e-4,
        }
    }
}

impl EstimatorOptions {
    /// Check the ranges for a bank of `scenarios` filters.
    pub fn validate(&self, scenarios: usize) -> Result<(), EstimateError> {
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(EstimateError::InvalidSetting(
                "dt",
                "must be finite and > 0",
            ));
        }
        if self.substeps == 0 {
            return Err(EstimateError::InvalidSetting("substeps", "must be >= 1"));
        }
        if !(self.c1.is_finite() && self.c1 > 0.0) {
            return Err(EstimateError::InvalidSetting(
                "c1",
                "must be finite and > 0",
            ));
        }
        if !(self.floor.is_finite() && self.floor >= 0.0 && self.floor * (scenarios as f64) < 1.0) {
            return Err(EstimateError::InvalidSetting(
                "floor",
                "must be in [0, 1/number of scenarios)",
            ));
        }
        Ok(())
    }
}
