//! The bank of scenario filters and the scenario probabilities of paper eqs. 10-11.

use super::{EkfError, EkfSettings, EstimateError, EstimatorOptions, ScenarioEkf};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::RobotModel;
use alloc::{vec, vec::Vec};
use nalgebra::SVector;

/// Scenario probability update of paper eqs. 10-11, in the log domain.
///
/// With `wᵢ = ln μᵢ(k−1) + ℓᵢ` (`ℓᵢ` the log-likelihood of scenario `i`, e.g.
/// [`InnovationStats::log_likelihood`](super::InnovationStats::log_likelihood) with `c1`):
///
/// * eq. 10: `μ'ᵢ = exp(wᵢ − max w) / Σⱼ exp(wⱼ − max w)` (log-sum-exp, so nothing underflows or
///   overflows for any innovation size);
/// * eq. 11 with renormalisation: `μᵢ = max(μ'ᵢ, floor)`, renormalised so that `Σ μ = 1` while
///   every `μᵢ ≥ floor` — the floored entries stay at `floor` and the others share
///   `1 − (#floored)·floor` in proportion to `μ'` (a projection, iterated until no entry drops
///   below the floor).
///
/// Degenerate inputs: non-positive or non-finite priors count as zero weight (all of them: a
/// uniform prior); a NaN log-likelihood leaves the (normalised, floored) prior unchanged;
/// `+∞` log-likelihoods share the mass equally; if every `wᵢ` is `−∞` the prior is kept. A
/// `floor` with `floor · n ≥ 1` gives the uniform distribution.
///
/// # Panics
/// If the three slices differ in length.
pub fn update_probabilities(prev: &[f64], log_likelihoods: &[f64], floor: f64, out: &mut [f64]) {
    let n = out.len();
    assert!(
        prev.len() == n && log_likelihoods.len() == n,
        "update_probabilities: slice lengths differ"
    );
    if n == 0 {
        return;
    }
    let floor = if floor.is_finite() {
        floor.max(0.0)
    } else {
        0.0
    };
    if floor * n as f64 >= 1.0 {
        out.fill(1.0 / n as f64);
        return;
    }
    let prior_ok = |p: f64| p.is_finite() && p > 0.0;
    let any_prior = prev.iter().any(|&p| prior_ok(p));
    let log_prior = |i: usize| {
        if !any_prior {
            0.0
        } else if prior_ok(prev[i]) {
            prev[i].ln()
        } else {
            f64::NEG_INFINITY
        }
    };

    // Eq. 10 in the log domain.
    let use_likelihood = log_likelihoods.iter().all(|l| !l.is_nan());
    let weight = |i: usize| {
        let lp = log_prior(i);
        if use_likelihood && lp > f64::NEG_INFINITY {
            lp + log_likelihoods[i]
        } else {
            lp
        }
    };
    let mut wmax = f64::NEG_INFINITY;
    for i in 0..n {
        let w = weight(i);
        if w > wmax {
            wmax = w;
        }
    }
    if wmax == f64::INFINITY {
        for (i, o) in out.iter_mut().enumerate() {
            *o = if weight(i) == f64::INFINITY { 1.0 } else { 0.0 };
        }
    } else if wmax == f64::NEG_INFINITY || wmax.is_nan() {
        // No information (every weight −∞): keep the prior.
        for (i, o) in out.iter_mut().enumerate() {
            *o = log_prior(i).exp();
        }
    } else {
        for (i, o) in out.iter_mut().enumerate() {
            *o = (weight(i) - wmax).exp();
        }
    }
    let sum: f64 = out.iter().sum();
    if !(sum.is_finite() && sum > 0.0) {
        out.fill(1.0 / n as f64);
    } else {
        out.iter_mut().for_each(|o| *o /= sum);
    }

    // Eq. 11: floor, then renormalise keeping every entry at or above the floor.
    if floor == 0.0 {
        return;
    }
    // Entries below the floor are pinned to it (marked by a negative sign while iterating).
    loop {
        let mut pinned = 0usize;
        let mut free_mass = 0.0;
        for &o in out.iter() {
            if o < 0.0 {
                pinned += 1;
            } else {
                free_mass += o;
            }
        }
        let scale = if free_mass > 0.0 {
            (1.0 - pinned as f64 * floor) / free_mass
        } else {
            0.0
        };
        let mut changed = false;
        for o in out.iter_mut() {
            if *o >= 0.0 && *o * scale < floor {
                *o = -1.0;
                changed = true;
            }
        }
        if !changed {
            for o in out.iter_mut() {
                *o = if *o < 0.0 { floor } else { *o * scale };
            }
            return;
        }
    }
}

/// A bank of [`ScenarioEkf`]s, one per payload scenario, with the scenario probabilities `μ`
/// of paper eqs. 10-11 (MODEL.md §8).
///
/// Each [`step`](Self::step) runs every filter, turns its innovation `(vᵢ, S̄ᵢ)` into the
/// log-likelihood `ℓᵢ = −½ c1 vᵢᵀ S̄ᵢ⁻¹ vᵢ − ½ ln((2π)^ny |c1 S̄ᵢ|)` and updates the probabilities
/// by [`update_probabilities`] (log-sum-exp, floor, renormalisation). The initial probabilities
/// are uniform. All storage is allocated in [`new`](Self::new); stepping does not allocate.
///
/// The [module documentation](crate::estimate) explains the augmented state, the measurement
/// and why the default noise covariances ([`EkfSettings`]) are what they are.
#[derive(Clone, Debug)]
pub struct EkfBank<const N: usize, const NA: usize, const NY: usize> {
    filters: Vec<ScenarioEkf<N, NA, NY>>,
    probabilities: Vec<f64>,
    scratch: Vec<f64>,
    log_likelihoods: Vec<f64>,
    c1: f64,
    floor: f64,
}

impl<const N: usize, const NA: usize, const NY: usize> EkfBank<N, NA, NY> {
    /// One filter per scenario model (payload merged into each model's links), all starting at
    /// `[q0, qd0, 0]`, with uniform probabilities.
    pub fn new(
        models: &[RobotModel<N>],
        settings: &EkfSettings,
        options: &EstimatorOptions,
        q0: &SVector<f64, N>,
        qd0: &SVector<f64, N>,
    ) -> Result<Self, EstimateError> {
        if models.is_empty() {
            return Err(EstimateError::NoScenario);
        }
        options.validate(models.len())?;
        let filters = models
            .iter()
            .map(|m| ScenarioEkf::new(*m, settings, options, q0, qd0))
            .collect::<Result<Vec<_>, _>>()?;
        let n = filters.len();
        Ok(Self {
            filters,
            probabilities: vec![1.0 / n as f64; n],
            scratch: vec![0.0; n],
            log_likelihoods: vec![0.0; n],
            c1: options.c1,
            floor: options.floor,
        })
    }

    /// Back to the initial state: every filter reset, uniform probabilities.
    pub fn reset(&mut self) {
        self.filters.iter_mut().for_each(ScenarioEkf::reset);
        let n = self.filters.len();
        self.probabilities.fill(1.0 / n as f64);
    }

    /// Restart every filter from `[q, qd, 0]` with uniform probabilities.
    pub fn reset_to(&mut self, q: &SVector<f64, N>, qd: &SVector<f64, N>) {
        self.filters.iter_mut().for_each(|f| f.reset_to(q, qd));
        let n = self.filters.len();
        self.probabilities.fill(1.0 / n as f64);
    }

    /// Resume every filter after a gap in the data ([`ScenarioEkf::resume_at`]); the
    /// probabilities are kept.
    pub fn resume_at(&mut self, q: &SVector<f64, N>, qd: &SVector<f64, N>) {
        self.filters.iter_mut().for_each(|f| f.resume_at(q, qd));
    }

    /// Overwrite scenario `i`'s disturbance estimate ([`ScenarioEkf::set_disturbance`]); an
    /// index out of range is ignored.
    pub fn set_disturbance(&mut self, i: usize, d: &SVector<f64, N>) {
        if let Some(f) = self.filters.get_mut(i) {
            f.set_disturbance(d);
        }
    }

    /// One period for every scenario (arguments as in [`ScenarioEkf::step`]), then the
    /// probability update of eqs. 10-11.
    ///
    /// If any filter fails this step (it is then left unchanged), the probabilities are kept and
    /// the first error is returned; the other filters have still been updated.
    pub fn step(
        &mut self,
        y: &SVector<f64, NY>,
        u_prev: &SVector<f64, N>,
        t_int_prev: &SVector<f64, N>,
    ) -> Result<(), EkfError> {
        self.step_per_scenario(y, u_prev, |_| *t_int_prev)
    }

    /// [`step`](Self::step) with scenario `i`'s strap torque `t_int_prev(i)`: scenarios whose
    /// strap geometry differs map the same measured strap forces to different joint torques
    /// (`Jᵢᵀ F`, docs/MODEL.md §4).
    pub fn step_per_scenario(
        &mut self,
        y: &SVector<f64, NY>,
        u_prev: &SVector<f64, N>,
        t_int_prev: impl Fn(usize) -> SVector<f64, N>,
    ) -> Result<(), EkfError> {
        let mut first_err = None;
        for (i, (f, ll)) in self
            .filters
            .iter_mut()
            .zip(self.log_likelihoods.iter_mut())
            .enumerate()
        {
            match f.step(y, u_prev, &t_int_prev(i)) {
                Ok(stats) => *ll = stats.log_likelihood(self.c1),
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
        }
        if let Some(e) = first_err {
            return Err(e);
        }
        update_probabilities(
            &self.probabilities,
            &self.log_likelihoods,
            self.floor,
            &mut self.scratch,
        );
        core::mem::swap(&mut self.probabilities, &mut self.scratch);
        Ok(())
    }

    /// One period with some measured channels missing (a sensor fault): every filter updates
    /// with the measured rows only, holding its disturbance when `hold_disturbance`
    /// ([`ScenarioEkf::step_masked`], scenario `i`'s strap torque `t_int_prev(i)`); the
    /// probabilities are kept. A failed filter is left unchanged and the first error returned.
    pub fn step_masked_per_scenario(
        &mut self,
        y: &SVector<f64, NY>,
        measured: &[bool; NY],
        hold_disturbance: bool,
        u_prev: &SVector<f64, N>,
        t_int_prev: impl Fn(usize) -> SVector<f64, N>,
    ) -> Result<(), EkfError> {
        let mut first_err = None;
        for (i, f) in self.filters.iter_mut().enumerate() {
            if let Err(e) = f.step_masked(y, measured, hold_disturbance, u_prev, &t_int_prev(i)) {
                first_err.get_or_insert(e);
            }
        }
        first_err.map_or(Ok(()), Err)
    }

    /// Probability-weighted one-period prediction `Σᵢ μᵢ f(x̂ᵢ)` of the joint angles and
    /// velocities under the applied torque `u` and scenario `i`'s strap torque `t_int(i)`
    /// (the model's estimate of the next measurement's `[q, qd]`).
    pub fn weighted_prediction(
        &self,
        u: &SVector<f64, N>,
        t_int: impl Fn(usize) -> SVector<f64, N>,
    ) -> (SVector<f64, N>, SVector<f64, N>) {
        let (mut q, mut qd) = (SVector::<f64, N>::zeros(), SVector::<f64, N>::zeros());
        for (i, (f, p)) in self.filters.iter().zip(&self.probabilities).enumerate() {
            let x = f.predict(f.state(), u, &t_int(i));
            for a in 0..N {
                q[a] += x[a] * *p;
                qd[a] += x[N + a] * *p;
            }
        }
        (q, qd)
    }

    /// Scenario probabilities `μᵢ(k)` (sum 1, each ≥ the floor).
    pub fn probabilities(&self) -> &[f64] {
        &self.probabilities
    }

    /// Disturbance estimate `d̂ᵢ` of scenario `i`.
    ///
    /// # Panics
    /// If `i` is out of range.
    pub fn disturbance(&self, i: usize) -> SVector<f64, N> {
        self.filters[i].disturbance()
    }

    /// Probability-weighted joint velocity `Σᵢ μᵢ q̇̂ᵢ` of the scenario filters (rad/s): the
    /// bank's lag-free velocity estimate (the probabilities of eqs. 10-11 on the EKF states).
    pub fn weighted_velocity(&self) -> SVector<f64, N> {
        let mut qd = SVector::<f64, N>::zeros();
        for (f, p) in self.filters.iter().zip(&self.probabilities) {
            qd += f.velocities() * *p;
        }
        qd
    }

    /// The scenario filters.
    pub fn filters(&self) -> &[ScenarioEkf<N, NA, NY>] {
        &self.filters
    }

    /// Number of scenarios.
    pub fn len(&self) -> usize {
        self.filters.len()
    }

    /// Always false (a bank has at least one scenario); provided for API completeness.
    pub fn is_empty(&self) -> bool {
        self.filters.is_empty()
    }

    /// Log-likelihoods `ℓᵢ` of the last successful step (zero before the first step).
    pub fn log_likelihoods(&self) -> &[f64] {
        &self.log_likelihoods
    }
}
