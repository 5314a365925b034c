//! Multi-stage robust NMPC (paper §3.2, eqs. 10-13): see [`MultiStage`].

use super::heavy::InertiaGate;
use super::limits::LimitsError;
use super::nmpc::{classify, horizon_inputs, NmpcCore};
use super::nmpc_problem::{NmpcProblem, NmpcSettings};
use super::ocp_tree::{tree_is_structured, TreeSqp};
use super::prediction::{HorizonInputs, PredictionModel};
use super::ride_through::{ChannelGuard, TorqueExtrapolation, EXTRAPOLATION_MIN_S};
#[cfg(doc)]
use super::robust::RobustTuning;
use super::robust::{IntentEstimate, RobustSettings, RobustState};
use super::strap_intent::StrapIntent;
use super::weights::WeightSmoother;
use super::{
    ControlOutput, Controller, EstimatedChannels, IntentEstimator, Measurement, StepStatus,
    TorqueLimits,
};
use crate::estimate::{EkfBank, EkfSettings, EstimateError, EstimatorOptions};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::JointState;
use crate::solver::{Constraints, LeastSquares, SolverError, Sqp, SqpInfo};
use alloc::{boxed::Box, vec, vec::Vec};
use nalgebra::{DMatrix, DVector, SVector};
#[cfg(feature = "std")]
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Multi-stage problem formulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Formulation {
    /// One independent NMPC per scenario, combined by probability (paper eq. 13).
    Decoupled,
    /// One coupled problem, all scenarios sharing the first `robust_horizon` inputs (paper eq. 12).
    Coupled,
}

/// The scenario tree solved as one NLP (eq. 12 with non-anticipativity): decision vector
/// `[shared increments (N·Nr), scenario 1's remaining (N·(Nc−Nr)), ..., scenario S's]`;
/// residuals are each scenario's eq.-7 residuals scaled by `√μ_i`.
#[derive(Clone, Debug)]
pub struct CoupledProblem<const N: usize> {
    scenarios: Vec<NmpcProblem<N>>,
    weights: Vec<f64>,
    nr: usize,
    nc: usize,
    zi: Vec<f64>,
    ri: Vec<f64>,
    jaci: DMatrix<f64>,
}

impl<const N: usize> CoupledProblem<N> {
    /// The tree of one scenario per model with the horizon and weights of `s`, sharing the
    /// first `robust_horizon` increments (clamped to `1..=Nc`); equal weights until
    /// [`Self::set_step`].
    pub fn new(models: &[PredictionModel<N>], s: &NmpcSettings, robust_horizon: usize) -> Self {
        let scenarios: Vec<NmpcProblem<N>> =
            models.iter().map(|m| NmpcProblem::new(*m, s)).collect();
        let (m1, n1) = (scenarios[0].num_residuals(), scenarios[0].num_vars());
        CoupledProblem {
            weights: vec![1.0; scenarios.len()],
            nr: robust_horizon.clamp(1, s.nc),
            nc: s.nc,
            zi: vec![0.0; n1],
            ri: vec![0.0; m1],
            jaci: DMatrix::zeros(m1, n1),
            scenarios,
        }
    }

    /// Sets every scenario's initial state `x0`, previous torque `t_prev` and its horizon
    /// inputs, and the scenario probabilities `weights` (`μ_i` of eq. 12), for one solve.
    /// `inputs` and `weights` hold one entry per scenario (extra entries are ignored).
    pub fn set_step(
        &mut self,
        x0: JointState<f64, N>,
        t_prev: SVector<f64, N>,
        inputs: &[HorizonInputs<N>],
        weights: &[f64],
    ) {
        for ((sc, inp), (w, wi)) in self
            .scenarios
            .iter_mut()
            .zip(inputs)
            .zip(self.weights.iter_mut().zip(weights))
        {
            sc.x0 = x0;
            sc.t_prev = t_prev;
            sc.inputs = *inp;
            *w = *wi;
        }
    }

    /// The scenarios' eq.-7 problems.
    pub fn scenarios(&self) -> &[NmpcProblem<N>] {
        &self.scenarios
    }

    /// The scenario probabilities `μ_i`.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Number of shared decision variables `N·Nr`.
    fn shared(&self) -> usize {
        N * self.nr
    }

    /// Scenario-private decision variables per scenario `N·(Nc − Nr)`.
    fn private(&self) -> usize {
        N * (self.nc - self.nr)
    }

    /// Scenario `i`'s decision vector from the coupled one.
    fn gather(&self, z: &[f64], i: usize, out: &mut [f64]) {
        let (sh, pr) = (self.shared(), self.private());
        out[..sh].copy_from_slice(&z[..sh]);
        out[sh..].copy_from_slice(&z[sh + i * pr..sh + (i + 1) * pr]);
    }

    /// Constraints of eqs. 8-9 of every scenario in the coupled variables: `|dT| ≤ ΔT_max`
    /// (box) and each scenario's cumulative torque rows; `scratch` holds one scenario's
    /// constraints (`N·Nc` variables and rows).
    pub fn write_constraints(
        &self,
        limits: &TorqueLimits,
        c: &mut Constraints,
        scratch: &mut Constraints,
    ) {
        let (sh, pr) = (self.shared(), self.private());
        let p1 = N * self.nc;
        c.zl.fill(-limits.rate);
        c.zu.fill(limits.rate);
        c.a.fill(0.0);
        for (i, sc) in self.scenarios.iter().enumerate() {
            sc.write_constraints(limits, scratch);
            for r in 0..p1 {
                let row = i * p1 + r;
                c.bl[row] = scratch.bl[r];
                c.bu[row] = scratch.bu[r];
                for col in 0..p1 {
                    let v = scratch.a[(r, col)];
                    let cc = if col < sh {
                        col
                    } else {
                        sh + i * pr + (col - sh)
                    };
                    c.a[(row, cc)] = v;
                }
            }
        }
    }
}

impl<const N: usize> LeastSquares for CoupledProblem<N> {
    fn num_vars(&self) -> usize {
        self.shared() + self.scenarios.len() * self.private()
    }

    fn num_residuals(&self) -> usize {
        self.scenarios.len() * self.ri.len()
    }

    fn residuals(&mut self, z: &[f64], r: &mut [f64]) -> bool {
        let m1 = self.ri.len();
        let mut zi = core::mem::take(&mut self.zi);
        let mut ok = true;
        for i in 0..self.scenarios.len() {
            self.gather(z, i, &mut zi);
            let w = self.weights[i].sqrt();
            let ri = &mut r[i * m1..(i + 1) * m1];
            ok &= self.scenarios[i].residuals(&zi, ri);
            ri.iter_mut().for_each(|v| *v *= w);
        }
        self.zi = zi;
        ok
    }

    fn residuals_jacobian(&mut self, z: &[f64], r: &mut [f64], jac: &mut DMatrix<f64>) -> bool {
        let (sh, pr, m1) = (self.shared(), self.private(), self.ri.len());
        let mut zi = core::mem::take(&mut self.zi);
        let mut jaci = core::mem::replace(&mut self.jaci, DMatrix::zeros(0, 0));
        jac.fill(0.0);
        let mut ok = true;
        for i in 0..self.scenarios.len() {
            self.gather(z, i, &mut zi);
            let w = self.weights[i].sqrt();
            let ri = &mut r[i * m1..(i + 1) * m1];
            ok &= self.scenarios[i].residuals_jacobian(&zi, ri, &mut jaci);
            ri.iter_mut().for_each(|v| *v *= w);
            for col in 0..jaci.ncols() {
                let cc = if col < sh {
                    col
                } else {
                    sh + i * pr + (col - sh)
                };
                for row in 0..m1 {
                    jac[(i * m1 + row, cc)] = w * jaci[(row, col)];
                }
            }
        }
        self.zi = zi;
        self.jaci = jaci;
        ok
    }
}

/// The coupled SQP with the QP back-end `[controller.sqp] qp` resolves to for the tree
/// ([`super::ocp_tree::tree_is_structured`]); only that one is allocated.
#[derive(Clone, Debug)]
enum CoupledSolver<const N: usize> {
    /// Condensed dense SQP, its constraint rows and a one-scenario scratch.
    Dense(Box<(Sqp, Constraints, Constraints)>),
    /// Multiple-shooting tree SQP with the block-arrowhead QP.
    Tree(Box<TreeSqp<N>>),
}

/// Solver state of the coupled formulation.
#[derive(Clone, Debug)]
struct CoupledCore<const N: usize> {
    problem: CoupledProblem<N>,
    solver: CoupledSolver<N>,
    z: DVector<f64>,
    zi: Vec<f64>,
    shared: Vec<f64>,
}

impl<const N: usize> CoupledCore<N> {
    fn new(
        models: &[PredictionModel<N>],
        s: &NmpcSettings,
        robust_horizon: usize,
    ) -> Result<Self, SolverError> {
        let problem = CoupledProblem::new(models, s, robust_horizon);
        let n = problem.num_vars();
        let solver = if tree_is_structured(s.qp, n) {
            CoupledSolver::Tree(Box::new(TreeSqp::new(s, problem.nr, models.len())?))
        } else {
            let p = models.len() * N * s.nc;
            CoupledSolver::Dense(Box::new((
                Sqp::new(n, problem.num_residuals(), p, s.sqp)?,
                Constraints::unbounded(n, p),
                Constraints::unbounded(N * s.nc, N * s.nc),
            )))
        };
        Ok(CoupledCore {
            solver,
            z: DVector::zeros(n),
            zi: vec![0.0; N * s.nc],
            shared: vec![0.0; problem.shared()],
            problem,
        })
    }

    fn solve(
        &mut self,
        x0: JointState<f64, N>,
        t_prev: SVector<f64, N>,
        inputs: &[HorizonInputs<N>],
        weights: &[f64],
        limits: &TorqueLimits,
    ) -> SqpInfo {
        let (sh, pr) = (self.problem.shared(), self.problem.private());
        // Warm start: shift each scenario's plan one step; shared part is the weighted mean.
        let mut sh_buf = core::mem::take(&mut self.shared);
        sh_buf.fill(0.0);
        for (i, w) in weights.iter().enumerate() {
            self.problem.gather(self.z.as_slice(), i, &mut self.zi);
            let n1 = self.zi.len();
            for k in 0..n1 {
                self.zi[k] = if k + N < n1 { self.zi[k + N] } else { 0.0 };
            }
            for (k, v) in sh_buf.iter_mut().enumerate() {
                *v += w * self.zi[k];
            }
            for k in 0..pr {
                self.z[sh + i * pr + k] = self.zi[sh + k];
            }
        }
        for (k, v) in sh_buf.iter().enumerate() {
            self.z[k] = *v;
        }
        self.shared = sh_buf;
        if !self.z.iter().all(|v| v.is_finite()) {
            self.z.fill(0.0);
        }
        self.problem.set_step(x0, t_prev, inputs, weights);
        let info = match &mut self.solver {
            CoupledSolver::Tree(tree) => tree.solve(
                &self.problem.scenarios,
                &self.problem.weights,
                limits,
                &mut self.z,
            ),
            CoupledSolver::Dense(dense) => {
                let (sqp, constraints, scratch) = &mut **dense;
                self.problem.write_constraints(limits, constraints, scratch);
                sqp.solve(&mut self.problem, constraints, &mut self.z)
            }
        };
        if !classify(info.status).1 {
            self.z.fill(0.0);
        }
        info
    }

    /// Step 5 (coupled) of [`MultiStage`]'s step: solve the tree and return the desired
    /// torque `T(k−1) + dT₀` (the shared first increment; `T(k−1)` when the solve is not
    /// usable), the status and the iterations.
    fn first_torque(
        &mut self,
        x0: JointState<f64, N>,
        prev: SVector<f64, N>,
        inputs: &[HorizonInputs<N>],
        weights: &[f64],
        limits: &TorqueLimits,
    ) -> (SVector<f64, N>, StepStatus, u32) {
        let info = self.solve(x0, prev, inputs, weights, limits);
        let (status, usable) = classify(info.status);
        let dt0 = SVector::<f64, N>::from_fn(|a, _| self.z[a]);
        (
            if usable { prev + dt0 } else { prev },
            status,
            info.iterations as u32,
        )
    }
}

/// Options of the multi-stage controller (MODEL.md §8).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MultiStageOptions {
    /// Decoupled (paper) or coupled (scenario-tree NLP).
    pub formulation: Formulation,
    /// Shared increments in the coupled formulation (1 = only the applied one).
    pub robust_horizon: usize,
    /// Solve the decoupled scenarios in parallel with rayon.
    pub parallel: bool,
}

/// Steps of estimated strap forces over which the EKF banks still update with the measured
/// rows of `y = [q, qd]` (`MultiStage::mark_estimated`) before `d̂` is replayed
/// (`MultiStage::replay_disturbance`) or, without a replay, held: an estimate a few steps old
/// is close to the force, a force rejected for a few steps (a gate's jolt, the ramp into a
/// rail) is no gait to replay, and the filters keep following the model's error along the gait
/// (at 3 kg it moves `d̂` by up to 0.7 N·m per step). While the forces follow their
/// continuation `d̂` is continued with them from the fault's first step instead
/// (`MultiStage::continue_disturbance`). Chosen by measurement (docs/RELIABILITY.md §2).
const REPLAY_AFTER_STEPS: u32 = 5;

/// Spacing (s) of the slots of the `d̂` history ([`DisturbanceReplay`]); the replay reads
/// between them by linear interpolation. `d̂` follows the gait (about 1 Hz), so 40 ms slots
/// keep it to about 1 % of its swing while the history of both banks fits the Cortex-M7's
/// RAM (docs/EMBEDDED.md).
const REPLAY_STRIDE_S: f64 = 0.04;

/// The disturbance estimates `d̂ᵢ` of the EKF banks over the last
/// [`ChannelGuard::HISTORY_S`], per bank (the main one, the robust method's disturbance bank)
/// and scenario, one slot every [`REPLAY_STRIDE_S`] in `f32`, for the replay of one gait
/// period back while the strap forces are estimated.
#[derive(Clone, Debug)]
struct DisturbanceReplay<const N: usize> {
    /// `ring[b][i * len + j % len]`: bank `b`, scenario `i`, the `d̂` recorded at step
    /// `j * stride` of the history (the second bank's ring is allocated with that bank,
    /// `with_robust`).
    ring: [Vec<SVector<f32, N>>; 2],
    len: usize,
    /// Steps per slot.
    stride: usize,
    /// Steps recorded since the history (re)started.
    count: usize,
    /// Replay offset per bank and scenario (NaN: not replaying).
    offset: [Vec<SVector<f64, N>>; 2],
    /// The gait period (steps) of the replay (0: not replaying).
    period: usize,
    /// The replay restarted on a new period (its offsets continue the replayed `d̂`).
    restarted: bool,
    /// `d̂` was continued at the gait frequency within this force fault
    /// (`MultiStage::continue_disturbance`): a replay that follows continues the current `d̂`.
    continued: bool,
    /// Every bank's `d̂ᵢ` (bank-major, two banks' room) on the continuation's first step, how
    /// many of them are set, and the steps since: the continuation is fitted again on each
    /// step to the same stretch of the history (kept out of the Cortex-M7's RAM,
    /// docs/EMBEDDED.md).
    starts: Vec<SVector<f64, N>>,
    started: usize,
    fit_steps: u32,
    /// Control period (s).
    dt: f64,
}

impl<const N: usize> DisturbanceReplay<N> {
    fn new(scenarios: usize, dt: f64) -> Self {
        let dt = if dt.is_finite() && dt > 0.0 { dt } else { 0.01 };
        let stride = ((REPLAY_STRIDE_S / dt).round() as usize).clamp(1, 1 << 10);
        let steps = ((ChannelGuard::<N>::HISTORY_S / dt).ceil() as usize).clamp(8, 1 << 16);
        let len = steps.div_ceil(stride) + 1;
        let ring = vec![SVector::zeros(); len * scenarios];
        let offset = vec![SVector::repeat(f64::NAN); scenarios];
        DisturbanceReplay {
            ring: [ring, Vec::new()],
            len,
            stride,
            count: 0,
            offset: [offset.clone(), offset],
            period: 0,
            restarted: false,
            continued: false,
            starts: vec![SVector::zeros(); 2 * scenarios],
            started: 0,
            fit_steps: 0,
            dt,
        }
    }

    /// Allocate the second bank's ring (its history starts with the first bank's).
    fn add_second_bank(&mut self) {
        self.ring[1] = self.ring[0].clone();
    }

    /// Whether `d̂` of `k` steps back can be read by [`Self::back`]: within the history and
    /// older than the last slot (`k > stride`).
    fn holds(&self, k: usize) -> bool {
        if k <= self.stride || k > self.count {
            return false;
        }
        let last = (self.count - 1) / self.stride;
        let first = (last + 1).saturating_sub(self.len);
        self.count - k >= first * self.stride
    }

    /// `d̂` of bank `b`, scenario `i`, `k` steps back (1: the last recorded), interpolated
    /// between its slots; `k` must satisfy [`Self::holds`].
    fn back(&self, b: usize, i: usize, k: usize) -> SVector<f64, N> {
        let t = self.count - k;
        let (j, f) = (
            t / self.stride,
            (t % self.stride) as f64 / self.stride as f64,
        );
        let slot = |j: usize| self.ring[b][i * self.len + j % self.len].cast::<f64>();
        if f == 0.0 {
            slot(j)
        } else {
            slot(j) * (1.0 - f) + slot(j + 1) * f
        }
    }

    /// Begin or continue the replay with the gait period `p` (steps): a new period within a
    /// replay restarts it (the offsets are taken again, continuous with the replayed `d̂`:
    /// the old offset against the new lag made the replay step).
    fn set_period(&mut self, p: usize) {
        if self.period != p {
            for o in self.offset.iter_mut() {
                o.fill(SVector::repeat(f64::NAN));
            }
            self.restarted = self.period != 0;
            self.period = p;
        }
    }

    /// End the replay and the continuation (the forces are measured again, or `d̂` is held:
    /// `continued` stays for the rest of the fault, see [`Self::end_fault`]).
    fn stop(&mut self) {
        for o in self.offset.iter_mut() {
            o.fill(SVector::repeat(f64::NAN));
        }
        self.period = 0;
        self.restarted = false;
        self.started = 0;
    }

    /// The strap forces are measured: a later fault's replay starts from its filters' update.
    fn end_fault(&mut self) {
        self.stop();
        self.continued = false;
    }

    /// Steps of history the continuation is fitted to (up to [`EXTRAPOLATION_FIT_S`](super::EXTRAPOLATION_FIT_S) before
    /// its first step); `None` when shorter than [`EXTRAPOLATION_MIN_S`].
    fn fit_span(&self) -> Option<usize> {
        let since = self.fit_steps as usize;
        let n = TorqueExtrapolation::<N>::fit_steps(self.count.saturating_sub(since), self.dt);
        ((n as f64) * self.dt >= EXTRAPOLATION_MIN_S - 1e-9 && self.holds(n + since)).then_some(n)
    }

    /// `d̂` of bank `b`, scenario `i` (the `index`-th in bank-major order) continued at the
    /// gait frequency `omega` (rad/s) from its value on the continuation's first step
    /// (`current` there): [`TorqueExtrapolation::fit_series`] fitted to the history of the
    /// `n` steps ([`Self::fit_span`]) before that step (older than the last slot, as
    /// [`Self::holds`] reads it); `None` when the fit is not finite.
    fn continued(
        &mut self,
        index: usize,
        b: usize,
        i: usize,
        current: &SVector<f64, N>,
        omega: f64,
        n: usize,
    ) -> Option<SVector<f64, N>> {
        if self.started == index {
            *self.starts.get_mut(index)? = *current;
            self.started += 1;
        }
        let start = *self.starts.get(index)?;
        let since = self.fit_steps as usize;
        // The history `stride + 1 ..= n` steps before the continuation's first step (its time
        // origin: the fit's steps back count from there), read between the slots as the
        // replay reads it (the slots alone: two cells of the fine scan lost at 12.1 N,
        // docs/RELIABILITY.md §2).
        let samples = (self.stride + 1..=n).map(|k| (k, self.back(b, i, k + since)));
        let fit = TorqueExtrapolation::fit_series(samples, omega, self.dt, start)?;
        Some(fit.at(self.fit_steps, self.dt))
    }

    /// The replayed `d̂` of bank `b`, scenario `i` at this step: one period `p` (set by
    /// [`Self::set_period`]) back plus the offset fixed at the replay's first step,
    /// `current − d̂(p + since steps back)`, `current` the bank's `d̂` there, unchanged since
    /// the filters' last update `since` steps back: the replay continues the gait from that
    /// update (anchored at `p + 1` steps back, a replay that began after steps without a
    /// known period carried the gait's change over them through the whole replay). After a
    /// new period within the replay the offset is `current − d̂(p + 1 steps back)`,
    /// continuous with the replay. `p + 1` must satisfy [`Self::holds`].
    fn replayed(
        &mut self,
        b: usize,
        i: usize,
        current: &SVector<f64, N>,
        since: usize,
    ) -> SVector<f64, N> {
        let p = self.period;
        if !self.offset[b][i].iter().all(|v| v.is_finite()) {
            // After a continuation in this fault the replay goes on from `current` (no longer,
            // or not only, the filters' last update): p + 1.
            let k = if !self.restarted && !self.continued && self.holds(p + since) {
                p + since
            } else {
                p + 1
            };
            self.offset[b][i] = current - self.back(b, i, k);
        }
        self.back(b, i, p) + self.offset[b][i]
    }

    /// Record this step's `d` of bank `b`, scenario `i`, or with `continue_p` the history's
    /// own value `p` steps back (the gait continued, while the forces are estimated).
    fn record_step(&mut self, b: usize, i: usize, d: &SVector<f64, N>, continue_p: Option<usize>) {
        let v = continue_p.map_or(*d, |p| self.back(b, i, p));
        self.record(b, i, &v);
    }

    /// Record `d̂` of bank `b`, scenario `i` for this step (kept at the slot steps only).
    fn record(&mut self, b: usize, i: usize, d: &SVector<f64, N>) {
        if self.count.is_multiple_of(self.stride) {
            self.ring[b][i * self.len + (self.count / self.stride) % self.len] = d.cast::<f32>();
        }
    }
}

/// The multi-stage robust NMPC controller of paper §3.2.
///
/// Each step: the EKF bank is advanced with `y = [q, qd]`, `T(k−1)` and the filtered strap
/// torque of step `k−1` (MODEL.md §8), giving the probabilities `μ_i(k)` of eqs. 10-11 and each
/// scenario's disturbance estimate `d̂_i`; every scenario's NMPC starts from `[q, filtered qd]`
/// with its own model and `d̂_i`; the torque follows eq. 13 (decoupled) or the shared first
/// increment (coupled), then the hard limits of eqs. 8-9.
///
/// One scenario per candidate payload (docs/MODEL.md §8), each with its own robot model and
/// EKF disturbance estimate, weighted by the EKF-bank probabilities ([`EkfBank`]).
///
/// Two formulations:
/// - [`Formulation::Decoupled`] (the paper): each scenario's NMPC of eq. 7 is solved on its own
///   and the increments are blended by eq. 13, `T(k) = T(k−1) + Σ μ_i dT_i(k)`.
/// - [`Formulation::Coupled`] (Lucia et al. 2013, as in do-mpc; beyond the paper): one NLP over
///   the scenario tree with the probability-weighted cost of eq. 12 and non-anticipativity: the
///   first `robust_horizon` increments are shared by all scenarios.
pub struct MultiStage<const N: usize, const NA: usize, const NY: usize> {
    bank: EkfBank<N, NA, NY>,
    cores: Vec<NmpcCore<N>>,
    coupled: Option<CoupledCore<N>>,
    models: Vec<PredictionModel<N>>,
    inputs: Vec<HorizonInputs<N>>,
    weights: Vec<f64>,
    dist: Vec<SVector<f64, N>>,
    #[cfg_attr(not(feature = "std"), allow(dead_code))] // only `parallel` is read, with std
    options: MultiStageOptions,
    intent: IntentEstimator,
    limits: TorqueLimits,
    prev: SVector<f64, N>,
    /// Strap force of the previous step as each scenario saw it (the filtered measurement, or
    /// in the robust filter-aware mode its own Smith prediction); scenario `i`'s EKF maps it
    /// through its own strap geometry (`Jᵢᵀ F`, docs/MODEL.md §4).
    prev_force: Vec<SVector<f64, N>>,
    started: bool,
    /// Time of the last measurement the EKF bank used.
    last_t: f64,
    /// This step's measurement has estimated channels ([`Controller::step_estimated`]): the
    /// EKF banks update with the rows of `y = [q, qd]` of `update_rows` only.
    estimating: bool,
    /// The rows of `y` measured this step (not estimates).
    measured: [bool; NY],
    /// The previous step's measurement had estimated channels: the banks resume at this
    /// step's measurement.
    was_estimating: bool,
    /// This step's strap forces are estimates, and the gait period in steps if known.
    forces_estimated: bool,
    /// Consecutive steps with estimated strap forces (without a continuation of `d̂` the
    /// filters update over the first `REPLAY_AFTER_STEPS` of them, then the replay begins).
    forces_estimated_for: u32,
    /// This step the banks update their joint states with the measured rows and hold `d̂`:
    /// set by `replay_disturbance` while the replay, or the continuation at the gait
    /// frequency, continues the filters' last update.
    hold_disturbance: bool,
    /// This force fault has had a step on which the filters predicted without an update (no
    /// replay, or no row of `y` measured): their joint states have drifted, and the rest of
    /// the fault also predicts only.
    went_blind: bool,
    /// The previous step held `d̂` with every row of `y` measured: its joint states followed
    /// the measurement, so the banks do not restart them when the forces are measured again.
    held_last: bool,
    period: Option<usize>,
    /// The gait frequency (rad/s) at which the strap forces are continued this step
    /// ([`EstimatedChannels::gait_omega`]).
    gait_omega: Option<f64>,
    /// `d̂` carried by the gait while the forces are estimated (`replay_disturbance`).
    replay: DisturbanceReplay<N>,
    /// This step's measurement ends estimates handed over as measurements
    /// ([`EstimatedChannels::resume`]): the banks resume at it.
    resuming: bool,
    /// Robust extensions (`[controller] method = "robust"`); `None` = the paper's method.
    robust: Option<RobustState<N>>,
    /// The robust method's disturbance bank ([`RobustTuning::disturbance_lead`]): a copy of
    /// the bank stepped with the led strap force, whose `d̂ᵢ` the predictions take; its
    /// probabilities are not used. `None` = `d̂ᵢ` from `bank`.
    dbank: Option<EkfBank<N, NA, NY>>,
    /// The strap force the disturbance bank saw at the previous step, per scenario.
    prev_dforce: Vec<SVector<f64, N>>,
    /// The robust method's inertia gate ([`RobustTuning::inertia_engage_ratio`]; `None` =
    /// off), and whether the filter-aware mode was used on the previous step.
    gate: Option<InertiaGate>,
    filter_aware_prev: bool,
    /// The robust method's smoothed scenario weights ([`RobustSettings::weight_smoothing_s`]);
    /// `None` = the bank's probabilities (the paper's).
    smoother: Option<WeightSmoother>,
    /// The robust method's strap-model intent observer
    /// ([`RobustSettings::intent_estimate`]); `None` = the paper's eqs. 5-6.
    strap_intent: Option<StrapIntent<N>>,
    ekf: EkfSettings,
    estimator: EstimatorOptions,
}

impl<const N: usize, const NA: usize, const NY: usize> MultiStage<N, NA, NY> {
    /// A controller with one scenario per prediction model (each model's robot carries its
    /// payload), EKF settings, and the initial previous torque `t0`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        models: Vec<PredictionModel<N>>,
        settings: &NmpcSettings,
        ekf: &EkfSettings,
        estimator: &EstimatorOptions,
        options: MultiStageOptions,
        intent: IntentEstimator,
        limits: TorqueLimits,
        t0: SVector<f64, N>,
    ) -> Result<Self, MultiStageError> {
        limits.validate()?;
        if models.is_empty() {
            return Err(MultiStageError::NoScenario);
        }
        let robots: Vec<_> = models.iter().map(|m| m.robot).collect();
        let zero = SVector::zeros();
        let bank = EkfBank::new(&robots, ekf, estimator, &zero, &zero)?;
        let (cores, coupled) = match options.formulation {
            Formulation::Decoupled => (
                models
                    .iter()
                    .map(|m| NmpcCore::new(*m, settings))
                    .collect::<Result<Vec<_>, _>>()?,
                None,
            ),
            Formulation::Coupled => (
                Vec::new(),
                Some(CoupledCore::new(&models, settings, options.robust_horizon)?),
            ),
        };
        let s = models.len();
        let replay = DisturbanceReplay::new(s, models[0].dt);
        let empty = HorizonInputs {
            q_h: zero,
            qd_h: zero,
            t_int_measured: zero,
            disturbance: zero,
        };
        Ok(MultiStage {
            bank,
            cores,
            coupled,
            inputs: vec![empty; s],
            weights: vec![1.0 / s as f64; s],
            dist: vec![zero; s],
            models,
            options,
            intent,
            limits,
            prev: limits.admissible(&t0),
            prev_force: vec![zero; s],
            started: false,
            last_t: 0.0,
            estimating: false,
            measured: [true; NY],
            was_estimating: false,
            forces_estimated: false,
            forces_estimated_for: 0,
            hold_disturbance: false,
            went_blind: false,
            held_last: false,
            period: None,
            gait_omega: None,
            replay,
            resuming: false,
            robust: None,
            dbank: None,
            prev_dforce: vec![zero; s],
            gate: None,
            filter_aware_prev: false,
            smoother: None,
            strap_intent: None,
            ekf: *ekf,
            estimator: *estimator,
        })
    }

    /// Enable the robust extensions of [`RobustSettings`] for a sensor filter of `window`
    /// samples (see `control/robust.rs`); without this call the controller is the paper's.
    pub fn with_robust(mut self, settings: &RobustSettings, window: usize) -> Self {
        let r = RobustState::new(settings, window, self.models[0].dt);
        if r.disturbance_bank() {
            let mut ekf = self.ekf;
            if r.disturbance_q() > 0.0 {
                ekf.q_disturbance = r.disturbance_q();
            }
            let robots: Vec<_> = self.models.iter().map(|m| m.robot).collect();
            let zero = SVector::zeros();
            // The settings passed the paper's bank's checks in `new`, and `q_disturbance` is
            // positive, so this succeeds.
            self.dbank = EkfBank::new(&robots, &ekf, &self.estimator, &zero, &zero).ok();
            if self.dbank.is_some() {
                self.replay.add_second_bank();
            }
        }
        let tuning = &settings.tuning;
        if r.gated() && tuning.inertia_engage_ratio > 0.0 {
            let dt = self.models[0].dt;
            self.gate = Some(InertiaGate::new(
                &self.models,
                tuning.inertia_engage_ratio,
                (tuning.inertia_engage_s / dt).round() as usize,
            ));
        }
        self.strap_intent =
            (settings.intent_estimate == IntentEstimate::StrapObserver).then(|| {
                StrapIntent::new(
                    self.models.iter().map(|m| &m.straps),
                    window,
                    self.models[0].dt,
                    settings.human_bandwidth_hz,
                    settings.observer_velocity_gain,
                )
            });
        self.robust = Some(r);
        self.smoother = WeightSmoother::new(
            self.models.len(),
            self.models[0].dt,
            settings.weight_smoothing_s,
        );
        self
    }

    /// The EKF bank.
    pub fn bank(&self) -> &EkfBank<N, NA, NY> {
        &self.bank
    }

    /// The decoupled scenario cores (empty for the coupled formulation).
    pub fn cores(&self) -> &[NmpcCore<N>] {
        &self.cores
    }

    /// The current coupled decision vector (coupled formulation only).
    pub fn coupled_solution(&self) -> Option<&DVector<f64>> {
        self.coupled.as_ref().map(|c| &c.z)
    }

    /// Whether the coupled formulation uses the structured tree QP (`None` when decoupled).
    pub fn coupled_is_structured(&self) -> Option<bool> {
        self.coupled
            .as_ref()
            .map(|c| matches!(c.solver, CoupledSolver::Tree(_)))
    }

    fn hold(&self, status: StepStatus) -> ControlOutput<N> {
        ControlOutput {
            torque: self.prev,
            status,
            iterations: 0,
        }
    }
}

/// Why a multi-stage controller could not be built.
#[derive(Debug, thiserror::Error)]
pub enum MultiStageError {
    /// No scenario was given.
    #[error("the multi-stage controller needs at least one scenario")]
    NoScenario,
    /// Invalid torque limits.
    #[error(transparent)]
    Limits(#[from] LimitsError),
    /// Invalid estimator settings.
    #[error("estimator settings: {0}")]
    Estimator(#[from] EstimateError),
    /// Invalid solver settings.
    #[error(transparent)]
    Solver(#[from] SolverError),
}

/// Strap stretch and its rate whose force the Smith predictor removes (filter-aware mode).
type Stretch<const N: usize> = (SVector<f64, N>, SVector<f64, N>);

/// The named steps of [`Controller::step`] for [`MultiStage`], in the order it runs them.
impl<const N: usize, const NA: usize, const NY: usize> MultiStage<N, NA, NY> {
    /// Step 1: advance the EKF bank (and the robust method's disturbance bank) with
    /// `y = [q, qd]`, `T(k−1)` and each scenario's strap torque of step `k−1` (eqs. 10-11);
    /// on the first step, after skipped periods or back from estimated channels, restart the
    /// filters' joint states at the measurement instead (not back from a step on which every
    /// filter updated its joint states with every row while holding `d̂`: they followed the
    /// measurement). Returns whether this step follows such a gap (which also restarts the
    /// robust method's histories and the strap observer, `start_state`).
    fn advance_banks(&mut self, m: &Measurement<N>) -> bool {
        // Back from estimated channels: the filters resume at the measurement like after a gap,
        // unless their joint states followed it while `d̂` was replayed.
        let followed = self.held_last;
        let holding = self.hold_disturbance && self.measured.iter().all(|&m| m);
        self.held_last = false;
        let resync = (self.was_estimating && !self.estimating && !followed) || self.resuming;
        let skipped = self.skipped_periods(m);
        let gap = !self.started || skipped || resync;
        #[cfg(not(feature = "std"))]
        let ekf_start = crate::clock::Instant::now();
        if !self.started {
            self.bank.reset_to(&m.q, &m.qd);
            if let Some(b) = self.dbank.as_mut() {
                b.reset_to(&m.q, &m.qd);
            }
            self.started = true;
        } else if skipped || resync {
            // Periods were skipped (e.g. a supervisor rejected bad data): restart the filters'
            // joint states at the measurement, keep d̂ and the probabilities.
            self.bank.resume_at(&m.q, &m.qd);
            if let Some(b) = self.dbank.as_mut() {
                b.resume_at(&m.q, &m.qd);
            }
        } else {
            let updated = self.update_banks(m);
            self.held_last = holding && updated;
        }
        #[cfg(not(feature = "std"))]
        crate::clock::account(crate::clock::Part::EkfBank, ekf_start.elapsed());
        self.last_t = m.t;
        self.was_estimating = self.estimating;
        gap
    }

    /// Periods were skipped before `m` (e.g. a supervisor rejected bad data).
    fn skipped_periods(&self, m: &Measurement<N>) -> bool {
        self.started && m.t - self.last_t > 1.5 * self.models[0].dt
    }

    /// The banks' predict-and-update with `y = [q, qd]`: every row, or with estimated
    /// channels ([`Controller::step_estimated`]) the measured rows only (the probabilities
    /// kept). A failed filter keeps its state and the probabilities; the controller goes on.
    /// Returns whether every filter of both banks updated.
    fn update_banks(&mut self, m: &Measurement<N>) -> bool {
        let mut y = SVector::<f64, NY>::zeros();
        for a in 0..N {
            y[a] = m.q[a];
            y[N + a] = m.qd[a];
        }
        let (models, prev) = (&self.models, &self.prev);
        let (forces, dforces) = (&self.prev_force, &self.prev_dforce);
        if self.estimating {
            let rows = self.update_rows();
            let (measured, hold) = (&rows, self.hold_disturbance);
            let main = self
                .bank
                .step_masked_per_scenario(&y, measured, hold, prev, |i| {
                    models[i].straps.torque(&forces[i])
                });
            let second = self.dbank.as_mut().map_or(Ok(()), |b| {
                b.step_masked_per_scenario(&y, measured, hold, prev, |i| {
                    models[i].straps.torque(&dforces[i])
                })
            });
            main.is_ok() && second.is_ok()
        } else {
            let main = self
                .bank
                .step_per_scenario(&y, prev, |i| models[i].straps.torque(&forces[i]));
            let second = self.dbank.as_mut().map_or(Ok(()), |b| {
                b.step_per_scenario(&y, prev, |i| models[i].straps.torque(&dforces[i]))
            });
            main.is_ok() && second.is_ok()
        }
    }

    /// Step 2: the NMPC's start state `x0` and the measurement the intent estimate uses: the
    /// filtered one, or in the robust filter-aware mode (engaged by the oscillation detectors
    /// or the inertia gate) the bank's probability-weighted lag-free velocity, with the strap
    /// stretch whose force the Smith predictor removes; with the strap observer `x0` takes the
    /// lag-free velocity at every step. `gap` restarts the robust method's histories.
    fn start_state(
        &mut self,
        m: &Measurement<N>,
        gap: bool,
    ) -> (JointState<f64, N>, Measurement<N>, Option<Stretch<N>>) {
        let mut x0 = JointState { q: m.q, qd: m.qd };
        let mut mi = *m;
        let mut stretch = None;
        let heavy = match self.gate.as_mut() {
            Some(g) => g.update(self.bank.probabilities()),
            None => false,
        };
        if let Some(r) = self.robust.as_mut() {
            let engaged = r.observe(m, &self.prev, gap) || heavy;
            if engaged && !self.filter_aware_prev {
                r.restart_velocity();
            }
            self.filter_aware_prev = engaged;
            if engaged {
                let qd = self.bank.weighted_velocity();
                if qd.iter().all(|v| v.is_finite()) {
                    x0.qd = qd;
                    mi.qd = qd;
                    stretch = r.relative_motion(m, &qd);
                }
            }
        }
        if let Some(si) = self.strap_intent.as_mut() {
            si.update(m, gap);
            if stretch.is_none() {
                let qd = self.bank.weighted_velocity();
                if qd.iter().all(|v| v.is_finite()) {
                    x0.qd = qd;
                }
            }
        }
        (x0, mi, stretch)
    }

    /// Step 3: per scenario, the strap force its EKF takes at the next step (the filtered
    /// force, led by the robust method, or the Smith-predicted one of its own strap model
    /// when `stretch` is given), its disturbance estimate `d̂ᵢ` and its horizon inputs (the
    /// intent estimate of eqs. 5-6 from `mi`, or the strap observer's).
    fn scenario_inputs(
        &mut self,
        m: &Measurement<N>,
        mut mi: Measurement<N>,
        stretch: Option<Stretch<N>>,
    ) {
        let (ekf_force, dist_force) = match self.robust.as_mut() {
            Some(r) => r.ekf_forces(&m.force),
            None => (m.force, m.force),
        };
        for i in 0..self.models.len() {
            if let Some((dq, dqd)) = &stretch {
                mi.force = m.force - self.models[i].straps.force(dq, dqd);
                self.prev_force[i] = mi.force;
                self.prev_dforce[i] = mi.force;
            } else {
                self.prev_force[i] = ekf_force;
                self.prev_dforce[i] = dist_force;
            }
            self.dist[i] = match &self.dbank {
                Some(b) => b.disturbance(i),
                None => self.bank.disturbance(i),
            };
            self.inputs[i] = horizon_inputs(&self.intent, &self.models[i], &mi, self.dist[i]);
            if let Some(si) = self.strap_intent.as_ref() {
                if let Some((q_h, qd_h)) = si.estimate(i, m) {
                    self.inputs[i].q_h = q_h;
                    self.inputs[i].qd_h = qd_h;
                }
            }
        }
    }

    /// Step 4: the scenario weights of the costs (eq. 12): the bank's probabilities, or the
    /// robust method's low-passed ones.
    fn update_weights(&mut self) {
        match self.smoother.as_mut() {
            Some(sm) => sm.apply(self.bank.probabilities(), &mut self.weights),
            None => self.weights.copy_from_slice(self.bank.probabilities()),
        }
    }

    /// Step 5 (decoupled): every scenario's NMPC of eq. 7 from `x0`, in parallel with rayon
    /// when `parallel` is set (and `std` is on), else in turn.
    fn solve_scenarios(&mut self, x0: JointState<f64, N>) {
        let (prev, limits, inputs) = (self.prev, self.limits, &self.inputs);
        let solve =
            |(i, core): (usize, &mut NmpcCore<N>)| core.solve(x0, prev, inputs[i], &limits).status;
        #[cfg(feature = "std")]
        let parallel = self.options.parallel;
        #[cfg(not(feature = "std"))]
        let parallel = false; // no threads without std: the scenarios run in turn
        if parallel {
            #[cfg(feature = "std")]
            self.cores.par_iter_mut().enumerate().for_each(|p| {
                solve(p);
            });
        } else {
            self.cores.iter_mut().enumerate().for_each(|p| {
                solve(p);
            });
        }
    }

    /// Step 6 (decoupled): eq. 13 over the scenarios whose solve is usable, renormalised:
    /// the desired torque `T(k−1) + Σ wᵢ dTᵢ / Σ wᵢ`, the worst status and the iterations.
    fn blend_increments(&self) -> (SVector<f64, N>, StepStatus, u32) {
        let prev = self.prev;
        let mut sum = SVector::<f64, N>::zeros();
        let (mut wsum, mut iters) = (0.0, 0u32);
        let mut worst = StepStatus::Ok;
        for (i, core) in self.cores.iter().enumerate() {
            let (st, usable) = classify(core.info.status);
            iters += core.info.iterations as u32;
            if st != StepStatus::Ok && worst != StepStatus::SolverFailed {
                worst = st;
            }
            if usable {
                sum += core.first_increment() * self.weights[i];
                wsum += self.weights[i];
            }
        }
        if wsum > 0.0 {
            (prev + sum / wsum, worst, iters)
        } else {
            (prev, StepStatus::SolverFailed, iters)
        }
    }

    /// Record which channels of this step are estimates. The filters update with the measured
    /// rows of `y = [q, qd]` (`update_rows`), and while a strap force (the filters' input) is
    /// estimated, with those over its first [`REPLAY_AFTER_STEPS`] steps only; after them an
    /// estimate drifting from the force would move `d̂`, so no row (the filters predict
    /// without an update, `d̂` held), unless `replay_disturbance` carries `d̂` (the replay, or
    /// the continuation from the fault's first step) and the measured rows update the joint
    /// states alone. The probabilities are kept throughout.
    fn mark_estimated(&mut self, estimated: &EstimatedChannels<N>) {
        let force = estimated.any_force();
        self.forces_estimated = force;
        self.forces_estimated_for = if force {
            self.forces_estimated_for.saturating_add(1)
        } else {
            0
        };
        self.period = estimated.period;
        self.gait_omega = estimated.gait_omega;
        self.estimating = estimated.any();
        self.resuming = estimated.resume;
        for a in 0..N {
            self.measured[a] = !estimated.q[a];
            self.measured[N + a] = !estimated.qd[a];
        }
        if force && !self.measured.iter().any(|&m| m) {
            self.went_blind = true;
        }
    }

    /// The rows of `y` the banks update with this step (`mark_estimated`): the measured ones,
    /// none after the first [`REPLAY_AFTER_STEPS`] steps of estimated forces unless `d̂` is
    /// held for the replay.
    fn update_rows(&self) -> [bool; NY] {
        let blind = self.forces_estimated
            && self.forces_estimated_for > REPLAY_AFTER_STEPS
            && !self.hold_disturbance;
        self.measured.map(|m| m && !blind)
    }

    /// While the strap forces are estimated for more than [`REPLAY_AFTER_STEPS`] (the filters
    /// would update `d̂ᵢ` from an estimate) and the gait period `p` is known: every bank's
    /// `d̂ᵢ` replays the gait one period back,
    /// `d̂ᵢ(k) = d̂ᵢ(k − p) + d̂ᵢ(k_u) − d̂ᵢ(k_u − p)` (`k_u` the step of the filters' last
    /// update: the step before the replay's first, unless the period was unknown then).
    /// `d̂ᵢ` carries the model's error along the gait (beyond the scenarios' payloads it
    /// changes by up to 0.7 N·m per step), and the held value drove the robot away from the
    /// leg (issue 28, docs/RELIABILITY.md §2a). While the replay continues the filters' last
    /// update (no step of this fault predicted without one), the banks hold `d̂ᵢ` and update
    /// their joint states with the measured rows: the NMPC starts from the filters' velocity,
    /// and predicted alone it drifted by 0.1-0.2 rad/s within a 200-ms fault at 3 kg. While
    /// the forces follow their continuation (`EstimatedChannels::gait_omega`; before the
    /// period is known, or fitted to measurements alone) `d̂ᵢ` is continued at the gait
    /// frequency instead (`continue_disturbance`, from the fault's first step), and the
    /// replay continues from it. Without either the filters update over the fault's first
    /// [`REPLAY_AFTER_STEPS`] steps, then predict only: with a held `d̂ᵢ`
    /// the measured rows would pull the joint states along the gait's disturbance instead
    /// (measured, docs/RELIABILITY.md §2).
    // Out of line: kept out of `step`'s stack frame (the Cortex-M7 image's stack peak).
    #[inline(never)]
    fn replay_disturbance(&mut self) {
        if !self.forces_estimated {
            self.forces_estimated_for = 0;
            self.went_blind = false;
        }
        let r = &mut self.replay;
        // Steps since the filters' last update (the replay's anchor).
        let since = self.forces_estimated_for.saturating_sub(REPLAY_AFTER_STEPS) as usize;
        let p = match self.period {
            Some(p)
                if self.forces_estimated
                    && self.forces_estimated_for > REPLAY_AFTER_STEPS
                    && r.holds(p + 1)
                    && self.gait_omega.is_none() =>
            {
                p
            }
            _ => {
                let after = self.forces_estimated && self.forces_estimated_for > REPLAY_AFTER_STEPS;
                // With the forces on their continuation `d̂ᵢ` is continued from the fault's
                // first step: the filters' updates on the estimated forces moved it away from
                // the gait (docs/RELIABILITY.md §2).
                let forces_continued = self.forces_estimated && self.gait_omega.is_some();
                if !((after || forces_continued) && !self.went_blind && self.continue_disturbance())
                {
                    if after {
                        self.went_blind = true;
                    }
                    if self.forces_estimated {
                        self.replay.stop();
                    } else {
                        self.replay.end_fault();
                    }
                }
                return;
            }
        };
        // A continuation within this fault is over; the replay continues its `d̂`.
        r.started = 0;
        r.set_period(p);
        if !self.went_blind && self.measured.iter().any(|&m| m) {
            self.hold_disturbance = true;
        }
        self.set_disturbances(|r, b, i, _, d| Some(r.replayed(b, i, d, since)));
    }

    /// Set every bank's `d̂ᵢ` to `f(replay, bank, scenario, index, d̂ᵢ)` where it gives one
    /// (`index` counts the filters in bank-major order).
    fn set_disturbances(
        &mut self,
        mut f: impl FnMut(
            &mut DisturbanceReplay<N>,
            usize,
            usize,
            usize,
            &SVector<f64, N>,
        ) -> Option<SVector<f64, N>>,
    ) {
        let mut k = 0;
        for b in 0..2 {
            let bank = match b {
                0 => &mut self.bank,
                _ => match self.dbank.as_mut() {
                    Some(d) => d,
                    None => continue,
                },
            };
            for i in 0..bank.len() {
                if let Some(d) = f(&mut self.replay, b, i, k, &bank.disturbance(i)) {
                    bank.set_disturbance(i, &d);
                }
                k += 1;
            }
        }
    }

    /// While the strap forces follow their continuation at the gait frequency ω
    /// ([`EstimatedChannels::gait_omega`], for at most [`FORCE_FIT_S`](super::FORCE_FIT_S);
    /// with the gait period known only for a continuation fitted to measurements alone):
    /// every bank's `d̂ᵢ` is continued at ω as well, from the fault's first step
    /// (`a + Σ_{h=1,2} (b_h sin hωτ + c_h cos hωτ)` fitted to its last
    /// [`EXTRAPOLATION_FIT_S`](super::EXTRAPOLATION_FIT_S) on that step, started at the
    /// filters' last update, the step before), and the banks hold it and update their joint
    /// states with the measured rows, as during the replay. Begun after [`REPLAY_AFTER_STEPS`]
    /// filter updates on the estimated forces, it started from a `d̂ᵢ` they had moved off the
    /// gait (docs/RELIABILITY.md §2: a 200-ms NaN of both forces at 1 s, 3 kg, 12.5 N, from
    /// the first step 11.8 N). Held instead, `d̂ᵢ` stood still while at 3 kg it moves by
    /// up to 0.7 N·m per step along the gait (docs/RELIABILITY.md §2); replayed one gait
    /// period back, it carried another gait early in the run (the human grows heavier,
    /// docs/MODEL.md §2: a 200-ms NaN of both forces at 2.25 s, 3 kg, 20.4 N, continued
    /// 14.1 N, with the forces' blend 9.9 N). `false` without a continuation (no ω, or too short
    /// a history): over the fault's first [`REPLAY_AFTER_STEPS`] steps the filters then update
    /// `d̂ᵢ`, after them it is held (a continuation that can be fitted only from a later step
    /// of the fault starts there).
    // Out of line, as `replay_disturbance`.
    #[inline(never)]
    fn continue_disturbance(&mut self) -> bool {
        let Some(omega) = self.gait_omega else {
            return false;
        };
        let r = &mut self.replay;
        if r.period != 0 {
            r.stop();
        }
        if r.started == 0 {
            r.fit_steps = 0;
        }
        let Some(n) = r.fit_span() else {
            r.started = 0;
            return false;
        };
        // A filter whose fit is not finite keeps its `d̂ᵢ`.
        self.set_disturbances(|r, b, i, k, d| r.continued(k, b, i, d, omega, n));
        let r = &mut self.replay;
        r.fit_steps = r.fit_steps.saturating_add(1);
        r.continued = true;
        if self.measured.iter().any(|&m| m) {
            self.hold_disturbance = true;
        }
        true
    }

    /// Record this step's `d̂ᵢ` of every bank for `replay_disturbance`. While the forces are
    /// estimated and the history holds one gait period `p`, the history continues the gait
    /// instead: it records its own value of `p` steps back, so the replay reads the gait
    /// before the fault however long the fault lasts (recording the replayed `d̂ᵢ`, which
    /// carries the replay's offset, would add that offset again every period).
    // Out of line, as `replay_disturbance`.
    #[inline(never)]
    fn record_disturbance(&mut self) {
        let r = &mut self.replay;
        let p = match self.period {
            Some(p) if self.forces_estimated && r.holds(p) => Some(p),
            _ => None,
        };
        for i in 0..self.bank.len() {
            r.record_step(0, i, &self.bank.disturbance(i), p);
            if let Some(db) = self.dbank.as_ref() {
                r.record_step(1, i, &db.disturbance(i), p);
            }
        }
        r.count = r.count.saturating_add(1);
    }
}

impl<const N: usize, const NA: usize, const NY: usize> Controller<N> for MultiStage<N, NA, NY> {
    /// One control step in named steps: `replay_disturbance` (while the forces are
    /// estimated), `advance_banks` (EKF banks), `record_disturbance`, `start_state`,
    /// `scenario_inputs`, `update_weights`, then the coupled solve (`CoupledCore::first_torque`)
    /// or every scenario's (`solve_scenarios`) blended by eq. 13 (`blend_increments`), and the
    /// hard limits of eqs. 8-9.
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N> {
        if !m.is_finite() {
            return self.hold(StepStatus::BadMeasurement);
        }
        // After skipped periods the history restarts (it is no longer one sample per period).
        if self.skipped_periods(m) {
            self.replay.count = 0;
        }
        self.replay_disturbance();
        let gap = self.advance_banks(m);
        self.record_disturbance();
        let (x0, mi, stretch) = self.start_state(m, gap);
        self.scenario_inputs(m, mi, stretch);
        self.update_weights();
        let prev = self.prev;
        let (desired, status, iterations) = match self.coupled.as_mut() {
            Some(c) => c.first_torque(x0, prev, &self.inputs, &self.weights, &self.limits),
            None => {
                self.solve_scenarios(x0);
                self.blend_increments()
            }
        };
        let torque = self.limits.clamp(&prev, &desired);
        self.prev = torque;
        ControlOutput {
            torque,
            status,
            iterations,
        }
    }

    fn name(&self) -> &'static str {
        "msnmpc"
    }

    fn probabilities(&self) -> Option<&[f64]> {
        Some(self.bank.probabilities())
    }

    fn disturbance(&self, i: usize) -> Option<SVector<f64, N>> {
        self.dist.get(i).copied()
    }

    fn previous_torque(&self) -> SVector<f64, N> {
        self.prev
    }

    /// Eq. 13 over the horizon: the probability-weighted increments of the usable scenario
    /// solves (decoupled formulation; the coupled one plans nothing here).
    fn planned_torques(&self, out: &mut [SVector<f64, N>]) -> usize {
        if self.coupled.is_some() {
            return 0;
        }
        let usable = |c: &NmpcCore<N>| classify(c.info.status).1;
        let wsum: f64 = self
            .cores
            .iter()
            .zip(&self.weights)
            .filter(|(c, _)| usable(c))
            .map(|(_, w)| *w)
            .sum();
        if wsum.is_nan() || wsum <= 0.0 {
            return 0;
        }
        super::plan_from(&self.prev, &self.limits, out, |j| {
            let mut sum = SVector::<f64, N>::zeros();
            for (c, w) in self.cores.iter().zip(&self.weights) {
                if usable(c) {
                    sum += c.increment(j)? * *w;
                }
            }
            Some(sum / wsum)
        })
    }

    fn set_previous_torque(&mut self, t: SVector<f64, N>) {
        self.prev = self.limits.admissible(&t);
    }

    /// The EKF bank's probability-weighted one-period prediction under the applied torque.
    fn predicted_state(&self) -> Option<(SVector<f64, N>, SVector<f64, N>)> {
        if !self.started {
            return None;
        }
        let (models, forces) = (&self.models, &self.prev_force);
        let (q, qd) = self
            .bank
            .weighted_prediction(&self.prev, |i| models[i].straps.torque(&forces[i]));
        (q.iter().chain(qd.iter()).all(|v| v.is_finite())).then_some((q, qd))
    }

    fn step_estimated(
        &mut self,
        m: &Measurement<N>,
        estimated: &EstimatedChannels<N>,
    ) -> ControlOutput<N> {
        self.mark_estimated(estimated);
        let out = self.step(m);
        self.estimating = false;
        self.hold_disturbance = false;
        self.forces_estimated = false;
        self.period = None;
        self.gait_omega = None;
        self.resuming = false;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The slotted `f32` history reads a gait-like `d̂` (1 Hz and its second harmonic, N·m)
    /// back to within 1.5 % of its swing at every lag it holds, and says which lags it holds.
    #[test]
    fn the_disturbance_history_reads_back_between_its_slots() {
        let dt = 0.01;
        let d = |k: usize| {
            let t = k as f64 * dt;
            let w = core::f64::consts::TAU;
            SVector::<f64, 2>::from([
                8.0 * (w * t).sin() + 2.0 * (2.0 * w * t + 0.3).cos(),
                -3.0 + 5.0 * (w * t - 1.0).cos(),
            ])
        };
        let mut r = DisturbanceReplay::<2>::new(3, dt);
        assert_eq!(r.stride, 4);
        r.add_second_bank();
        let steps = 1000;
        for k in 0..steps {
            for b in 0..2 {
                for i in 0..3 {
                    r.record(b, i, &(d(k) * (1.0 + (b + i) as f64)));
                }
            }
            r.count += 1;
        }
        let history = (ChannelGuard::<2>::HISTORY_S / dt).round() as usize;
        assert!(!r.holds(r.stride) && r.holds(r.stride + 1));
        assert!(r.holds(history) && !r.holds(history + 2 * r.stride));
        for k in (r.stride + 1)..=history {
            for (b, i) in [(0, 0), (1, 2)] {
                let scale = 1.0 + (b + i) as f64;
                let err = r.back(b, i, k) - d(steps - k) * scale;
                assert!(
                    err.amax() <= 0.015 * 10.0 * scale,
                    "bank {b}, scenario {i}, {k} back: {err:?}"
                );
            }
        }
        // A restarted history holds nothing until it has recorded past the lag.
        r.count = 0;
        assert!(!r.holds(r.stride + 1));
    }

    /// A 1-Hz gait of `d̂` (amplitude 6 on the first joint, `c` on the second) at 10 ms.
    fn sine_gait(k: usize, c: f64) -> SVector<f64, 2> {
        let t = k as f64 * 0.01;
        SVector::<f64, 2>::from([6.0 * (core::f64::consts::TAU * t).sin(), c])
    }

    /// A replay history holding the first 400 steps of `sine_gait(·, c)`.
    fn recorded_gait(c: f64) -> DisturbanceReplay<2> {
        let mut r = DisturbanceReplay::<2>::new(1, 0.01);
        for k in 0..400 {
            r.record_step(0, 0, &sine_gait(k, c), None);
            r.count += 1;
        }
        r
    }

    /// The replay over a fault of several gait periods repeats the gait before the fault with
    /// one offset: `d̂(k) − d̂(k − p)` stays near zero from the second period on. Recording the
    /// replayed `d̂` instead of the continued gait added the offset again every period (2 N·m
    /// here, the `d̂` held 2 N·m off the gait when the replay began).
    #[test]
    fn the_replay_repeats_the_gait_without_drift() {
        let p = 100;
        let gait = |k: usize| sine_gait(k, 1.0);
        let mut r = recorded_gait(1.0);
        let mut current = gait(399) + SVector::from([2.0, 2.0]);
        let mut out = Vec::new();
        r.set_period(p);
        for _ in 0..350 {
            assert!(r.holds(p + 1));
            current = r.replayed(0, 0, &current, 1);
            out.push(current);
            r.record_step(0, 0, &current, Some(p));
            r.count += 1;
        }
        for k in p..out.len() {
            let drift = (out[k] - out[k - p]).amax();
            assert!(drift <= 0.05, "{k} steps into the replay: {drift}");
        }
        // It starts where d̂ was: one step of the gait away.
        assert!((out[0] - (gait(399) + SVector::from([2.0, 2.0]))).amax() <= 0.5);
    }

    /// The filters update over the first steps of a force fault (their `d̂` follows the gait,
    /// here 0.3 off it), then the replay continues
    /// the gait from their last update: at once (one step of the gait on, no step), or, when
    /// the period became known only 4 steps later (`d̂` held and recorded meanwhile), where
    /// the gait is by then. Anchored at the fault's start (the rule while `d̂` was held over
    /// the first steps) it stepped by the gait's change over them (1.9 here); anchored one
    /// period and one step back, the late replay stayed at the held value, 1.4 off.
    #[test]
    fn the_replay_continues_the_gait_from_the_filters_last_update() {
        let p = 100;
        let updated = |k: usize| sine_gait(k, 0.5) + SVector::from([0.3, 0.3]);
        for late in [0usize, 4] {
            let mut r = recorded_gait(0.5);
            // The forces are lost from step 400; while the period is known the history records
            // the gait continued, else the filters' `d̂`.
            let last = 400 + REPLAY_AFTER_STEPS as usize - 1;
            let known = (late == 0).then_some(p);
            for k in 400..=last {
                r.record_step(0, 0, &updated(k), known);
                r.count += 1;
            }
            // No period known for `late` steps: `d̂` held, recorded as it is.
            for _ in 0..late {
                r.record_step(0, 0, &updated(last), None);
                r.count += 1;
            }
            r.set_period(p);
            let mut current = updated(last);
            for k in last + 1 + late..last + 50 {
                current = r.replayed(0, 0, &current, k - last);
                // Within the history slots' interpolation (40 ms of a 6-N·m, 1-Hz gait).
                let err = (current - updated(k)).amax();
                assert!(
                    err <= 0.15,
                    "{late} late, step {k}: {current} against {}",
                    updated(k)
                );
                r.record_step(0, 0, &current, Some(p));
                r.count += 1;
            }
        }
    }

    /// A new gait-period estimate within a replay restarts it where it is: no step.
    #[test]
    fn a_new_period_within_the_replay_does_not_step_it() {
        let gait = |k: usize| sine_gait(k, 1.0);
        let mut r = recorded_gait(1.0);
        let mut current = gait(399);
        let mut largest: f64 = 0.0;
        for step in 0..80 {
            // The period estimate changes from 100 to 94 steps 45 steps into the replay,
            // where the gait moves fast.
            let p = if step < 45 { 100 } else { 94 };
            r.set_period(p);
            let next = r.replayed(0, 0, &current, 1);
            largest = largest.max((next - current).amax());
            current = next;
            r.record_step(0, 0, &current, Some(p));
            r.count += 1;
        }
        // The gait moves by at most 6·2π·0.01 ≈ 0.38 per step.
        assert!(largest <= 0.45, "the replay stepped by {largest}");
    }
}
