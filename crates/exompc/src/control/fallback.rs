//! The safety supervisor's fallback controller: a low-gain *transparent* controller that
//! carries the robot and its (estimated) payload itself, so that the straps carry little.

use super::Measurement;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::{RobotModel, Straps};
use alloc::{vec, vec::Vec};
use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

/// `[monitors.fallback]`: settings of the [`Transparent`] fallback controller.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FallbackSettings {
    /// Share `α` of the robot's inertia compensated along the predicted human acceleration,
    /// in [0, 1]. Default 1.
    pub inertia_share: f64,
    /// Low-pass cut-off (Hz) of the encoder acceleration in the robot's velocity estimate
    /// (Coriolis and friction), > 0. Default 25.
    pub acceleration_cutoff_hz: f64,
    /// Memory (s) of the payload estimate's exponentially weighted least squares, > 0.
    /// Default 1.
    pub estimate_memory_s: f64,
    /// The payload estimate is kept in `[0, max_payload_kg]`, in [0, 20]. Default 10.
    pub max_payload_kg: f64,
    /// Samples (control periods) of the cubic least-squares fit that predicts the human's
    /// motion, in 4..=100. Default 8.
    pub human_window: usize,
    /// How far ahead (s) of the newest human-angle estimate (one period old) the fit is
    /// evaluated, in [0, 0.1]. Default 0.01 (one period: the present).
    pub human_prediction_s: f64,
}

impl Default for FallbackSettings {
    fn default() -> Self {
        FallbackSettings {
            inertia_share: 1.0,
            acceleration_cutoff_hz: 25.0,
            estimate_memory_s: 1.0,
            max_payload_kg: 10.0,
            human_window: 8,
            human_prediction_s: 0.01,
        }
    }
}

impl FallbackSettings {
    /// Polynomial degree of the human-motion fit.
    pub const DEGREE: usize = 3;
    /// Largest `human_window`.
    pub const MAX_WINDOW: usize = 100;

    /// Checks every field against its documented range; the error names the first offending
    /// field (relative to `[monitors.fallback]`), its value and the allowed values.
    pub fn validate(&self) -> Result<(), FallbackSettingsError> {
        // (field, value, zero allowed, upper end, allowed values); every lower end is 0.
        let reals = [
            (
                "inertia_share",
                self.inertia_share,
                true,
                1.0,
                "finite, in [0, 1]",
            ),
            (
                "acceleration_cutoff_hz",
                self.acceleration_cutoff_hz,
                false,
                f64::MAX,
                "finite, > 0",
            ),
            (
                "estimate_memory_s",
                self.estimate_memory_s,
                false,
                f64::MAX,
                "finite, > 0",
            ),
            (
                "max_payload_kg",
                self.max_payload_kg,
                true,
                20.0,
                "finite, in [0, 20]",
            ),
            (
                "human_prediction_s",
                self.human_prediction_s,
                true,
                0.1,
                "finite, in [0, 0.1]",
            ),
        ];
        for (field, value, zero, hi, allowed) in reals {
            let above = value > 0.0 || (zero && value == 0.0);
            if !(value.is_finite() && above && value <= hi) {
                return Err(FallbackSettingsError {
                    field,
                    value,
                    allowed,
                });
            }
        }
        if !(Self::DEGREE + 1..=Self::MAX_WINDOW).contains(&self.human_window) {
            return Err(FallbackSettingsError {
                field: "human_window",
                value: self.human_window as f64,
                allowed: "integer in 4..=100",
            });
        }
        Ok(())
    }
}

/// A [`FallbackSettings`] field outside its range.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("monitors.fallback.{field} = {value}: allowed {allowed}")]
pub struct FallbackSettingsError {
    /// The field's name in `[monitors.fallback]`.
    pub field: &'static str,
    /// Its value.
    pub value: f64,
    /// The allowed values in words.
    pub allowed: &'static str,
}

/// Least-squares weights that give the value's first and second time derivatives at `lead`
/// periods after the newest of `len` samples (newest first) of a polynomial of `degree`
/// fitted to them, in units of 1/period and 1/period².
fn polynomial_weights(len: usize, degree: usize, lead: f64) -> (Vec<f64>, Vec<f64>) {
    let d = degree.min(len.saturating_sub(1));
    let v = nalgebra::DMatrix::<f64>::from_fn(len, d + 1, |i, j| (-(i as f64)).powi(j as i32));
    let vt = v.transpose();
    let pinv = (&vt * &v)
        .try_inverse()
        .map(|m| m * vt)
        .unwrap_or_else(|| nalgebra::DMatrix::zeros(d + 1, len));
    let (mut w1, mut w2) = (vec![0.0; len], vec![0.0; len]);
    for i in 0..len {
        for j in 1..=d {
            let jf = j as f64;
            w1[i] += pinv[(j, i)] * jf * lead.powi(j as i32 - 1);
            if j >= 2 {
                w2[i] += pinv[(j, i)] * jf * (jf - 1.0) * lead.powi(j as i32 - 2);
            }
        }
    }
    (w1, w2)
}

/// Transparent fallback controller (used by the supervisor's `fallback` monitor response).
///
/// It makes the robot follow the person's leg by itself, so that the straps carry little: the
/// robot's inverse dynamics (paper eq. 1) along the *predicted human motion*, with the nominal
/// model plus a point payload of estimated mass `m̂_p` at the configured
/// `robot.payload_position_m` (docs/MODEL.md §3). The inverse dynamics are affine in `m_p`,
/// `τ(q, qd, qdd) = τ₀ + m_p Y`, `Y = τ₁ − τ₀` (the robot with 1 kg minus the bare robot), so
///
/// ```text
/// T = τ₀(q, v, α â_H) + m̂_p Y(q, v, α â_H) + friction(v)
/// ```
///
/// with `q` the encoder angles, `v` the robot velocity differentiated from them (no
/// moving-average delay) and `â_H` the human's joint acceleration predicted for the present.
/// Gravity, Coriolis and friction are compensated fully, the inertia by the share `α`
/// (`inertia_share`, default 1).
///
/// **Human motion without the force filter's delay.** The strap torque at the previous sample
/// follows from the robot's own dynamics (a disturbance observer on the exact encoder angles):
/// `Jᵀ F = M a + C v + G + friction − T̄` (paper eq. 1; `a` the central second difference, `T̄`
/// the torque applied over the two periods around it). Inverting the strap model (paper eqs.
/// 3-4, docs/MODEL.md §4), `ks e + cs ė = (JᵀJ)⁻¹ Jᵀ F` gives the human-robot angle error `e`
/// (integrated exactly for the torque held over each period), and `q̂_H = q_R + e` the human's
/// angles, one period old. A cubic least-squares fit over the last `human_window` of them,
/// evaluated `human_prediction_s` ahead, gives `â_H`. With an exact model the estimate does
/// not depend on the robot's motion (the human's motion is the person's), so no fast loop runs
/// through the robot's delayed acceleration or the filtered force: the prediction error `δ`
/// of the fit drives `M ë + C_s ė + K_s e = −M δ` with the full robot inertia on the straps.
/// Until `human_window` estimates exist (after a start or a restart) only gravity, Coriolis and
/// friction are compensated.
///
/// **Payload estimate.** Paper eq. 1 with the strap torque `Jᵀ F` on the right-hand side gives,
/// per step, `Jᵀ F − (τ₀ + friction − T) = m_p Y + D`. The measured force is a moving average of
/// `w` samples (`uncertainty.filter_window`, docs/MODEL.md §5), so the right-hand quantities are
/// averaged over the same `w` samples before they are compared with it; `m̂_p` is their
/// exponentially weighted least-squares fit (memory `estimate_memory_s`), clamped to
/// `[0, max_payload_kg]`. It runs on every step (the supervisor calls [`Transparent::observe`]),
/// so it is ready when a monitor trips.
///
/// Preallocated in `new`; `observe` and `torque` allocate nothing.
#[derive(Clone, Debug)]
pub struct Transparent<const N: usize> {
    bare: RobotModel<N>,
    unit: RobotModel<N>,
    jt: SMatrix<f64, N, N>,
    /// `(ks JᵀJ)⁻¹`: strap torque to the spring-only angle error.
    strap_inv: SMatrix<f64, N, N>,
    /// Exact step factor `1 − exp(−dt cs/ks)` of the strap's first-order error dynamics.
    strap_step: f64,
    dt: f64,
    s: FallbackSettings,
    /// Last three encoder samples, newest first, and how many are valid.
    q: [SVector<f64, N>; 3],
    nq: usize,
    /// Last two applied torques, newest first.
    torque: [SVector<f64, N>; 2],
    /// Window of (regressor `Y`, residual `τ₀ + friction − T`), aligned with the filtered force.
    ring: Vec<(SVector<f64, N>, SVector<f64, N>)>,
    pos: usize,
    filled: usize,
    /// The previous measurement's filtered strap torque `Jᵀ F̄`.
    prev_strap: Option<SVector<f64, N>>,
    acc: SVector<f64, N>,
    /// Human-robot angle error `e` (None before the first estimate).
    error: Option<SVector<f64, N>>,
    /// Ring of human-angle estimates `q̂_H` (newest at `human_pos − 1`), and how many.
    human: Vec<SVector<f64, N>>,
    human_pos: usize,
    human_filled: usize,
    /// Weights (newest first) of the fit's acceleration at the prediction time.
    human_acc_w: Vec<f64>,
    syy: f64,
    sye: f64,
    mass: f64,
}

impl<const N: usize> Transparent<N> {
    /// From the bare robot model, the robot with a 1 kg payload at the payload position, the
    /// straps, the control period `dt` (s) and the measurement filter window `window` (samples).
    /// Out-of-range settings are brought into range (see [`FallbackSettings::validate`]).
    pub fn new(
        bare: RobotModel<N>,
        unit: RobotModel<N>,
        straps: &Straps<N>,
        dt: f64,
        window: usize,
        settings: FallbackSettings,
    ) -> Self {
        let dt = if dt.is_finite() && dt > 0.0 { dt } else { 0.01 };
        let ks = if straps.stiffness.is_finite() && straps.stiffness > 0.0 {
            straps.stiffness
        } else {
            1.0
        };
        let strap_inv = (straps.j.transpose() * straps.j * ks)
            .try_inverse()
            .unwrap_or_else(SMatrix::zeros);
        let tau = if straps.damping.is_finite() {
            straps.damping.max(0.0) / ks
        } else {
            0.0
        };
        let strap_step = if tau > 0.0 {
            1.0 - (-dt / tau).exp()
        } else {
            1.0
        };
        let len = settings
            .human_window
            .clamp(FallbackSettings::DEGREE + 1, FallbackSettings::MAX_WINDOW);
        let lead = if settings.human_prediction_s.is_finite() {
            settings.human_prediction_s.clamp(0.0, 0.1) / dt
        } else {
            0.0
        };
        let (_, w2) = polynomial_weights(len, FallbackSettings::DEGREE, lead);
        Transparent {
            bare,
            unit,
            jt: straps.j.transpose(),
            strap_inv,
            strap_step,
            dt,
            s: settings,
            q: [SVector::zeros(); 3],
            nq: 0,
            torque: [SVector::zeros(); 2],
            ring: vec![(SVector::zeros(), SVector::zeros()); window.clamp(1, 1024)],
            pos: 0,
            filled: 0,
            prev_strap: None,
            acc: SVector::zeros(),
            error: None,
            human: vec![SVector::zeros(); len],
            human_pos: 0,
            human_filled: 0,
            human_acc_w: w2.iter().map(|w| w / (dt * dt)).collect(),
            syy: 0.0,
            sye: 0.0,
            mass: 0.0,
        }
    }

    /// The current payload estimate `m̂_p` (kg).
    pub fn payload_estimate(&self) -> f64 {
        self.mass
    }

    /// The newest human-angle estimate `q̂_H` (rad, one period old), once one exists.
    pub fn human_angle_estimate(&self) -> Option<SVector<f64, N>> {
        let n = self.human.len();
        (self.human_filled > 0).then(|| self.human[(self.human_pos + n - 1) % n])
    }

    /// Restart the estimates (e.g. after a gap in the data); the payload estimate is kept.
    pub fn restart(&mut self) {
        self.nq = 0;
        self.filled = 0;
        self.pos = 0;
        self.prev_strap = None;
        self.acc = SVector::zeros();
        self.error = None;
        self.human_filled = 0;
        self.human_pos = 0;
    }

    fn inverse_dynamics(
        &self,
        q: &SVector<f64, N>,
        v: &SVector<f64, N>,
        a: &SVector<f64, N>,
    ) -> (SVector<f64, N>, SVector<f64, N>) {
        let (m0, c0, g0) = self.bare.chain.terms(q, v);
        let (m1, c1, g1) = self.unit.chain.terms(q, v);
        let t0 = m0 * a + c0 + g0;
        (t0, m1 * a + c1 + g1 - t0)
    }

    /// Feed one valid measurement and the torque applied over the period that ended with it.
    pub fn observe(&mut self, m: &Measurement<N>, applied: &SVector<f64, N>) {
        if !m.is_finite() || !applied.iter().all(|x| x.is_finite()) {
            return;
        }
        self.observe_inner(m, applied, true);
    }

    /// Feed a measurement whose encoder channels (`q`, `qd`) are valid but whose strap forces
    /// are not (silent, non-finite or at the sensor's range): the torque needs only the
    /// encoders, so the human-motion estimate goes on; the payload estimate, which compares
    /// the measured strap torque with the model, is frozen until forces are valid again.
    pub fn observe_encoders(&mut self, m: &Measurement<N>, applied: &SVector<f64, N>) {
        let finite = |v: &SVector<f64, N>| v.iter().all(|x| x.is_finite());
        if !finite(&m.q) || !finite(&m.qd) || !finite(applied) {
            return;
        }
        self.observe_inner(m, applied, false);
    }

    fn observe_inner(&mut self, m: &Measurement<N>, applied: &SVector<f64, N>, forces: bool) {
        self.q = [m.q, self.q[0], self.q[1]];
        self.nq = (self.nq + 1).min(3);
        self.torque = [*applied, self.torque[0]];
        let strap = if forces {
            self.jt * m.force
        } else {
            SVector::zeros()
        };
        if self.nq == 3 {
            // Central differences at the previous sample k−1.
            let dt = self.dt;
            let v = (self.q[0] - self.q[2]) / (2.0 * dt);
            let a = (self.q[0] - 2.0 * self.q[1] + self.q[2]) / (dt * dt);
            let gamma =
                1.0 - (-2.0 * core::f64::consts::PI * self.s.acceleration_cutoff_hz * dt).exp();
            self.acc += (a - self.acc) * gamma;
            let (t0, y) = self.inverse_dynamics(&self.q[1], &v, &a);
            // The torque over [k−2, k] drove the acceleration at k−1.
            let drive = (self.torque[0] + self.torque[1]) * 0.5;
            let resid = t0 + self.bare.friction_torque(&v) - drive;
            self.observe_human(&(resid + y * self.mass));
            let w = self.ring.len();
            self.ring[self.pos] = (y, resid);
            self.pos = (self.pos + 1) % w;
            self.filled = (self.filled + 1).min(w);
            if let (Some(prev), true, true) = (self.prev_strap, self.filled == w, forces) {
                // The force measured at k−1 averages samples k−w .. k−1: the ring's content.
                let (mut ys, mut rs) = (SVector::<f64, N>::zeros(), SVector::<f64, N>::zeros());
                for (y, r) in &self.ring {
                    ys += y;
                    rs += r;
                }
                let inv = 1.0 / w as f64;
                let (ym, e) = (ys * inv, prev - rs * inv);
                let memory = self.s.estimate_memory_s.max(dt);
                let lambda = (-dt / memory).exp();
                self.syy = lambda * self.syy + ym.norm_squared();
                self.sye = lambda * self.sye + ym.dot(&e);
                if self.syy > 1e-12 {
                    self.mass = (self.sye / self.syy).clamp(0.0, self.s.max_payload_kg.max(0.0));
                }
            }
        }
        self.prev_strap = forces.then_some(strap);
    }

    /// One human-angle estimate at k−1 from the strap torque `strap` the robot's dynamics
    /// imply there: `e` follows `(cs/ks) ė + e = (ks JᵀJ)⁻¹ strap`.
    fn observe_human(&mut self, strap: &SVector<f64, N>) {
        let u = self.strap_inv * strap;
        let e = match self.error {
            Some(e) => e + (u - e) * self.strap_step,
            None => u,
        };
        self.error = Some(e);
        let n = self.human.len();
        self.human[self.human_pos] = self.q[1] + e;
        self.human_pos = (self.human_pos + 1) % n;
        self.human_filled = (self.human_filled + 1).min(n);
    }

    /// The predicted human joint acceleration `â_H` (zero until the fit's window is full).
    fn human_acceleration(&self) -> SVector<f64, N> {
        let n = self.human.len();
        if self.human_filled < n {
            return SVector::zeros();
        }
        let mut a = SVector::<f64, N>::zeros();
        for (i, w) in self.human_acc_w.iter().enumerate() {
            a += self.human[(self.human_pos + n - 1 - i) % n] * *w;
        }
        a
    }

    /// The fallback torque for the latest observed measurement (before limits).
    pub fn torque(&self) -> SVector<f64, N> {
        let q = self.q[0];
        let v = match self.nq {
            0 | 1 => SVector::zeros(),
            _ => (self.q[0] - self.q[1]) / self.dt + self.acc * (0.5 * self.dt),
        };
        let a = self.human_acceleration() * self.s.inertia_share.clamp(0.0, 1.0);
        let (t0, y) = self.inverse_dynamics(&q, &v, &a);
        t0 + y * self.mass + self.bare.friction_torque(&v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fit's weights reproduce the derivatives of any cubic exactly, at any lead.
    #[test]
    fn polynomial_weights_are_exact_on_cubics() {
        let p = |t: f64| 0.3 - 1.2 * t + 0.7 * t * t - 0.05 * t * t * t;
        let d1 = |t: f64| -1.2 + 1.4 * t - 0.15 * t * t;
        let d2 = |t: f64| 1.4 - 0.3 * t;
        for (len, lead) in [(4, 0.0), (8, 1.0), (13, 2.5)] {
            let (w1, w2) = polynomial_weights(len, 3, lead);
            let samples: Vec<f64> = (0..len).map(|i| p(-(i as f64))).collect();
            let a1: f64 = w1.iter().zip(&samples).map(|(w, x)| w * x).sum();
            let a2: f64 = w2.iter().zip(&samples).map(|(w, x)| w * x).sum();
            assert!((a1 - d1(lead)).abs() < 1e-9, "{len} {lead}: {a1}");
            assert!((a2 - d2(lead)).abs() < 1e-9, "{len} {lead}: {a2}");
        }
    }

    #[test]
    fn settings_validate_names_the_field() {
        assert_eq!(FallbackSettings::default().validate(), Ok(()));
        let bad = |f: fn(&mut FallbackSettings)| {
            let mut s = FallbackSettings::default();
            f(&mut s);
            s.validate().unwrap_err().field
        };
        assert_eq!(bad(|s| s.inertia_share = 1.01), "inertia_share");
        assert_eq!(
            bad(|s| s.acceleration_cutoff_hz = 0.0),
            "acceleration_cutoff_hz"
        );
        assert_eq!(
            bad(|s| s.acceleration_cutoff_hz = f64::INFINITY),
            "acceleration_cutoff_hz"
        );
        assert_eq!(bad(|s| s.estimate_memory_s = f64::NAN), "estimate_memory_s");
        assert_eq!(bad(|s| s.max_payload_kg = -0.1), "max_payload_kg");
        assert_eq!(bad(|s| s.human_window = 3), "human_window");
        assert_eq!(bad(|s| s.human_window = 101), "human_window");
        assert_eq!(bad(|s| s.human_prediction_s = 0.2), "human_prediction_s");
    }
}
