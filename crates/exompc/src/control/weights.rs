//! Smoothed scenario weights of the robust method ([`RobustSettings::weight_smoothing_s`]).
//!
//! The paper's MS-NMPC weights each scenario's cost by the EKF bank's current probability
//! `μᵢ(k)` (paper eq. 12). Where no scenario fits well — a fast gait, a long measurement
//! filter — those posteriors chatter between 0 and 1 from one step to the next, and every
//! switch moves the shared first input toward another scenario's optimum: a torque step of
//! several N·m that the strap forces and the torque-oscillation detector then see as an
//! interaction oscillation (docs/ROBUSTNESS.md, sixth pass). Averaging the weights over a
//! short time turns those switches into a blend; where the bank identifies one scenario
//! steadily (the default scenario) the weights equal the probabilities.
//!
//! [`RobustSettings::weight_smoothing_s`]: super::robust::RobustSettings::weight_smoothing_s

use alloc::{vec, vec::Vec};

/// The probability one scenario must exceed before [`WeightSmoother`] starts low-passing
/// (more than half: that scenario is more likely than all the others together). Any value
/// from 0.35 to 0.99 gives the same standard envelope (docs/ROBUSTNESS.md, eighth pass).
pub(crate) const START_PROBABILITY: f64 = 0.5;

/// First-order low-pass of the scenario probabilities, `w ← w + β (μ − w)`,
/// `β = min(dt / τ, 1)`. The weights keep summing to one. Buffers are allocated in
/// [`WeightSmoother::new`]; [`WeightSmoother::apply`] does not allocate.
///
/// **Start.** Until one scenario first holds more than [`START_PROBABILITY`] of the
/// probability, the weights are the probabilities themselves; the low-pass starts from that
/// posterior. The bank's first probabilities are its uniform prior (and near-uniform for the
/// step after it, before the states have diverged): a low-pass started there would keep
/// `1 − 1/n` of the weight on the scenarios the bank has already ruled out for about `τ`. On a
/// heavy distal load that mixture moves the first torques toward the ruled-out scenarios'
/// gravity compensation, the posteriors then flip from step to step and the loop chatters at
/// the start (1-DOF, payload at 0.43 m, 0 kg: ±8 N in the first 0.25 s, 46 % of the run's
/// strap-force power above 3 Hz; docs/ROBUSTNESS.md, eighth pass). The smoothing is for the
/// chatter of an established bank, not for its first identification.
#[derive(Clone, Debug)]
pub(crate) struct WeightSmoother {
    beta: f64,
    w: Vec<f64>,
    started: bool,
}

impl WeightSmoother {
    /// A smoother of `n` weights at period `dt` (s) with time constant `tau_s` (s); `None` for
    /// `tau_s <= 0` (no smoothing, the paper's weights).
    pub(crate) fn new(n: usize, dt: f64, tau_s: f64) -> Option<Self> {
        (tau_s > 0.0).then(|| WeightSmoother {
            beta: (dt / tau_s).min(1.0),
            w: vec![0.0; n],
            started: false,
        })
    }

    /// Advance by one step with the probabilities `p` and write the smoothed weights to `out`
    /// (both of the smoother's length; a non-finite probability keeps the previous weights).
    /// Before the start (see [`WeightSmoother`]) `out` is `p`.
    pub(crate) fn apply(&mut self, p: &[f64], out: &mut [f64]) {
        if p.iter().all(|v| v.is_finite()) {
            if self.started {
                for (w, p) in self.w.iter_mut().zip(p) {
                    *w += (p - *w) * self.beta;
                }
            } else if p.iter().any(|&v| v > START_PROBABILITY) {
                self.w.copy_from_slice(p);
                self.started = true;
            }
        }
        if self.started {
            out.copy_from_slice(&self.w);
        } else {
            out.copy_from_slice(p);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Probabilities that flip between two scenarios every step average to an even blend, and a
    /// steady probability vector is passed through unchanged.
    #[test]
    fn chattering_probabilities_blend_and_steady_ones_pass() {
        let mut s = WeightSmoother::new(3, 0.01, 0.1).unwrap();
        let mut out = [0.0; 3];
        for k in 0..400 {
            let p = if k % 2 == 0 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            s.apply(&p, &mut out);
        }
        assert!(
            (out[0] - 0.5).abs() < 0.06 && (out[1] - 0.5).abs() < 0.06,
            "{out:?}"
        );
        assert!((out.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let mut t = WeightSmoother::new(3, 0.01, 0.1).unwrap();
        for _ in 0..10 {
            t.apply(&[0.2, 0.2, 0.6], &mut out);
            assert_eq!(out, [0.2, 0.2, 0.6]);
        }
        assert!(WeightSmoother::new(3, 0.01, 0.0).is_none());
    }

    /// The prior and the near-uniform probabilities after it pass through unsmoothed; the
    /// low-pass starts at the first posterior with a majority scenario, so a scenario the bank
    /// has ruled out keeps no weight from the prior, and smooths from there on.
    #[test]
    fn smoothing_starts_at_the_first_majority() {
        let third = 1.0 / 3.0;
        let mut s = WeightSmoother::new(3, 0.01, 0.15).unwrap();
        let mut out = [0.0; 3];
        for p in [[third; 3], [0.332, 0.335, 0.333], [0.5, 0.25, 0.25]] {
            s.apply(&p, &mut out);
            assert_eq!(out, p, "before the start the weights are the probabilities");
        }
        s.apply(&[0.994, 0.005, 0.001], &mut out);
        assert_eq!(out, [0.994, 0.005, 0.001], "starts at the first majority");
        // From here on a flip is low-passed: w ← w + (dt/τ)(μ − w).
        s.apply(&[0.0, 1.0, 0.0], &mut out);
        let beta = 0.01 / 0.15;
        let expect = [
            0.994 + (0.0 - 0.994) * beta,
            0.005 + (1.0 - 0.005) * beta,
            0.001 + (0.0 - 0.001) * beta,
        ];
        for (o, e) in out.iter().zip(expect) {
            assert!((o - e).abs() < 1e-15, "{out:?} vs {expect:?}");
        }
        // A non-finite probability keeps the weights.
        s.apply(&[f64::NAN, 0.5, 0.5], &mut out);
        for (o, e) in out.iter().zip(expect) {
            assert!((o - e).abs() < 1e-15);
        }
    }
}
