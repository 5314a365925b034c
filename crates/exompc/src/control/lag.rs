//! The known measurement filter (a moving average over the last `w` samples of the velocities
//! and strap forces, `docs/MODEL.md §5`) seen from the controller: a Smith predictor on the
//! strap force, and an oscillation detector on the filtered force.
//!
//! The filtered force `F̄(k)` is the mean of `F(k−w+1..k)`. The strap model is linear
//! (`F = ks J (q_H − q_R) + cs J (qd_H − qd_R)`, paper eqs. 3-4), so
//! `F̄ = ks J (q̄_H − q̄_R) + cs J (qd̄_H − qd̄_R)` with the same window means. The robot's own
//! part of the force change since the window's mean time `τ = (w−1)/2·dt` is known from the
//! exact encoder angles and a lag-free velocity, so [`ForceLag::predicted_force`] removes it:
//! `F̂(k) = F̄(k) − ks J (q_R(k) − q̄_R(k) − τ qd̄_R) − cs J (qd_R(k) − qd̄_R)`, assuming the
//! human moved over the window like the robot's filtered motion `qd̄_R` (a smooth human). The
//! robot's response to the controller's own commands then reaches the intent estimate without
//! the filter's delay, the delay that turns the high-gain force loop of eqs. 5-6 into a limit
//! cycle when the prediction model is accurate and the leg heavy.

use super::highpass::HighPass;
use super::Measurement;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::Straps;
use alloc::{vec, vec::Vec};
use nalgebra::SVector;

/// Moving average of the encoder angles over the sensor filter's window and the Smith-predicted
/// strap force. Allocation-free after [`ForceLag::new`].
#[derive(Clone, Debug)]
pub struct ForceLag<const N: usize> {
    buf: Vec<SVector<f64, N>>,
    next: usize,
    len: usize,
    dt: f64,
    /// Low-passed robot acceleration (from the lag-free velocity), the human's acceleration
    /// estimate `a_H`.
    acc: LowPassAcceleration<N>,
}

/// The acceleration of a velocity signal: successive samples differenced and low-passed
/// (first order, `a ← a + γ (Δv/dt − a)`, `γ = 1 − exp(−2π f dt)`). The human acceleration
/// `a_H` of the Smith predictor ([`ForceLag`]) and of the strap observer
/// (`control/strap_intent.rs`).
#[derive(Clone, Debug)]
pub(crate) struct LowPassAcceleration<const N: usize> {
    dt: f64,
    gamma: f64,
    /// Previous velocity (`None` after a restart).
    prev: Option<SVector<f64, N>>,
    acc: SVector<f64, N>,
}

impl<const N: usize> LowPassAcceleration<N> {
    /// For samples `dt` (s) apart, low-passed at `bandwidth_hz` (> 0); starts at zero.
    pub(crate) fn new(dt: f64, bandwidth_hz: f64) -> Self {
        LowPassAcceleration {
            dt,
            gamma: 1.0 - (-2.0 * core::f64::consts::PI * bandwidth_hz * dt).exp(),
            prev: None,
            acc: SVector::zeros(),
        }
    }

    /// Record this period's velocity (the first after a restart only sets the reference).
    pub(crate) fn push(&mut self, v: &SVector<f64, N>) {
        if let Some(p) = self.prev {
            let a = (v - p) / self.dt;
            self.acc += (a - self.acc) * self.gamma;
        }
        self.prev = Some(*v);
    }

    /// Forget the previous velocity, keep the acceleration.
    pub(crate) fn restart(&mut self) {
        self.prev = None;
    }

    /// Forget the previous velocity and the acceleration.
    pub(crate) fn reset(&mut self) {
        self.prev = None;
        self.acc = SVector::zeros();
    }

    /// The low-passed acceleration.
    pub(crate) fn value(&self) -> SVector<f64, N> {
        self.acc
    }
}

impl<const N: usize> ForceLag<N> {
    /// For a `window`-sample moving average (≥ 1; 1 = no filter) at period `dt` (s); the
    /// human's acceleration is the robot's, low-passed at `human_bandwidth_hz` (> 0).
    pub fn new(window: usize, dt: f64, human_bandwidth_hz: f64) -> Self {
        ForceLag {
            buf: vec![SVector::zeros(); window.max(1)],
            next: 0,
            len: 0,
            dt,
            acc: LowPassAcceleration::new(dt, human_bandwidth_hz),
        }
    }

    /// Record the lag-free joint velocity of this period (updates `a_H`).
    pub fn push_velocity(&mut self, qd: &SVector<f64, N>) {
        self.acc.push(qd);
    }

    /// Forget the last velocity (the next [`Self::push_velocity`] starts the acceleration
    /// estimate afresh), e.g. after periods in which no velocity was pushed.
    pub fn restart_velocity(&mut self) {
        self.acc.restart();
    }

    /// The filter window `w` (samples).
    pub fn window(&self) -> usize {
        self.buf.len()
    }

    /// Forget the angle history (first sample, or after a gap in the data).
    pub fn reset(&mut self) {
        self.len = 0;
        self.next = 0;
        self.acc.reset();
    }

    /// Record the encoder angles of this period.
    pub fn push(&mut self, q: &SVector<f64, N>) {
        let w = self.buf.len();
        self.buf[self.next] = *q;
        self.next = (self.next + 1) % w;
        self.len = (self.len + 1).min(w);
    }

    /// Mean `q̄_R` of the recorded angles (zero before the first) and its lag
    /// `τ = (len−1)/2·dt` (s); like the sensor filter, it averages fewer samples at start-up.
    pub fn mean(&self) -> (SVector<f64, N>, f64) {
        if self.len == 0 {
            return (SVector::zeros(), 0.0);
        }
        let w = self.buf.len();
        let mut s = SVector::zeros();
        for i in 0..self.len {
            s += self.buf[(self.next + w - 1 - i) % w];
        }
        (s / self.len as f64, (self.len - 1) as f64 * 0.5 * self.dt)
    }

    /// The constant-acceleration shift of the window mean to the present, `(τ, τ² − c₂)`,
    /// `c₂ = dt² (w−1)(2w−1)/12` over the `w` recorded samples (at least one): a signal whose
    /// window-mean rate is `v̄` and acceleration `a` is `τ v̄ + (τ² − c₂) a` ahead of its mean,
    /// and its rate `τ a` ahead.
    pub fn lag_coefficients(&self) -> (f64, f64) {
        let w = self.len.max(1) as f64;
        let tau = (w - 1.0) * 0.5 * self.dt;
        let c2 = self.dt * self.dt * (w - 1.0) * (2.0 * w - 1.0) / 12.0;
        (tau, tau * tau - c2)
    }

    /// `F̂(k)` of the module documentation, from the filtered measurement `m` (its angles
    /// already [`push`](Self::push)ed) and the lag-free joint velocity `qd_now`.
    pub fn predicted_force(
        &self,
        straps: &Straps<N>,
        m: &Measurement<N>,
        qd_now: &SVector<f64, N>,
    ) -> SVector<f64, N> {
        match self.relative_motion(m, qd_now) {
            Some((dq, dqd)) => m.force - straps.force(&dq, &dqd),
            None => m.force,
        }
    }

    /// The strap stretch and stretch rate `(Δq, Δqd)` whose force the Smith predictor removes,
    /// `F̂(k) = F̄(k) − F(Δq, Δqd)` ([`predicted_force`](Self::predicted_force) for any strap
    /// model, the force being linear in them); `None` before the first angles.
    pub fn relative_motion(
        &self,
        m: &Measurement<N>,
        qd_now: &SVector<f64, N>,
    ) -> Option<(SVector<f64, N>, SVector<f64, N>)> {
        if self.len == 0 {
            return None;
        }
        let (q_mean, _) = self.mean();
        // Constant-acceleration human over the window: q_H(k) − q̄_H = τ qd̄_H + (τ² − c2) a_H,
        // qd_H(k) − qd̄_H = τ a_H, with qd̄_H ≈ qd̄_R.
        let (tau, k2) = self.lag_coefficients();
        let acc = self.acc.value();
        let dq_h = m.qd * tau + acc * k2;
        let dqd_h = acc * tau;
        Some((m.q - q_mean - dq_h, qd_now - m.qd - dqd_h))
    }
}

/// Detects an interaction oscillation in the filtered strap forces: the share of their power
/// above `cutoff_hz` (the second-order Butterworth [`HighPass`] that the supervisor's
/// `OscillationDetector` uses too), averaged exponentially over
/// `window_s`, exceeds `fraction` while the high-frequency RMS exceeds `min_force_n`.
#[derive(Clone, Copy, Debug)]
pub struct HfShareDetector<const N: usize> {
    hp: HighPass<N>,
    beta: f64,
    fraction: f64,
    min_power: f64,
    hp_power: f64,
    total_power: f64,
    started: bool,
}

impl<const N: usize> HfShareDetector<N> {
    /// A detector at period `dt` (s); arguments as in the type documentation.
    pub fn new(dt: f64, cutoff_hz: f64, window_s: f64, fraction: f64, min_force_n: f64) -> Self {
        HfShareDetector {
            hp: HighPass::new(cutoff_hz, dt),
            beta: (dt / window_s).min(1.0),
            fraction,
            min_power: min_force_n * min_force_n,
            hp_power: 0.0,
            total_power: 0.0,
            started: false,
        }
    }

    /// Restart from the next sample (after a gap in the data).
    pub fn reset(&mut self) {
        self.started = false;
        self.hp_power = 0.0;
        self.total_power = 0.0;
    }

    /// Feed one filtered force sample; returns true while an oscillation is detected.
    pub fn push(&mut self, f: &SVector<f64, N>) -> bool {
        if !self.started {
            self.hp.reset();
            self.started = true;
        }
        let hp2 = self.hp.push(f);
        self.hp_power += (hp2.norm_squared() - self.hp_power) * self.beta;
        self.total_power += (f.norm_squared() - self.total_power) * self.beta;
        self.detected()
    }

    /// True while the averaged high-frequency share and level exceed the thresholds.
    pub fn detected(&self) -> bool {
        self.hp_power > self.min_power && self.hp_power > self.fraction * self.total_power
    }

    /// Averaged high-frequency share of the strap-force power (0 before any power).
    pub fn share(&self) -> f64 {
        if self.total_power > 0.0 {
            self.hp_power / self.total_power
        } else {
            0.0
        }
    }
}
