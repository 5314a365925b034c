//! The safety supervisor's fallback controller: a low-gain *transparent* controller that
//! carries the robot and its (estimated) payload itself, so that the straps carry little.

use super::Measurement;
use crate::model::{RobotModel, Straps};
use nalgebra::{SMatrix, SVector};

/// Settings of the [`Transparent`] fallback controller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FallbackSettings {
    /// Share `α` of the robot's own inertia compensated with its measured acceleration, in
    /// [0, 1). `α < 1` keeps the delayed acceleration feedback stable by the small-gain theorem
    /// (the person carries the remaining `1 − α`). Default 0.85.
    pub inertia_share: f64,
    /// Low-pass cut-off (Hz) of the encoder acceleration. Default 25.
    pub acceleration_cutoff_hz: f64,
    /// Memory (s) of the payload estimate's exponentially weighted least squares. Default 1.
    pub estimate_memory_s: f64,
    /// The payload estimate is kept in `[0, max_payload_kg]`. Default 10.
    pub max_payload_kg: f64,
}

impl Default for FallbackSettings {
    fn default() -> Self {
        FallbackSettings {
            inertia_share: 0.85,
            acceleration_cutoff_hz: 25.0,
            estimate_memory_s: 1.0,
            max_payload_kg: 10.0,
        }
    }
}

/// Transparent fallback controller (used by the supervisor's `fallback` monitor response).
///
/// The robot's own dynamics (paper eq. 1) are compensated with the nominal model plus a point
/// payload of estimated mass `m̂_p` at the configured `robot.payload_position_m`
/// (docs/MODEL.md §3): the inverse dynamics are affine in `m_p`,
/// `τ(q, qd, qdd) = τ₀ + m_p Y`, `Y = τ₁ − τ₀` (the robot with 1 kg minus the bare robot), so
///
/// ```text
/// T = τ₀(q, v, α a) + m̂_p Y(q, v, α a) + friction(v)
/// ```
///
/// with `v`, `a` the velocity and acceleration differentiated from the exact encoder angles (no
/// moving-average delay; `a` low-passed at `acceleration_cutoff_hz`). Gravity, Coriolis and
/// friction are compensated fully, the inertia by the share `α < 1`. There is no intent
/// feed-forward and no force feedback: the straps move the robot, which is made light, so no
/// fast loop runs through the filtered force and its delay.
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
    syy: f64,
    sye: f64,
    mass: f64,
}

impl<const N: usize> Transparent<N> {
    /// From the bare robot model, the robot with a 1 kg payload at the payload position, the
    /// straps, the control period `dt` (s) and the measurement filter window `window` (samples).
    pub fn new(
        bare: RobotModel<N>,
        unit: RobotModel<N>,
        straps: &Straps<N>,
        dt: f64,
        window: usize,
        settings: FallbackSettings,
    ) -> Self {
        let dt = if dt.is_finite() && dt > 0.0 { dt } else { 0.01 };
        Transparent {
            bare,
            unit,
            jt: straps.j.transpose(),
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
            syy: 0.0,
            sye: 0.0,
            mass: 0.0,
        }
    }

    /// The current payload estimate `m̂_p` (kg).
    pub fn payload_estimate(&self) -> f64 {
        self.mass
    }

    /// Restart the estimates (e.g. after a gap in the data); the payload estimate is kept.
    pub fn restart(&mut self) {
        self.nq = 0;
        self.filled = 0;
        self.pos = 0;
        self.prev_strap = None;
        self.acc = SVector::zeros();
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
        self.q = [m.q, self.q[0], self.q[1]];
        self.nq = (self.nq + 1).min(3);
        self.torque = [*applied, self.torque[0]];
        let strap = self.jt * m.force;
        if self.nq == 3 {
            // Central differences at the previous sample k−1.
            let dt = self.dt;
            let v = (self.q[0] - self.q[2]) / (2.0 * dt);
            let a = (self.q[0] - 2.0 * self.q[1] + self.q[2]) / (dt * dt);
            let gamma =
                1.0 - (-2.0 * std::f64::consts::PI * self.s.acceleration_cutoff_hz * dt).exp();
            self.acc += (a - self.acc) * gamma;
            let (t0, y) = self.inverse_dynamics(&self.q[1], &v, &a);
            // The torque over [k−2, k] drove the acceleration at k−1.
            let drive = (self.torque[0] + self.torque[1]) * 0.5;
            let resid = t0 + self.bare.friction_torque(&v) - drive;
            let w = self.ring.len();
            self.ring[self.pos] = (y, resid);
            self.pos = (self.pos + 1) % w;
            self.filled = (self.filled + 1).min(w);
            if let (Some(prev), true) = (self.prev_strap, self.filled == w) {
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
        self.prev_strap = Some(strap);
    }

    /// The fallback torque for the latest observed measurement (before limits).
    pub fn torque(&self) -> SVector<f64, N> {
        let q = self.q[0];
        let v = match self.nq {
            0 | 1 => SVector::zeros(),
            _ => (self.q[0] - self.q[1]) / self.dt + self.acc * (0.5 * self.dt),
        };
        let a = self.acc * self.s.inertia_share.clamp(0.0, 0.99);
        let (t0, y) = self.inverse_dynamics(&q, &v, &a);
        t0 + y * self.mass + self.bare.friction_torque(&v)
    }
}
