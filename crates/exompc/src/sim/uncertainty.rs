//! Plant uncertainties of paper §4.1 (MODEL.md §5): mass perturbation, lumped disturbance,
//! measurement noise, human mass ramp.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Which uncertainties act on the plant and how large the noise is.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    /// Add `m_dis(t)` to each robot link's mass.
    pub mass_perturbation: bool,
    /// Apply the lumped disturbance `D(t)` on each joint.
    pub disturbance: bool,
    /// Velocity noise amplitude (rad/s), default 1e-4.
    pub velocity_noise: f64,
    /// Strap force noise amplitude (N), default 1e-3.
    pub force_noise: f64,
    /// Noise angular frequency (rad/s), default 100.
    pub noise_frequency: f64,
}

impl Default for Uncertainty {
    fn default() -> Self {
        Uncertainty {
            mass_perturbation: true,
            disturbance: true,
            velocity_noise: 1e-4,
            force_noise: 1e-3,
            noise_frequency: 100.0,
        }
    }
}

impl Uncertainty {
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
