//! The human's desired joint trajectories (MODEL.md §6), with exact time derivatives obtained by
//! second-order dual numbers (`num_dual::second_derivative`).

use crate::check::{real as check, InvalidField, Range};
#[cfg(not(feature = "std"))]
use crate::math::{second_derivative, Dual2};
use crate::model::Real;
use core::f64::consts::PI;
use nalgebra::SVector;
#[cfg(feature = "std")]
use num_dual::{second_derivative, Dual2};
use serde::{Deserialize, Serialize};

/// A desired trajectory `q_d(t)` with velocity and acceleration.
pub trait Trajectory<const N: usize> {
    /// `q_d(t)` generic over the scalar type (so derivatives are exact).
    fn position<T: Real>(&self, t: T) -> SVector<T, N>;

    /// `(q_d, qd_d, qdd_d)` at `t`, derivatives exact.
    fn eval(&self, t: f64) -> (SVector<f64, N>, SVector<f64, N>, SVector<f64, N>) {
        let mut q = SVector::zeros();
        let mut qd = SVector::zeros();
        let mut qdd = SVector::zeros();
        for i in 0..N {
            let (f, d1, d2) = second_derivative(|s: Dual2<f64>| self.position(s)[i], t);
            q[i] = f;
            qd[i] = d1;
            qdd[i] = d2;
        }
        (q, qd, qdd)
    }
}

/// Swing-like hip/knee trajectory of variable frequency and amplitude (MODEL.md §6, 2-DOF).
///
/// Its fields are the parametric keys of the scenario's `[trajectory]` table (see
/// [`Gait`](super::Gait), which embeds this struct); [`SwingTrajectory::validate`] states their
/// ranges.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SwingTrajectory {
    /// Mean frequency (Hz), default 0.8.
    pub base_frequency_hz: f64,
    /// Frequency swing amplitude (Hz), default 0.2.
    pub frequency_swing_hz: f64,
    /// Period of the frequency swing (s), default 15.
    pub frequency_period_s: f64,
    /// Hip offset (rad), default 0.10.
    pub hip_offset: f64,
    /// Mean hip amplitude (rad), default 0.30.
    pub hip_amplitude: f64,
    /// Hip amplitude swing (rad), default 0.05.
    pub hip_amplitude_swing: f64,
    /// Period of the hip amplitude swing (s), default 10.
    pub hip_amplitude_period_s: f64,
    /// Mean knee amplitude (rad), default 1.00.
    pub knee_amplitude: f64,
    /// Knee amplitude swing (rad), default 0.15.
    pub knee_amplitude_swing: f64,
    /// Period of the knee amplitude swing (s), default 7.
    pub knee_amplitude_period_s: f64,
    /// Knee phase lag (rad), default π/3.
    pub knee_phase: f64,
}

impl Default for SwingTrajectory {
    fn default() -> Self {
        SwingTrajectory {
            base_frequency_hz: 0.8,
            frequency_swing_hz: 0.2,
            frequency_period_s: 15.0,
            hip_offset: 0.10,
            hip_amplitude: 0.30,
            hip_amplitude_swing: 0.05,
            hip_amplitude_period_s: 10.0,
            knee_amplitude: 1.00,
            knee_amplitude_swing: 0.15,
            knee_amplitude_period_s: 7.0,
            knee_phase: PI / 3.0,
        }
    }
}

impl SwingTrajectory {
    /// Checks every field: finite, periods and the base frequency `> 0`, amplitudes `>= 0`,
    /// `frequency_swing_hz` in `[0, base_frequency_hz)` (so the frequency stays positive).
    /// The error names the field as in the `[trajectory]` table (`hip_amplitude`).
    pub fn validate(&self) -> Result<(), InvalidField> {
        use Range::*;
        check("base_frequency_hz", self.base_frequency_hz, Pos)?;
        check(
            "frequency_swing_hz",
            self.frequency_swing_hz,
            ClosedOpen(0.0, self.base_frequency_hz),
        )?;
        check("frequency_period_s", self.frequency_period_s, Pos)?;
        check("hip_offset", self.hip_offset, Any)?;
        check("hip_amplitude", self.hip_amplitude, NonNeg)?;
        check("hip_amplitude_swing", self.hip_amplitude_swing, NonNeg)?;
        check("hip_amplitude_period_s", self.hip_amplitude_period_s, Pos)?;
        check("knee_amplitude", self.knee_amplitude, NonNeg)?;
        check("knee_amplitude_swing", self.knee_amplitude_swing, NonNeg)?;
        check("knee_amplitude_period_s", self.knee_amplitude_period_s, Pos)?;
        check("knee_phase", self.knee_phase, Any)
    }
}

impl Trajectory<2> for SwingTrajectory {
    /// `q_d1 = offset + a_h(t) sin φ(t)`, `q_d2 = −a_k(t) (1 − cos(φ(t) − phase)) / 2` with
    /// `φ(t) = 2π (f0 t + fs Tf/(2π) (1 − cos(2π t / Tf)))` (MODEL.md §6).
    fn position<T: Real>(&self, t: T) -> SVector<T, 2> {
        let w = 2.0 * PI / self.frequency_period_s;
        let phi = (t * self.base_frequency_hz
            + (T::one() - (t * w).cos()) * (self.frequency_swing_hz / w))
            * (2.0 * PI);
        let ah = (t * (2.0 * PI / self.hip_amplitude_period_s)).sin() * self.hip_amplitude_swing
            + self.hip_amplitude;
        let ak = (t * (2.0 * PI / self.knee_amplitude_period_s)).sin() * self.knee_amplitude_swing
            + self.knee_amplitude;
        let q1 = ah * phi.sin() + self.hip_offset;
        let q2 = -(ak * (T::one() - (phi - self.knee_phase).cos())) * 0.5;
        SVector::<T, 2>::new(q1, q2)
    }
}

/// 1-DOF knee trajectory `q_d(t) = −A (1 − cos(2π f t))` (MODEL.md §6, paper §4.2).
///
/// In the scenario's `[trajectory]` table its fields are the keys `one_dof_amplitude` and
/// `one_dof_frequency_hz` (see [`Gait`](super::Gait)).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct KneeTrajectory {
    /// Amplitude `A` (rad), >= 0; default 0.6.
    #[serde(rename = "one_dof_amplitude")]
    pub amplitude: f64,
    /// Frequency `f` (Hz), > 0; default 0.5.
    #[serde(rename = "one_dof_frequency_hz")]
    pub frequency_hz: f64,
}

impl Default for KneeTrajectory {
    fn default() -> Self {
        KneeTrajectory {
            amplitude: 0.6,
            frequency_hz: 0.5,
        }
    }
}

impl KneeTrajectory {
    /// Checks `one_dof_amplitude` (finite, `>= 0`) and `one_dof_frequency_hz` (finite, `> 0`).
    pub fn validate(&self) -> Result<(), InvalidField> {
        check("one_dof_amplitude", self.amplitude, Range::NonNeg)?;
        check("one_dof_frequency_hz", self.frequency_hz, Range::Pos)
    }
}

impl Trajectory<1> for KneeTrajectory {
    fn position<T: Real>(&self, t: T) -> SVector<T, 1> {
        SVector::<T, 1>::new(
            -(T::one() - (t * (2.0 * PI * self.frequency_hz)).cos()) * self.amplitude,
        )
    }
}
