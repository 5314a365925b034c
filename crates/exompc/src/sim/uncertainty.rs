//! Plant uncertainties of paper §4.1 (MODEL.md §5): mass perturbation, lumped disturbance,
//! measurement noise, human mass ramp.

use crate::check::{self, InvalidField, Range};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use core::f64::consts::PI;
use serde::{Deserialize, Serialize};

/// Upper bound on any payload (kg) a scenario accepts (`[uncertainty] payload_kg`, the
/// multi-stage scenarios' payloads).
pub const MAX_PAYLOAD_KG: f64 = 20.0;

/// `[uncertainty]`: which uncertainties act on the plant and how large the measurement noise
/// is (MODEL.md §5, paper §4.1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Uncertainty {
    /// True payload m_p at the middle of the robot shank (kg), in [0, 20]; unknown to the
    /// controller (MODEL.md §3, §5). Default 0.
    pub payload_kg: f64,
    /// Enable `m_dis(t) = 0.05 sin(t) + 0.01 sin(100 t + pi/4)` kg on each robot link (MODEL.md §5).
    pub mass_perturbation: bool,
    /// Enable the lumped joint disturbance `D(t) = 0.1 sin(t) + 0.05 sin(100 t + pi/2)` N·m (MODEL.md §5).
    pub disturbance: bool,
    /// Enable the linear human body-mass ramp of the 2-DOF run (MODEL.md §2).
    pub human_mass_ramp: bool,
    /// Velocity measurement noise amplitude (rad/s), >= 0: `a sin(w t)` (MODEL.md §5). Default 1e-4.
    pub velocity_noise: f64,
    /// Strap force measurement noise amplitude (N), >= 0 (MODEL.md §5). Default 1e-3.
    pub force_noise: f64,
    /// Angular frequency w of the measurement noise (rad/s), >= 0 (MODEL.md §5). Default 100.
    pub noise_frequency: f64,
    /// Moving-average window on measured velocities and forces (samples), 1..=100 (MODEL.md §5). Default 5.
    pub filter_window: usize,
}

impl Default for Uncertainty {
    fn default() -> Self {
        Self {
            payload_kg: 0.0,
            mass_perturbation: true,
            disturbance: true,
            human_mass_ramp: true,
            velocity_noise: 1e-4,
            force_noise: 1e-3,
            noise_frequency: 100.0,
            filter_window: 5,
        }
    }
}

impl Uncertainty {
    /// Checks the payload (in [0, [`MAX_PAYLOAD_KG`]]), the noise amplitudes and frequency
    /// (finite, >= 0) and the filter window (1..=100); the error names the key.
    pub fn validate(&self) -> Result<(), InvalidField> {
        check::reals(&[
            (
                "payload_kg",
                self.payload_kg,
                Range::Closed(0.0, MAX_PAYLOAD_KG),
            ),
            ("velocity_noise", self.velocity_noise, Range::NonNeg),
            ("force_noise", self.force_noise, Range::NonNeg),
            ("noise_frequency", self.noise_frequency, Range::NonNeg),
        ])?;
        check::int("filter_window", self.filter_window, 1, 100)
    }

    /// `m_dis(t) = 0.05 sin(t) + 0.01 sin(100 t + π/4)` kg (MODEL.md §5), or 0 when off.
    #[inline]
    pub fn mass_perturbation(&self, t: f64) -> f64 {
        if self.mass_perturbation {
            0.05 * t.sin() + 0.01 * (100.0 * t + PI / 4.0).sin()
        } else {
            0.0
        }
    }

    /// `D(t) = 0.1 sin(t) + 0.05 sin(100 t + π/2)` N·m on each joint (left side of eq. 1).
    #[inline]
    pub fn disturbance(&self, t: f64) -> f64 {
        if self.disturbance {
            0.1 * t.sin() + 0.05 * (100.0 * t + PI / 2.0).sin()
        } else {
            0.0
        }
    }

    /// Velocity noise sample at `t` (rad/s).
    #[inline]
    pub fn velocity_noise(&self, t: f64) -> f64 {
        self.velocity_noise * (self.noise_frequency * t).sin()
    }

    /// Force noise sample at `t` (N).
    #[inline]
    pub fn force_noise(&self, t: f64) -> f64 {
        self.force_noise * (self.noise_frequency * t).sin()
    }
}
