//! Structure-exploiting Gauss–Newton SQP for the coupled scenario tree (paper eq. 12 with
//! non-anticipativity; [`super::Formulation::Coupled`]): every scenario's eq.-7 problem in the
//! multiple-shooting stages of [`super::ocp`] (state `x = [q, qd, T]`, input `dT`), all scenarios
//! sharing the first `Nr = robust_horizon` inputs, solved with the block-arrowhead QP
//! [`crate::solver::TreeQp`].
//!
//! The cost is `Σ_i μ_i ½‖r_i‖²` (`r_i` scenario `i`'s residuals of eq. 7, `μ_i` its probability,
//! eqs. 10–11), so scenario `i`'s stage weights are `μ_i Q`, `μ_i r_t I`, and a shared input's
//! weight is `Σ_i μ_i r_t I`. The condensed form of the step QP is exactly the dense
//! Gauss–Newton QP of the coupled NLP (`control::multistage::CoupledProblem` with
//! [`crate::solver::Sqp`]), including its regularisation `δ = hessian_regularization ·
//! (1 + max diag JᵀJ)`, so both back-ends take the same steps; the cumulative torque bound of
//! eq. 8 on a shared stage is imposed once (scenario 1's copy), the other copies are
//! identical.

use super::nmpc_problem::QpBackend;
use super::nmpc_problem::{NmpcProblem, NmpcSettings};
use super::ocp::{copy_step, stage_residual, stage_steps, write_stage_jacobian, StepBounds};
use super::prediction::StepJacobian;
use super::TorqueLimits;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::JointState;
use crate::solver::engine::{self, finite_or_inf, BoundCheck, SqpSteps};
use crate::solver::{QpInfo, SolverError, SqpInfo, SqpSettings, SqpStatus, TreeQp};
use alloc::{vec, vec::Vec};
use nalgebra::DVector;

/// Smallest number of coupled decision variables `N·(Nr + S·(Nc − Nr))` for which
/// [`QpBackend::Auto`] picks the tree QP for the coupled formulation (measured with
/// `exompc bench`, docs/PERFORMANCE.md).
pub const AUTO_TREE_MIN_VARS: usize = 16;

/// Whether `backend` resolves to the tree QP for a coupled problem with `n_vars` decision
/// variables.
pub fn tree_is_structured(backend: QpBackend, n_vars: usize) -> bool {
    match backend {
        QpBackend::Dense => false,
        QpBackend::Structured => true,
        QpBackend::Auto => n_vars >= AUTO_TREE_MIN_VARS,
    }
}

/// Gauss–Newton SQP over the scenario tree with the block-arrowhead QP. It runs the SQP engine
/// of [`crate::solver::Sqp`] (`solver/engine.rs`) with a tree back-end and reproduces the dense
/// coupled iterates with `HessianModel::GaussNewton`, at `O(S·Np·N³)` per iteration instead of
/// `O((S·Nc·N)³)`. Decision vector as the dense coupled problem's: `[shared increments (N·Nr),
/// scenario 1's remaining increments (N·(Nc − Nr)), …, scenario S's]`. All workspace is
/// allocated in [`TreeSqp::new`]; [`TreeSqp::solve`] allocates nothing and never panics.
#[derive(Clone, Debug)]
pub struct TreeSqp<const N: usize> {
    settings: SqpSettings,
    z_trial: DVector<f64>,
    w: TreeWork<N>,
}

/// Workspace of the tree back-end.
#[derive(Clone, Debug)]
struct TreeWork<const N: usize> {
    np: usize,
    nc: usize,
    nr: usize,
    ns: usize,
    r_d: f64,
    r_t: f64,
    hessian_regularization: f64,
    qp: TreeQp,
    weights: Vec<f64>,
    /// Cumulative torques `T_{i,j}` (`T` part of `x_{i,j+1}`, `j < Nc`) at the current iterate,
    /// at `(i·Nc + j)·N`.
    torques: Vec<f64>,
    torques_trial: Vec<f64>,
    dz: DVector<f64>,
    /// Gradient in trajectory layout at the current point.
    grad: Vec<f64>,
    costate: Vec<f64>,
    shared_stat: Vec<f64>,
    zi: Vec<f64>,
    /// The box of the step (from the solve's limits).
    bounds: StepBounds,
}

impl<const N: usize> TreeSqp<N> {
    /// Allocates the workspace for `scenarios ≥ 1` scenarios with the horizon and weights of
    /// `s`, sharing the first `robust_horizon` increments (clamped to `1..=Nc`).
    pub fn new(
        s: &NmpcSettings,
        robust_horizon: usize,
        scenarios: usize,
    ) -> Result<Self, SolverError> {
        s.sqp.validate()?;
        let (np, nc) = (s.np, s.nc);
        let nr = robust_horizon.clamp(1, nc.max(1));
        let qp = TreeQp::new(3 * N, N, np, nc, nr, scenarios, s.sqp.qp)?;
        let (len, nv) = (qp.len(), qp.num_inputs());
        Ok(Self {
            settings: s.sqp,
            z_trial: DVector::zeros(nv),
            w: TreeWork {
                np,
                nc,
                nr,
                ns: scenarios,
                r_d: s.r_d,
                r_t: s.r_t,
                hessian_regularization: s.sqp.hessian_regularization,
                qp,
                weights: vec![0.0; scenarios],
                torques: vec![0.0; scenarios * nc * N],
                torques_trial: vec![0.0; scenarios * nc * N],
                dz: DVector::zeros(nv),
                grad: vec![0.0; len],
                costate: vec![0.0; 6 * N],
                shared_stat: vec![0.0; nr * N],
                zi: vec![0.0; nc * N],
                bounds: StepBounds::default(),
            },
        })
    }

    /// Number of decision variables `N·(Nr + S·(Nc − Nr))`.
    pub fn num_vars(&self) -> usize {
        self.w.qp.num_inputs()
    }

    /// The QP solver (its last solution and multipliers).
    pub fn qp(&self) -> &TreeQp {
        &self.w.qp
    }

    /// Solves the coupled problem for the scenarios `problems` (their `x0`, `t_prev`, `inputs`)
    /// with probabilities `weights` under `limits` from the warm start `z` (overwritten with the
    /// result). Statuses as in [`crate::solver::Sqp::solve`]; wrong counts or lengths give
    /// `DimensionMismatch`, negative or non-finite weights `NonFiniteInput`.
    pub fn solve(
        &mut self,
        problems: &[NmpcProblem<N>],
        weights: &[f64],
        limits: &TorqueLimits,
        z: &mut DVector<f64>,
    ) -> SqpInfo {
        let mut steps = TreeSteps {
            w: &mut self.w,
            problems,
            weights,
            limits,
        };
        engine::solve(&mut steps, &self.settings, &mut self.z_trial, z)
    }
}

/// The tree back-end of the engine for one solve.
struct TreeSteps<'a, const N: usize> {
    w: &'a mut TreeWork<N>,
    problems: &'a [NmpcProblem<N>],
    weights: &'a [f64],
    limits: &'a TorqueLimits,
}

impl<const N: usize> TreeWork<N> {
    fn nsh(&self) -> usize {
        self.nr * N
    }

    fn npr(&self) -> usize {
        (self.nc - self.nr) * N
    }

    /// Scenario `i`'s increments from the coupled decision vector into `zi`.
    fn gather(&mut self, z: &[f64], i: usize) {
        let (sh, pr) = (self.nsh(), self.npr());
        self.zi[..sh].copy_from_slice(&z[..sh]);
        self.zi[sh..].copy_from_slice(&z[sh + i * pr..sh + (i + 1) * pr]);
    }

    /// `R̄ = (Σ μ_i r) I + δ I` on the shared inputs, `R_i = μ_i r I + δ I` on the private ones.
    fn set_input_weights(&mut self, r: f64, weighted: bool, delta: f64) {
        let total: f64 = if weighted {
            self.weights.iter().sum()
        } else {
            1.0
        };
        for rj in self.qp.r_shared.chunks_exact_mut(N * N) {
            rj.fill(0.0);
            for a in 0..N {
                rj[a * N + a] = total * r + delta;
            }
        }
        let per = self.nc - self.nr;
        for (k, rk) in self.qp.data.r.chunks_exact_mut(N * N).enumerate() {
            let mu = if weighted { self.weights[k / per] } else { 1.0 };
            rk.fill(0.0);
            for a in 0..N {
                rk[a * N + a] = mu * r + delta;
            }
        }
    }

    /// Simulates every scenario from its `x0` with its increments from `z`; with `jac`, fills the
    /// QP's dynamics matrices and gradient. Writes the cumulative torques into `torques_trial` and
    /// returns the cost `Σ μ_i ½‖r_i‖²` (non-finite when anything is).
    fn evaluate(&mut self, problems: &[NmpcProblem<N>], z: &[f64], jac: bool) -> f64 {
        let nx = 3 * N;
        let (np, nc) = (self.np, self.nc);
        let sqrt_rd = self.r_d.sqrt();
        let sqrt_rt = self.r_t.sqrt();
        let nv = self.qp.num_inputs();
        let mut total = 0.0;
        let mut finite = true;
        for (i, problem) in problems.iter().enumerate() {
            let mu = self.weights[i];
            self.gather(z, i);
            let dt = problem.model.dt;
            let inp = problem.inputs;
            let mut x = problem.x0;
            let mut u = problem.t_prev;
            let mut sum = 0.0;
            let consts = problem.model.jacobian_constants();
            for j in 0..np {
                if j < nc {
                    for a in 0..N {
                        u[a] += self.zi[j * N + a];
                        self.torques_trial[(i * nc + j) * N + a] = u[a];
                    }
                }
                let tau = j as f64 * dt;
                x = if jac {
                    let (xn, g): (JointState<f64, N>, StepJacobian<N>) = problem
                        .model
                        .tailored(&consts, &inp, &u)
                        .step_with_jacobian(&x, tau);
                    let ao = (i * np + j) * nx * nx;
                    let aj = &mut self.qp.data.a[ao..ao + nx * nx];
                    aj.fill(0.0);
                    for c in 0..N {
                        aj[(2 * N + c) * nx + 2 * N + c] = 1.0;
                    }
                    let bj = (j < nc).then(|| {
                        let bo = (i * nc + j) * nx * N;
                        let bj = &mut self.qp.data.b[bo..bo + nx * N];
                        bj.fill(0.0);
                        for c in 0..N {
                            bj[c * nx + 2 * N + c] = 1.0;
                        }
                        bj
                    });
                    write_stage_jacobian(&g, aj, bj);
                    xn
                } else {
                    problem.model.step_value_using(&consts, &x, &u, tau, &inp)
                };
                let tj = (j + 1) as f64 * dt;
                let xo = nv + (i * np + j) * nx;
                let grad = jac.then(|| (mu, &mut self.qp.data.g[xo..xo + nx]));
                finite &= stage_residual(problem, &x, tj, sqrt_rd, &mut sum, grad);
            }
            for zk in &self.zi {
                let rz = sqrt_rt * zk;
                sum += rz * rz;
            }
            total += mu * sum;
        }
        if jac {
            let (sh, pr) = (self.nsh(), self.npr());
            let wsum: f64 = self.weights.iter().sum();
            for (g, zk) in self.qp.data.g[..sh].iter_mut().zip(&z[..sh]) {
                *g = wsum * self.r_t * zk;
            }
            for i in 0..self.ns {
                for k in 0..pr {
                    let idx = sh + i * pr + k;
                    self.qp.data.g[idx] = self.weights[i] * self.r_t * z[idx];
                }
            }
            finite &= self.qp.data.a.iter().all(|v| v.is_finite())
                && self.qp.data.b.iter().all(|v| v.is_finite());
        }
        if finite {
            0.5 * total
        } else {
            f64::NAN
        }
    }

    /// The trial point becomes the current one (its torques and gradient).
    fn accept(&mut self) {
        self.torques.copy_from_slice(&self.torques_trial);
        self.grad.copy_from_slice(&self.qp.data.g);
    }

    /// The QP (linear term written by the caller) with the step-space bounds at `z`, its step
    /// copied into `dz`.
    fn solve_step(&mut self, z: &DVector<f64>) -> QpInfo {
        self.shift_bounds(z);
        let qi = self.qp.solve();
        copy_step(&mut self.dz, self.qp.solution());
        qi
    }

    /// Step-space bounds of the QP at `z` (with `torques` the cumulative torques at `z`); a
    /// shared stage's torque bound only on scenario 1.
    fn shift_bounds(&mut self, z: &DVector<f64>) {
        self.bounds
            .shift_inputs(z, &mut self.qp.data.lo, &mut self.qp.data.hi);
        for i in 0..self.ns {
            for j in 0..self.nc {
                for a in 0..N {
                    let x = self.qp.x_index(i, j + 1, 2 * N + a);
                    if j < self.nr && i > 0 {
                        self.qp.data.lo[x] = f64::NEG_INFINITY;
                        self.qp.data.hi[x] = f64::INFINITY;
                    } else {
                        let t = self.torques[(i * self.nc + j) * N + a];
                        self.qp.data.lo[x] = -self.bounds.tmax - t;
                        self.qp.data.hi[x] = self.bounds.tmax - t;
                    }
                }
            }
        }
    }

    /// KKT residual at `z` with the last QP multipliers: stationarity by an adjoint sweep per
    /// scenario (the shared inputs summing every scenario's part), box and cumulative violation,
    /// complementarity. Returns `(kkt, violation)`.
    fn kkt(&mut self, z: &DVector<f64>) -> (f64, f64) {
        let nx = 3 * N;
        let (np, nc, nr) = (self.np, self.nc, self.nr);
        let nv = self.qp.num_inputs();
        let mult = self.qp.multipliers();
        let (mu, next) = self.costate.split_at_mut(nx);
        let mut stat: f64 = 0.0;
        for ((s, g), m) in self.shared_stat.iter_mut().zip(&self.grad).zip(mult) {
            *s = g + m;
        }
        for i in 0..self.ns {
            next.fill(0.0);
            for j in (0..np).rev() {
                // μ_{j+1} = g_x + mult_x + A_{j+1}ᵀ μ_{j+2}.
                let xo = nv + (i * np + j) * nx;
                for c in 0..nx {
                    let mut s = self.grad[xo + c] + mult[xo + c];
                    if j + 1 < np {
                        let ao = (i * np + j + 1) * nx * nx;
                        let a = &self.qp.data.a[ao..ao + nx * nx];
                        for t in 0..nx {
                            s += a[c * nx + t] * next[t];
                        }
                    }
                    mu[c] = s;
                }
                if j < nc {
                    let bo = (i * nc + j) * nx * N;
                    let b = &self.qp.data.b[bo..bo + nx * N];
                    for t in 0..N {
                        let mut s = 0.0;
                        for c in 0..nx {
                            s += b[t * nx + c] * mu[c];
                        }
                        if j < nr {
                            self.shared_stat[j * N + t] += s;
                        } else {
                            let u = self.qp.u_index(i, j, t);
                            s += self.grad[u] + mult[u];
                            stat = stat.max(s.abs());
                        }
                    }
                }
                next.copy_from_slice(mu);
            }
        }
        for s in &self.shared_stat {
            stat = stat.max(s.abs());
        }
        let mut check = BoundCheck::default();
        for k in 0..nv {
            check.add(self.bounds.rl - z[k], z[k] - self.bounds.ru, mult[k]);
        }
        for i in 0..self.ns {
            for j in 0..nc {
                for a in 0..N {
                    let t = self.torques[(i * nc + j) * N + a];
                    let x = self.qp.x_index(i, j + 1, 2 * N + a);
                    check.add(-self.bounds.tmax - t, t - self.bounds.tmax, mult[x]);
                }
            }
        }
        let k = stat.max(check.violation).max(check.complementarity);
        (finite_or_inf(k), check.violation)
    }
}

impl<const N: usize> SqpSteps for TreeSteps<'_, N> {
    fn check_inputs(&mut self, z: &DVector<f64>) -> Result<(), SqpStatus> {
        let w = &mut *self.w;
        let ps = self.problems;
        if z.len() != w.qp.num_inputs()
            || ps.len() != w.ns
            || self.weights.len() != w.ns
            || ps.iter().any(|p| p.np() != w.np || p.nc() != w.nc)
        {
            return Err(SqpStatus::DimensionMismatch);
        }
        if !z.iter().all(|v| v.is_finite())
            || !self.weights.iter().all(|v| v.is_finite() && *v >= 0.0)
        {
            return Err(SqpStatus::NonFiniteInput);
        }
        let nan = ps.iter().any(|p| p.t_prev.iter().any(|v| v.is_nan()));
        w.bounds = StepBounds::of(self.limits, nan)?;
        w.weights.copy_from_slice(self.weights);
        // Q_i = μ_i diag(I, r_d LᵢᵀLᵢ, 0) on every state (Lᵢ the velocity metric of
        // scenario i's problem, the identity in the paper's eq. 7).
        let nx = 3 * N;
        for ((qi, &mu), p) in
            w.qp.data
                .q
                .chunks_exact_mut(w.np * nx * nx)
                .zip(&w.weights)
                .zip(ps)
        {
            let lv = p.velocity_metric();
            let qv = lv.tr_mul(lv) * w.r_d;
            for qk in qi.chunks_exact_mut(nx * nx) {
                qk.fill(0.0);
                for a in 0..N {
                    qk[a * nx + a] = mu;
                    for b in 0..N {
                        qk[(N + b) * nx + N + a] = mu * qv[(a, b)];
                    }
                }
            }
        }
        Ok(())
    }

    fn general_violation(&mut self, z: &DVector<f64>) -> f64 {
        let w = &mut *self.w;
        let mut viol: f64 = 0.0;
        for (i, p) in self.problems.iter().enumerate() {
            w.gather(z.as_slice(), i);
            let mut acc = p.t_prev;
            for j in 0..w.nc {
                for a in 0..N {
                    acc[a] += w.zi[j * N + a];
                    w.torques[(i * w.nc + j) * N + a] = acc[a];
                    viol = viol.max(acc[a].abs() - w.bounds.tmax);
                }
            }
        }
        viol
    }

    fn projection_qp(&mut self, z: &DVector<f64>) -> QpInfo {
        // min ½|d|² with the same QP: dynamics reduced to T_j = T_{j−1} + u_j.
        let w = &mut *self.w;
        super::ocp::held_layout(&mut w.qp.data.a, &mut w.qp.data.b, N);
        w.set_input_weights(1.0, false, 0.0);
        w.qp.data.g.fill(0.0);
        w.solve_step(z)
    }

    fn solve_qp(&mut self, z: &DVector<f64>) -> QpInfo {
        // Gauss–Newton with the dense path's regularisation δ = reg · (1 + max diag JᵀJ).
        let w = &mut *self.w;
        let r_t = w.r_t;
        w.set_input_weights(r_t, true, 0.0);
        let delta = w.hessian_regularization * (1.0 + w.qp.max_condensed_diagonal());
        w.set_input_weights(r_t, true, delta);
        w.qp.data.g.copy_from_slice(&w.grad);
        w.solve_step(z)
    }

    stage_steps!(problems);
}
