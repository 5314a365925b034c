//! Gains of the human-intent estimate (paper eqs. 5-6): fixed numbers (`K = k·I`, the paper's)
//! or derived from the strap stiffness (`k1 = "auto"`, `K = (κ / ks)·I`; docs/MODEL.md §4, §8).
//!
//! The strap force is `F = ks J (q_H − q_R) + cs J (qd_H − qd_R)` (paper eqs. 3-4), so the
//! intent loop `q̂_H = q_R + K1 F` has the gain `K1 ks J`: with a fixed `K1` it is right for one
//! strap stiffness only (the paper's 0.005 rad/N at 937.5 N/m gives 1.31 on the thigh and 0.75
//! on the knee; straps twice as stiff double it, and the loop rings through the sensor filter's
//! delay; straps half as stiff halve it and the robot lags the person). `"auto"` divides by the
//! configured stiffness, `K = (κ / ks)·I`, which keeps the loop gain `κ J` of the default
//! straps at any stiffness; `κ1 = 0.005 × 937.5 rad/m` reproduces the paper's gains on its
//! straps. (The full inverse `K1 = κ (ks J)⁻¹`, which also equalises the joints' loop gains,
//! was measured and not kept: docs/ROBUSTNESS.md §4.)

use crate::model::Straps;
use alloc::{format, string::String};
use nalgebra::SVector;

/// `κ1` (rad/m) of `k1 = "auto"`: `K1 = κ1 / ks`; the paper's 0.005 rad/N at its default
/// 937.5 N/m straps.
pub const AUTO_K1_PER_STIFFNESS: f64 = 4.6875;

/// `κ2` (rad/(m·s)) of `k2 = "auto"`: `K2 = κ2 / ks`; the paper's 0.05 rad/(N·s) at 937.5 N/m.
pub const AUTO_K2_PER_STIFFNESS: f64 = 46.875;

/// One gain of the intent estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum IntentGain {
    /// `K = k·I` (the paper's diagonal gain; rad/N for K1, rad/(N·s) for K2).
    Fixed(f64),
    /// `K = (κ / ks)·I` with the prediction model's strap stiffness `ks` (κ in rad/m for K1,
    /// rad/(m·s) for K2).
    PerStiffness(f64),
}

impl IntentGain {
    /// The scalar gain `k` of `K = k·I` for straps `straps` (0 if `ks` is not positive).
    #[inline]
    pub fn value<const N: usize>(&self, straps: &Straps<N>) -> f64 {
        match *self {
            IntentGain::Fixed(k) => k,
            IntentGain::PerStiffness(kappa) if straps.stiffness > 0.0 => kappa / straps.stiffness,
            IntentGain::PerStiffness(_) => 0.0,
        }
    }

    /// `K F` for straps `straps`.
    #[inline]
    pub fn apply<const N: usize>(
        &self,
        straps: &Straps<N>,
        f: &SVector<f64, N>,
    ) -> SVector<f64, N> {
        f * self.value(straps)
    }
}

/// A configured intent gain (`controller.k1`, `controller.k2`): a number (the paper's fixed
/// `K = k·I`) or `"auto"` (derived from the strap stiffness, [`IntentGain::PerStiffness`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "GainToml", into = "GainToml")]
pub enum GainSetting {
    /// A fixed gain `k` (`K = k·I`).
    Value(f64),
    /// `"auto"`: `K = (κ / ks)·I` with [`AUTO_K1_PER_STIFFNESS`] or [`AUTO_K2_PER_STIFFNESS`].
    Auto,
}

impl GainSetting {
    /// The fixed number, `None` for `"auto"`.
    pub fn value(&self) -> Option<f64> {
        match *self {
            GainSetting::Value(v) => Some(v),
            GainSetting::Auto => None,
        }
    }

    /// The estimator gain; `kappa` is the `κ` used for `"auto"`.
    pub fn gain(&self, kappa: f64) -> IntentGain {
        match *self {
            GainSetting::Value(v) => IntentGain::Fixed(v),
            GainSetting::Auto => IntentGain::PerStiffness(kappa),
        }
    }
}

impl From<f64> for GainSetting {
    fn from(v: f64) -> Self {
        GainSetting::Value(v)
    }
}

/// TOML form of [`GainSetting`]: a number or the word `auto`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(untagged)]
enum GainToml {
    Number(f64),
    Word(String),
}

impl TryFrom<GainToml> for GainSetting {
    type Error = String;
    fn try_from(t: GainToml) -> Result<Self, String> {
        match t {
            GainToml::Number(v) => Ok(GainSetting::Value(v)),
            GainToml::Word(w) if w == "auto" => Ok(GainSetting::Auto),
            GainToml::Word(w) => Err(format!(
                "invalid value `{w}`: expected a number >= 0 or \"auto\" (gain from the strap stiffness)"
            )),
        }
    }
}

impl From<GainSetting> for GainToml {
    fn from(g: GainSetting) -> Self {
        match g {
            GainSetting::Value(v) => GainToml::Number(v),
            GainSetting::Auto => GainToml::Word("auto".into()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straps(ks: f64) -> Straps<2> {
        Straps::two_dof(0.28, 0.16, ks, ks / 10.0)
    }

    #[test]
    fn auto_gains_are_the_papers_at_its_straps_and_scale_with_one_over_stiffness() {
        let (k1, k2) = (
            GainSetting::Auto.gain(AUTO_K1_PER_STIFFNESS),
            GainSetting::Auto.gain(AUTO_K2_PER_STIFFNESS),
        );
        // Bit for bit the paper's 0.005 / 0.05 at 937.5 N/m.
        assert_eq!(k1.value(&straps(937.5)), 0.005);
        assert_eq!(k2.value(&straps(937.5)), 0.05);
        for ks in [468.75, 1875.0, 3000.0] {
            // The loop gain K1 ks J (and K2 ks J) does not change with the stiffness.
            let s = straps(ks);
            assert!((k1.value(&s) * ks - 0.005 * 937.5).abs() < 1e-12, "{ks}");
            assert!((k2.value(&s) * ks - 0.05 * 937.5).abs() < 1e-12, "{ks}");
        }
        assert_eq!(k1.value(&straps(0.0)), 0.0);
        let f = SVector::<f64, 2>::new(10.0, -4.0);
        assert_eq!(k1.apply(&straps(1875.0), &f), f * 0.0025);
        assert_eq!(
            IntentGain::Fixed(0.007).apply(&straps(1875.0), &f),
            f * 0.007
        );
    }
}
