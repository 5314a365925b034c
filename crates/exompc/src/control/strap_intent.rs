//! The robust method's intent estimate from the strap model
//! ([`RobustSettings::intent_estimate`] `= "strap_observer"`).
//!
//! The paper's estimate (eqs. 5-6), `q̂_H = q_R + K1 F̄`, `q̂d_H = qd̄_R + K2 F̄`, reads the
//! angle difference and its rate straight off the strap force. The force is
//! `F = ks J Δq + cs J Δqd` (paper eqs. 3-4, `Δq = q_H − q_R`), so `K1 F` mixes the stretch
//! with its rate (`cs/ks = 0.1 s`: at the gait frequency the rate term is about half the
//! stretch term), `K1 = 0.005 I` gives the knee 0.75 of its stretch and none of the thigh
//! strap's share of the shank strap, and `K2 F` is a velocity guess proportional to the force.
//! On the default scenario the paper's estimate misses the human's knee angle by 0.009 rad RMS
//! (the true stretch is 0.016 rad RMS) and its velocity by 0.13 rad/s RMS (the true stretch
//! rate is 0.09 rad/s RMS).
//!
//! The strap model is a first-order system in the stretch: with `u = (ks J)⁻¹ F`,
//! `Δq + τs Δqd = u`, `τs = cs / ks`. So the stretch is `u` low-passed with time constant
//! `τs`, and its rate `(u − Δq)/τs` — an observer with no gain to tune, exact for the strap
//! model. Fed the filtered force `F̄` (a moving average over the last `w` samples,
//! docs/MODEL.md §5) it returns the window means of the stretch and its rate (the model is
//! linear), so `q̄_R + Δq̄` and `qd̄_R + Δqd̄` are the window means of the human's angle and
//! velocity, whatever the robot did: the robot's own motion does not enter the estimate. The
//! window mean lags by `τ = (w−1)/2·dt`; the estimate is moved forward over it with the
//! human's acceleration `a_H` (the difference of successive window-mean velocities, low-passed
//! at [`RobustSettings::human_bandwidth_hz`]), exactly as the Smith predictor of
//! `control/lag.rs` does for the robot: `q̂_H = q̄_H + τ qd̄_H + (τ² − c₂) a_H`,
//! `q̂d_H = qd̄_H + τ a_H`, `c₂ = dt² (w−1)(2w−1)/12`.
//!
//! The reference velocity of the horizon adds the angle error,
//! `qd_ref = q̂d_H + kv (q̂_H − q_R)` ([`RobustSettings::observer_velocity_gain`], 25/s): the
//! paper's `K2 F̄` did that implicitly (`K2 ks J` ≈ 13/s on the thigh), and without it the NMPC
//! (whose velocity weight `r_d` dominates over its 30 ms horizon) matches the human's velocity
//! but closes an angle error only slowly. `q_R` is the exact encoder angle, so this feedback
//! carries no filter delay. With the observer the NMPC starts from the EKF bank's lag-free
//! velocity (`control/multistage.rs`), as in the filter-aware mode.
//!
//! Each scenario uses its own strap model (`Jᵢ`, `ksᵢ`, `csᵢ`). Allocation-free after
//! [`StrapIntent::new`].
//!
//! [`RobustSettings::observer_velocity_gain`]: super::robust::RobustSettings::observer_velocity_gain
//!
//! [`RobustSettings::intent_estimate`]: super::robust::RobustSettings::intent_estimate
//! [`RobustSettings::human_bandwidth_hz`]: super::robust::RobustSettings::human_bandwidth_hz

use super::lag::{ForceLag, LowPassAcceleration};
use super::Measurement;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::Straps;
use alloc::vec::Vec;
use nalgebra::{SMatrix, SVector};

/// One scenario's strap observer.
#[derive(Clone, Debug)]
struct Observer<const N: usize> {
    /// `(ks J)⁻¹`; `None` when the strap model cannot be inverted (the paper's estimate is
    /// then kept for this scenario).
    inverse: Option<SMatrix<f64, N, N>>,
    /// `τs = cs / ks` (s) and the step coefficients of the first-order hold.
    tau: f64,
    decay: f64,
    ramp: f64,
    /// Window-mean stretch `Δq̄` and rate `Δqd̄`, the last `u`.
    stretch: SVector<f64, N>,
    rate: SVector<f64, N>,
    u_prev: SVector<f64, N>,
    /// The human acceleration: the window-mean human velocity differenced and low-passed.
    acc: LowPassAcceleration<N>,
}

impl<const N: usize> Observer<N> {
    fn new(straps: &Straps<N>, dt: f64, bandwidth_hz: f64) -> Self {
        let ks = straps.stiffness;
        let inverse = if ks > 0.0 && ks.is_finite() {
            (straps.j * ks)
                .try_inverse()
                .filter(|m| m.iter().all(|v| v.is_finite()))
        } else {
            None
        };
        let tau = if ks > 0.0 {
            (straps.damping / ks).max(0.0)
        } else {
            0.0
        };
        // x(k) = a x(k−1) + (1 − a) u(k−1) + (u(k) − u(k−1)) (1 − τ (1 − a)/dt): exact for
        // a `u` linear between the samples.
        let (decay, ramp) = if tau > 0.0 {
            let a = (-dt / tau).exp();
            (a, 1.0 - tau * (1.0 - a) / dt)
        } else {
            (0.0, 1.0)
        };
        Observer {
            inverse,
            tau,
            decay,
            ramp,
            stretch: SVector::zeros(),
            rate: SVector::zeros(),
            u_prev: SVector::zeros(),
            acc: LowPassAcceleration::new(dt, bandwidth_hz),
        }
    }
}

/// The strap-model intent observer of the module documentation, one per scenario.
#[derive(Clone, Debug)]
pub(crate) struct StrapIntent<const N: usize> {
    /// The encoder angles' window mean (the sensor filter's window).
    angles: ForceLag<N>,
    observers: Vec<Observer<N>>,
    dt: f64,
    started: bool,
    /// Gain (1/s) of the angle error in the reference velocity.
    kv: f64,
}

impl<const N: usize> StrapIntent<N> {
    /// Observers for the scenarios' strap models `straps`, a `window`-sample sensor filter at
    /// period `dt` (s), the human acceleration low-passed at `bandwidth_hz` (> 0), and the
    /// reference velocity's angle-error gain `velocity_gain` (1/s, >= 0).
    pub(crate) fn new<'a>(
        straps: impl Iterator<Item = &'a Straps<N>>,
        window: usize,
        dt: f64,
        bandwidth_hz: f64,
        velocity_gain: f64,
    ) -> Self {
        StrapIntent {
            angles: ForceLag::new(window, dt, bandwidth_hz),
            observers: straps.map(|s| Observer::new(s, dt, bandwidth_hz)).collect(),
            dt,
            started: false,
            kv: velocity_gain,
        }
    }

    /// Advance every observer with the filtered measurement `m`; `gap` restarts them (first
    /// sample, or periods skipped): the stretch is then taken as `u` and its rate as zero.
    pub(crate) fn update(&mut self, m: &Measurement<N>, gap: bool) {
        let restart = gap || !self.started;
        if restart {
            self.angles.reset();
            self.started = true;
        }
        self.angles.push(&m.q);
        for o in &mut self.observers {
            let Some(inv) = o.inverse else { continue };
            let u = inv * m.force;
            if restart {
                o.stretch = u;
                o.rate = SVector::zeros();
                o.acc.reset();
            } else if o.tau > 0.0 {
                o.stretch =
                    o.stretch * o.decay + o.u_prev * (1.0 - o.decay) + (u - o.u_prev) * o.ramp;
                o.rate = (u - o.stretch) / o.tau;
            } else {
                o.rate = (u - o.u_prev) / self.dt;
                o.stretch = u;
            }
            o.u_prev = u;
            o.acc.push(&(m.qd + o.rate));
        }
    }

    /// The horizon's human reference `(q̂_H, q̂d_H + kv (q̂_H − q_R))` of scenario `i` for the
    /// measurement `m` last passed to [`Self::update`]; `None` when its strap model cannot be
    /// inverted, or before the first update.
    pub(crate) fn estimate(
        &self,
        i: usize,
        m: &Measurement<N>,
    ) -> Option<(SVector<f64, N>, SVector<f64, N>)> {
        let o = self.observers.get(i)?;
        o.inverse?;
        if !self.started {
            return None;
        }
        let (q_mean, _) = self.angles.mean();
        let (tau, k2) = self.angles.lag_coefficients();
        let (vh, acc) = (m.qd + o.rate, o.acc.value());
        let q_h = q_mean + o.stretch + vh * tau + acc * k2;
        let qd_h = vh + acc * tau + (q_h - m.q) * self.kv;
        Some((q_h, qd_h))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straps() -> Straps<2> {
        Straps::two_dof(0.28, 0.16, 937.5, 93.7)
    }

    /// Human and robot move smoothly; the filtered measurement is the moving average of the
    /// exact signals. The observer must return the human's angle and velocity closely, for
    /// any robot motion.
    fn track(window: usize, robot_wiggle: f64) -> (f64, f64) {
        let dt = 0.01;
        let s = straps();
        let mut si = StrapIntent::new(std::iter::once(&s), window, dt, 3.0, 0.0);
        let human = |t: f64| {
            SVector::<f64, 2>::new(0.3 * (5.0 * t).sin(), -0.5 * (1.0 - (5.0 * t - 1.0).cos()))
        };
        let human_v =
            |t: f64| SVector::<f64, 2>::new(1.5 * (5.0 * t).cos(), -2.5 * (5.0 * t - 1.0).sin());
        // The robot lags and wiggles at 4 Hz on its own.
        let w = 2.0 * std::f64::consts::PI * 4.0;
        let robot = |t: f64| human(t - 0.02) + SVector::repeat(robot_wiggle * (w * t).sin());
        let robot_v =
            |t: f64| human_v(t - 0.02) + SVector::repeat(robot_wiggle * w * (w * t).cos());
        let mut hist: Vec<(SVector<f64, 2>, SVector<f64, 2>)> = Vec::new();
        let (mut eq, mut ev) = (0.0f64, 0.0f64);
        for k in 0..400 {
            let t = k as f64 * dt;
            let f = s.force(&(human(t) - robot(t)), &(human_v(t) - robot_v(t)));
            hist.push((robot_v(t), f));
            let n = hist.len().min(window);
            let tail = &hist[hist.len() - n..];
            let qd = tail.iter().map(|x| x.0).sum::<SVector<f64, 2>>() / n as f64;
            let force = tail.iter().map(|x| x.1).sum::<SVector<f64, 2>>() / n as f64;
            let m = Measurement {
                t,
                q: robot(t),
                qd,
                force,
            };
            si.update(&m, k == 0);
            let (qh, qdh) = si.estimate(0, &m).unwrap();
            if k > 100 {
                eq = eq.max((qh - human(t)).amax());
                ev = ev.max((qdh - human_v(t)).amax());
            }
        }
        (eq, ev)
    }

    #[test]
    fn observer_recovers_the_human_without_the_robots_motion() {
        // No filter: the strap model alone (first-order-hold error only).
        let (eq, ev) = track(1, 0.0);
        assert!(eq < 2e-5 && ev < 2e-4, "{eq} {ev}");
        // A 4 Hz robot wiggle of 0.05 rad (1.26 rad/s) does not enter the estimate: what is left
        // is the first-order hold's error, 1 % of the wiggle.
        let (eq_w, ev_w) = track(1, 0.05);
        assert!(eq_w < 5e-4 && ev_w < 5e-3, "{eq_w} {ev_w}");
        // Behind a 9-sample moving average the window mean is moved forward over its 40 ms lag
        // with the low-passed acceleration: a few per cent of the wiggle, not the wiggle.
        let (eq9, ev9) = track(9, 0.05);
        assert!(eq9 < 3e-3 && ev9 < 0.2, "{eq9} {ev9}");
    }

    #[test]
    fn steady_stretch_is_exact_and_a_bad_strap_model_gives_none() {
        let dt = 0.01;
        let s = straps();
        let mut si = StrapIntent::new(std::iter::once(&s), 5, dt, 3.0, 0.0);
        let dq = SVector::<f64, 2>::new(0.01, -0.02);
        let q = SVector::<f64, 2>::new(0.1, -0.3);
        let m = Measurement {
            t: 0.0,
            q,
            qd: SVector::zeros(),
            force: s.force(&dq, &SVector::zeros()),
        };
        for _ in 0..50 {
            si.update(&m, false);
        }
        let (qh, qdh) = si.estimate(0, &m).unwrap();
        assert!((qh - (q + dq)).amax() < 1e-12 && qdh.amax() < 1e-9);
        let slack = Straps::two_dof(0.28, 0.16, 0.0, 93.7);
        let mut bad = StrapIntent::new(std::iter::once(&slack), 5, dt, 3.0, 0.0);
        bad.update(&m, true);
        assert!(bad.estimate(0, &m).is_none());
    }
}
