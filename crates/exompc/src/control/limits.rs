//! Hard torque and torque-rate limits (paper eqs. 8-9).

use nalgebra::SVector;

/// A torque limit outside its allowed range (from [`TorqueLimits::validate`]).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("invalid torque limit `{field}` = {value}: allowed range is {allowed}")]
pub struct LimitsError {
    /// Name of the offending limit (`torque_max` or `torque_rate`).
    pub field: &'static str,
    /// The rejected value.
    pub value: f64,
    /// Human-readable description of the allowed range.
    pub allowed: &'static str,
}

/// `|T| ≤ max` and `|T − T_prev| ≤ rate` on every joint (paper eqs. 8-9, MODEL.md §8).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TorqueLimits {
    /// Torque magnitude limit `T_max` (N·m), default 30.
    pub max: f64,
    /// Torque change limit per control period `ΔT_max` (N·m), default 1000 N·m/s × 0.01 s = 10.
    pub rate: f64,
}

impl TorqueLimits {
    /// Check the limits: both finite and `> 0`. Controllers check this in their constructors;
    /// `admissible`/`clamp` never panic, but only valid limits give meaningful torques.
    pub fn validate(&self) -> Result<(), LimitsError> {
        for (field, value) in [("torque_max", self.max), ("torque_rate", self.rate)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(LimitsError {
                    field,
                    value,
                    allowed: "finite, > 0",
                });
            }
        }
        Ok(())
    }

    /// `t` brought within `±max`, a NaN entry replaced by 0 (a safe starting torque).
    #[inline]
    pub fn admissible<const N: usize>(&self, t: &SVector<f64, N>) -> SVector<f64, N> {
        t.map(|v| {
            if v.is_nan() {
                0.0
            } else {
                v.max(-self.max).min(self.max)
            }
        })
    }

    /// The admissible torque closest to `desired`, given the previous torque `prev`.
    /// A non-finite `desired` entry holds `prev` on that joint; a NaN `prev` entry counts as 0.
    /// The result satisfies both limits exactly whenever `|prev| ≤ max`.
    #[inline]
    pub fn clamp<const N: usize>(
        &self,
        prev: &SVector<f64, N>,
        desired: &SVector<f64, N>,
    ) -> SVector<f64, N> {
        let mut out = *prev;
        for i in 0..N {
            let p = if prev[i].is_nan() {
                0.0
            } else {
                prev[i].max(-self.max).min(self.max)
            };
            let d = if desired[i].is_finite() {
                desired[i]
            } else {
                p
            };
            let lo = (p - self.rate).max(-self.max);
            let hi = (p + self.rate).min(self.max);
            // max/min rather than f64::clamp: never panics, even on invalid limits.
            out[i] = d.max(lo).min(hi);
        }
        out
    }

    /// True when `t` satisfies both limits relative to `prev` (with a tiny tolerance).
    pub fn admits<const N: usize>(&self, prev: &SVector<f64, N>, t: &SVector<f64, N>) -> bool {
        const TOL: f64 = 1e-9;
        (0..N).all(|i| {
            t[i].is_finite()
                && t[i].abs() <= self.max + TOL
                && (t[i] - prev[i]).abs() <= self.rate + TOL
        })
    }
}
