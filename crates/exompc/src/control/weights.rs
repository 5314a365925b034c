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

/// First-order low-pass of the scenario probabilities, `w ← w + β (μ − w)`,
/// `β = min(dt / τ, 1)`, starting at the first probabilities it sees. The weights keep summing
/// to one. Buffers are allocated in [`WeightSmoother::new`]; [`WeightSmoother::apply`] does not
/// allocate.
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
    pub(crate) fn apply(&mut self, p: &[f64], out: &mut [f64]) {
        if p.iter().all(|v| v.is_finite()) {
            if self.started {
                for (w, p) in self.w.iter_mut().zip(p) {
                    *w += (p - *w) * self.beta;
                }
            } else {
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
            t.apply(&[0.2, 0.3, 0.5], &mut out);
            assert_eq!(out, [0.2, 0.3, 0.5]);
        }
        assert!(WeightSmoother::new(3, 0.01, 0.0).is_none());
    }
}
