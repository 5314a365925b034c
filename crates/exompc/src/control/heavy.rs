//! The inertia gate of the robust method ([`super::RobustTuning::inertia_engage_ratio`]): the
//! filter-aware mode is also used while the identified scenario makes the leg heavy.
//!
//! The moving average on the velocities and strap forces (docs/MODEL.md §5) delays the force
//! loop of the intent estimate (paper eqs. 5-6) by `(w−1)/2` samples, and its margin against
//! that delay shrinks as a payload raises the leg's inertia (docs/ROBUSTNESS.md, sixth pass): a
//! distal load limit-cycles from the first step, before the oscillation detectors can see it.
//! The payload scenarios of the multi-stage NMPC already know each scenario's inertia, so the
//! gate needs no detection: scenario `i`'s *inertia ratio* is the largest over the joints `j`
//! of `Mᵢ,jj(0) / minₛ Mₛ,jj(0)`, the joint's diagonal mass-matrix entry at the stretched leg
//! (`q = 0`, docs/MODEL.md §3) over the lightest scenario's, and the gate is open while the
//! probability `Σ μᵢ` of the scenarios whose ratio reaches the threshold has been at least ½
//! for [`super::RobustTuning::inertia_engage_s`] without a break; it then stays open (like the
//! detectors' engagement), so that a brief identification error does not switch the mode back
//! and forth.

use super::PredictionModel;
use alloc::vec::Vec;

/// Which scenarios count as heavy; see the module documentation. Allocated in
/// [`InertiaGate::new`]; [`InertiaGate::update`] does not allocate.
#[derive(Clone, Debug)]
pub(crate) struct InertiaGate {
    heavy: Vec<bool>,
    /// Consecutive steps needed, the current run of heavy steps, and whether it is open.
    need: usize,
    run: usize,
    latched: bool,
}

impl InertiaGate {
    /// The gate for the scenarios `models`, threshold `ratio` (> 0; 0 = never open) and
    /// `need` consecutive heavy steps before it opens (0 counts as 1).
    pub(crate) fn new<const N: usize>(
        models: &[PredictionModel<N>],
        ratio: f64,
        need: usize,
    ) -> Self {
        let heavy = inertia_ratios(models)
            .iter()
            .map(|r| ratio > 0.0 && *r >= ratio)
            .collect();
        InertiaGate {
            heavy,
            need: need.max(1),
            run: 0,
            latched: false,
        }
    }

    /// Record this step's probabilities `mu`; returns whether the gate is open.
    pub(crate) fn update(&mut self, mu: &[f64]) -> bool {
        if !self.latched && self.heavy(mu) {
            self.run += 1;
            self.latched = self.run >= self.need;
        } else {
            self.run = 0;
        }
        self.latched
    }

    /// Whether the heavy scenarios hold at least half of the probabilities `mu`.
    fn heavy(&self, mu: &[f64]) -> bool {
        if mu.len() != self.heavy.len() {
            return false;
        }
        let p: f64 = mu
            .iter()
            .zip(&self.heavy)
            .filter(|(_, h)| **h)
            .map(|(m, _)| *m)
            .sum();
        p >= 0.5
    }
}

/// Each scenario's inertia ratio: the largest over the joints of its diagonal mass-matrix entry
/// at `q = 0` over the smallest one among the scenarios (1 for the lightest scenario).
pub fn inertia_ratios<const N: usize>(models: &[PredictionModel<N>]) -> Vec<f64> {
    let zero = nalgebra::SVector::<f64, N>::zeros();
    let diag: Vec<_> = models
        .iter()
        .map(|m| m.robot.chain.mass_matrix(&zero).diagonal())
        .collect();
    diag.iter()
        .map(|d| {
            (0..N)
                .map(|j| {
                    let lightest = diag.iter().map(|e| e[j]).fold(f64::INFINITY, f64::min);
                    d[j] / lightest
                })
                .fold(1.0, f64::max)
        })
        .collect()
}
