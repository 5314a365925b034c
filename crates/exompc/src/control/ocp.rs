//! Structure-exploiting Gauss–Newton SQP for the NMPC problem of paper eq. 7 (constraints eqs.
//! 8–9), in multiple-shooting stages, with the Riccati QP of [`crate::solver::RiccatiQp`].
//!
//! Stage `j` has state `x_j = [q_j, qd_j, T_{j−1}]` (`nx = 3N`: the torque applied over the
//! previous step is part of the state) and, for `j < Nc`, input `u_j = dT(k+j)` (`nu = N`):
//!
//! ```text
//! T_j = T_{j−1} + u_j,   (q, qd)_{j+1} = Φ((q, qd)_j, T_j)   (RK4 prediction step, docs/MODEL.md §8)
//! ```
//!
//! so the rate bound of eq. 9 is an input box and the cumulative torque bound of eq. 8 a box on the
//! `T` part of `x_1 … x_Nc`; stages after `Nc` have no input (`T` held). The step-space QP of one
//! Gauss–Newton iteration has stage costs `Q = diag(I, r_d LᵀL, 0)` (`L` the velocity metric, `NmpcProblem::velocity_metric`; the identity in the paper's eq. 7), `R = r_t I` and the linearised
//! dynamics `A_j = [[Φ_x, Φ_u], [0, I]]`, `B_j = [Φ_u; I]`; its condensed form is exactly the dense
//! QP `min ½dᵀ(JᵀJ)d + (Jᵀr)ᵀd` of [`crate::solver::Sqp`] with the Gauss–Newton Hessian.
//!
//! Hessian models: Gauss–Newton (also for `structured_secant`: the secant `S` of the dense path
//! is a dense matrix in the condensed variables and would destroy the stage structure), or the
//! exact Hessian (`HessianModel::Exact`): the stage blocks `W_j` of `control::hessian` enter as
//! `Q_j += W_j`, `R_j += W_j[T, T]` and the cross terms `S_j = W_j[T, :]` of the Riccati QP, with
//! the dense back-end's inertia correction (`engine::HessianShift`) when the QP reports the
//! Hessian not positive definite, so both back-ends take the same steps.

use super::hessian::costates;
use super::nmpc_problem::{NmpcProblem, NmpcSettings};
use super::prediction::StepJacobian;
use super::TorqueLimits;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::JointState;
use crate::solver::engine::{self, finite_or_inf, BoundCheck, HessianShift, KktTest, SqpSteps};
use crate::solver::riccati::held_congruence;
use crate::solver::{
    HessianModel, QpInfo, QpStatus, RiccatiQp, SolverError, SqpInfo, SqpSettings, SqpStatus,
};
use alloc::{vec, vec::Vec};
use nalgebra::{DVector, SMatrix, SVector};

/// SQP (Gauss–Newton or exact Hessian) over the multiple-shooting form of eq. 7 with the
/// Riccati QP. It runs the same SQP engine as [`crate::solver::Sqp`] (input checks, warm-start
/// projection, Armijo line search, KKT termination; `solver/engine.rs`) with a stage-structured
/// back-end, and so reproduces the dense iterates with `HessianModel::GaussNewton` and `Exact`,
/// but every iteration costs `O(Np·N³)` instead of `O((N·Nc)³ + Np·(N·Nc)²)`. All workspace is allocated in
/// [`StructuredSqp::new`]; [`StructuredSqp::solve`] allocates nothing and never panics.
#[derive(Clone, Debug)]
pub struct StructuredSqp<const N: usize> {
    settings: SqpSettings,
    z_trial: DVector<f64>,
    w: StageWork<N>,
}

/// Workspace of the stage-structured back-end.
#[derive(Clone, Debug)]
struct StageWork<const N: usize> {
    np: usize,
    nc: usize,
    r_d: f64,
    r_t: f64,
    hessian_regularization: f64,
    qp: RiccatiQp,
    /// `T` part of `x_1..x_Nc` (the cumulative torques) at the current iterate.
    torques: Vec<f64>,
    torques_trial: Vec<f64>,
    /// The decision-variable part of the last QP step.
    dz: DVector<f64>,
    /// Gradient of the cost in trajectory layout at the current point (`qp.data.g` is
    /// overwritten by trial linearisations).
    grad: Vec<f64>,
    costate: Vec<f64>,
    /// The box of the step (from the solve's limits).
    bounds: StepBounds,
    /// `HessianModel::Exact`: the QP gets the stage blocks `W_j` of `control::hessian`.
    exact: bool,
    /// `qp.data.q`, `qp.s` hold curvature (must be reset before a Gauss–Newton or projection QP).
    curved: bool,
    /// States `x_j` (`j = 0..Np`) and held torques `T_j` of the last linearisation, and of the
    /// current point (exact Hessian only).
    states: Vec<JointState<f64, N>>,
    states_trial: Vec<JointState<f64, N>>,
    held: Vec<SVector<f64, N>>,
    held_trial: Vec<SVector<f64, N>>,
    /// Costates `λ_{j+1}` of `(q, qd)`.
    lam: Vec<(SVector<f64, N>, SVector<f64, N>)>,
    /// Largest diagonal entry of the condensed `JᵀJ` at the solve's first Gauss–Newton QP (at
    /// the current QP with the exact Hessian).
    maxdiag: f64,
    /// `maxdiag` was computed in this solve.
    maxdiag_known: bool,
    /// Inertia correction of the exact Hessian (shared rule with the dense back-end).
    shift: HessianShift,
    /// `qp.data.a`, `qp.data.b` hold the constant zero and identity entries of the held-input
    /// form, so a linearisation writes only `F_j`, `G_j` (`projection_qp` writes the layout
    /// alone).
    layout: bool,
    /// The problem's velocity-residual metric `L` (`NmpcProblem::velocity_metric`) and the
    /// Gauss–Newton velocity block `r_d LᵀL` of `Q_j`.
    lv: SMatrix<f64, N, N>,
    qv: SMatrix<f64, N, N>,
}

impl<const N: usize> StructuredSqp<N> {
    /// Allocates the workspace for the horizon and weights of `s`.
    pub fn new(s: &NmpcSettings) -> Result<Self, SolverError> {
        s.sqp.validate()?;
        let (np, nc) = (s.np, s.nc);
        let nx = 3 * N;
        let mut qp = RiccatiQp::new(nx, N, np, nc, s.sqp.qp)?;
        // `evaluate` and `projection_qp` write A_j = [[F, G], [0, I]], B_j = [G; I] only.
        qp.assume_held_input_form();
        // `evaluate` fills them only from finite linearisations that `accept` then takes, and
        // `add_curvature` keeps only finite blocks.
        qp.assume_finite_stage_data();
        let len = qp.len();
        let zero_state = JointState {
            q: SVector::zeros(),
            qd: SVector::zeros(),
        };
        let mut sqp = Self {
            settings: s.sqp,
            z_trial: DVector::zeros(nc * N),
            w: StageWork {
                np,
                nc,
                r_d: s.r_d,
                r_t: s.r_t,
                hessian_regularization: s.sqp.hessian_regularization,
                qp,
                torques: vec![0.0; nc * N],
                torques_trial: vec![0.0; nc * N],
                dz: DVector::zeros(nc * N),
                grad: vec![0.0; len],
                costate: vec![0.0; 2 * nx],
                bounds: StepBounds::default(),
                exact: s.sqp.hessian == HessianModel::Exact,
                curved: false,
                states: vec![zero_state; np],
                states_trial: vec![zero_state; np],
                held: vec![SVector::zeros(); np],
                held_trial: vec![SVector::zeros(); np],
                lam: vec![(SVector::zeros(), SVector::zeros()); np],
                maxdiag: 0.0,
                maxdiag_known: false,
                shift: HessianShift::default(),
                layout: false,
                lv: SMatrix::identity(),
                qv: SMatrix::identity() * s.r_d,
            },
        };
        // Q = diag(I, r_d I, 0) for every state until `use_velocity_metric` (L = I); R set per
        // solve.
        sqp.w.curved = true;
        sqp.w.reset_curvature();
        Ok(sqp)
    }

    /// The QP solver (its last solution and multipliers).
    pub fn qp(&self) -> &RiccatiQp {
        &self.w.qp
    }

    /// Solves eq. 7 for `problem` (its `x0`, `t_prev`, `inputs`) under `limits` from the warm
    /// start `z` (overwritten with the result). Statuses as in [`crate::solver::Sqp::solve`].
    pub fn solve(
        &mut self,
        problem: &NmpcProblem<N>,
        limits: &TorqueLimits,
        z: &mut DVector<f64>,
    ) -> SqpInfo {
        self.w.use_velocity_metric(problem.velocity_metric());
        let mut steps = StageSteps {
            w: &mut self.w,
            problem,
            limits,
        };
        engine::solve(&mut steps, &self.settings, &mut self.z_trial, z)
    }
}

/// The stage-structured back-end of the engine for one solve.
struct StageSteps<'a, const N: usize> {
    w: &'a mut StageWork<N>,
    problem: &'a NmpcProblem<N>,
    limits: &'a TorqueLimits,
}

impl<const N: usize> StageWork<N> {
    /// Takes the velocity-residual metric `L` of the problem to solve: the Gauss–Newton stage
    /// costs become `Q_j = diag(I, r_d LᵀL, 0)` (rewritten only when `L` changes).
    fn use_velocity_metric(&mut self, lv: &SMatrix<f64, N, N>) {
        if *lv == self.lv {
            return;
        }
        self.lv = *lv;
        self.qv = lv.tr_mul(lv) * self.r_d;
        // Rewrite the Gauss–Newton blocks with the new `r_d LᵀL`.
        self.curved = true;
        self.reset_curvature();
    }

    /// Writes `R = diag(r)` into every input stage of the QP.
    fn set_input_weight(&mut self, r: f64) {
        for j in 0..self.nc {
            let rj = &mut self.qp.data.r[j * N * N..(j + 1) * N * N];
            rj.fill(0.0);
            for a in 0..N {
                rj[a * N + a] = r;
            }
        }
    }

    /// `R = (r_t + δ) I` with the regularisation of the dense path,
    /// `δ = hessian_regularization · (1 + max diag JᵀJ)`. With the Gauss–Newton Hessian the
    /// diagonal is that of the solve's first QP (the later linearisations of a solve move `δ` by
    /// `hessian_regularization` times the change of the diagonal, ~1e-14 by default, so both
    /// back-ends solve the same QPs to ~1e-12 relative); with the exact Hessian it is that of the
    /// current linearisation in every QP, since it also scales the inertia correction.
    fn gauss_newton_input_weight(&mut self) -> f64 {
        if self.exact || !self.maxdiag_known {
            self.maxdiag = self.max_condensed_diagonal();
            self.maxdiag_known = true;
        }
        self.r_t + self.hessian_regularization * (1.0 + self.maxdiag)
    }

    /// Adds `μ I` to every `R_j` (the condensed Hessian gets `+ μ I`).
    fn shift_input_weight(&mut self, mu: f64) {
        for j in 0..self.nc {
            let rj = &mut self.qp.data.r[j * N * N..(j + 1) * N * N];
            for a in 0..N {
                rj[a * N + a] += mu;
            }
        }
    }

    /// Largest diagonal entry of the condensed Gauss–Newton Hessian `JᵀJ` at the current
    /// linearisation: for input `a` of stage `i`, `(B_iᵀ V_i B_i)_aa + r_t` with
    /// `V_{Np−1} = Q_{Np−1}`, `V_j = Q_j + A_{j+1}ᵀ V_{j+1} A_{j+1}` (`O(Np·nx³)`). `A` has the
    /// block form `[[F, G], [0, I]]` (`F` on `(q, qd)`, `G = Φ_u`, the held torque), so with
    /// `V = [[V11, V12], [V12ᵀ, V22]]`: `AᵀVA = [[FᵀV11F, FᵀX], [XᵀF, GᵀX + V12ᵀG + V22]]`,
    /// `X = V11 G + V12`.
    fn max_condensed_diagonal(&mut self) -> f64 {
        match N {
            1 => self.max_condensed_diagonal_fixed::<3, 1>(),
            2 => self.max_condensed_diagonal_fixed::<6, 2>(),
            _ => self.max_condensed_diagonal_any_size(),
        }
    }

    /// [`Self::max_condensed_diagonal`] with fixed-size blocks for the 1-DOF and 2-DOF stages
    /// (`NX = 3N`, `NU = N`): `W_j = A_jᵀ V_j A_j` by the held-input congruence of the Riccati
    /// factor, `V_{j−1} = Q_{j−1} + W_j`. Since `B_j = [G_j; I]` is the last `NU` columns of
    /// `A_j` (the held-input form written by [`Self::evaluate`]), `(B_jᵀ V_j B_j)_aa` is the
    /// diagonal entry `W_j[ns + a, ns + a]`: one congruence a stage, no separate `Bᵀ V B`.
    /// Equals the slice version to rounding (unit test).
    fn max_condensed_diagonal_fixed<const NX: usize, const NU: usize>(&self) -> f64 {
        let nn = NX * NX;
        let ns = NX - NU;
        let (np, nc) = (self.np, self.nc);
        let qp = &self.qp;
        let mut maxdiag = self.r_t;
        let mut v = SMatrix::<f64, NX, NX>::from_column_slice(&qp.data.q[(np - 1) * nn..np * nn]);
        for j in (0..np).rev() {
            let a = SMatrix::<f64, NX, NX>::from_column_slice(&qp.data.a[j * nn..(j + 1) * nn]);
            let w = held_congruence::<NX, NU>(&v, &a);
            if j < nc {
                for i in 0..NU {
                    maxdiag = maxdiag.max(w[(ns + i, ns + i)] + self.r_t);
                }
            }
            if j == 0 {
                break;
            }
            v = w + SMatrix::<f64, NX, NX>::from_column_slice(&qp.data.q[(j - 1) * nn..j * nn]);
        }
        maxdiag
    }

    /// [`Self::max_condensed_diagonal`] for any `N`: the Riccati solver's general stage
    /// kernels ([`RiccatiQp::max_condensed_gram_diagonal`], `Bᵀ V B` without `R`) plus `r_t`.
    fn max_condensed_diagonal_any_size(&mut self) -> f64 {
        self.r_t + self.qp.max_condensed_gram_diagonal()
    }

    /// Simulates from `problem.x0` with increments `z`; with `jac`, fills the QP's dynamics
    /// matrices and gradient. Writes the cumulative torques into `torques_trial` and returns the
    /// cost `½‖r‖²` (non-finite when anything is).
    #[allow(clippy::eq_op)] // `v − v` is the finiteness test
    fn evaluate(&mut self, problem: &NmpcProblem<N>, z: &[f64], jac: bool) -> f64 {
        let nx = 3 * N;
        let (np, nc) = (self.np, self.nc);
        let dt = problem.model.dt;
        let inp = problem.inputs;
        let sqrt_rd = self.r_d.sqrt();
        let sqrt_rt = self.r_t.sqrt();
        let mut x = problem.x0;
        let mut u = problem.t_prev;
        let mut sum = 0.0;
        let mut finite = true;
        let off = nc * N;
        let consts = problem.model.jacobian_constants();
        if jac && !self.layout {
            self.write_held_layout();
        }
        for j in 0..np {
            if j < nc {
                for a in 0..N {
                    u[a] += z[j * N + a];
                    self.torques_trial[j * N + a] = u[a];
                }
            }
            let tau = j as f64 * dt;
            if jac && self.exact {
                self.states_trial[j] = x;
                self.held_trial[j] = u;
            }
            let xn = if jac {
                let (xn, g): (JointState<f64, N>, StepJacobian<N>) = problem
                    .model
                    .tailored(&consts, &inp, &u)
                    .step_with_jacobian(&x, tau);
                // The only non-constant entries of A_j and B_j.
                // Branch-free: `v − v` is 0 for a finite `v` and NaN otherwise; one lane per
                // entry (six adds deep instead of one chain of 6·N² adds).
                let mut nan = SMatrix::<f64, N, N>::zeros();
                for m in [g.qq, g.qv, g.vq, g.vv, g.qu, g.vu] {
                    for (l, v) in nan.iter_mut().zip(m.iter()) {
                        *l += v - v;
                    }
                }
                finite &= nan.sum() == 0.0;
                // The zero and identity entries are in place (`write_held_layout`).
                let aj = &mut self.qp.data.a[j * nx * nx..(j + 1) * nx * nx];
                let bj = (j < nc).then(|| &mut self.qp.data.b[j * nx * N..(j + 1) * nx * N]);
                write_stage_jacobian(&g, aj, bj);
                xn
            } else {
                problem.model.step_value_using(&consts, &x, &u, tau, &inp)
            };
            x = xn;
            let tj = (j + 1) as f64 * dt;
            let xo = off + j * nx;
            let grad = jac.then(|| (1.0, &mut self.qp.data.g[xo..xo + nx]));
            finite &= stage_residual(problem, &x, tj, sqrt_rd, &mut sum, grad);
        }
        for (k, zk) in z.iter().enumerate() {
            let rz = sqrt_rt * zk;
            sum += rz * rz;
            if jac {
                self.qp.data.g[k] = sqrt_rt * rz;
            }
        }
        if finite {
            0.5 * sum
        } else {
            f64::NAN
        }
    }

    /// Writes the constant part of the held-input form into every `A_j`, `B_j`: zeros, and the
    /// identity `I` of `A_j`'s last block and `B_j`'s last rows (the linearisation fills in `F_j`
    /// and `G_j`).
    fn write_held_layout(&mut self) {
        held_layout(&mut self.qp.data.a, &mut self.qp.data.b, N);
        self.layout = true;
    }

    /// Restores the Gauss–Newton stage costs `Q_j = diag(I, r_d LᵀL, 0)`, `S_j = 0` if the last
    /// QP had curvature (`R` is set by the caller).
    fn reset_curvature(&mut self) {
        if !self.curved {
            return;
        }
        let nx = 3 * N;
        self.qp.data.q.fill(0.0);
        for j in 0..self.np {
            let qj = &mut self.qp.data.q[j * nx * nx..(j + 1) * nx * nx];
            for a in 0..N {
                qj[a * nx + a] = 1.0;
                for b in 0..N {
                    qj[(N + b) * nx + N + a] = self.qv[(a, b)];
                }
            }
        }
        self.qp.s.fill(0.0);
        self.curved = false;
    }

    /// Adds the exact stage blocks `W_j` (`control::hessian`) at the current point to the
    /// Gauss–Newton QP: with `x_j = (q_j, qd_j, T_{j−1})` and `T_j = T_{j−1} + u_j`,
    /// `Q_j += W_j`, `R_j += W_j[T, T]`, `S_j = W_j[T, :]` (for `j ≥ Nc`, `T_j = T_{j−1}`: `Q_j`
    /// only). The costates come from the cost gradient `grad` and the dynamics `qp.data.a`.
    /// Returns `false` (and restores the Gauss–Newton blocks) when a block is non-finite.
    fn add_curvature(&mut self, problem: &NmpcProblem<N>) -> bool {
        let nx = 3 * N;
        let s2 = 2 * N;
        let (np, nc) = (self.np, self.nc);
        let off = nc * N;
        let (grad, a) = (&self.grad, &self.qp.data.a);
        costates(
            np,
            |j| {
                let xo = off + j * nx;
                (
                    SVector::from_fn(|i, _| grad[xo + i]),
                    SVector::from_fn(|i, _| grad[xo + N + i]),
                )
            },
            |j| {
                let aj = &a[j * nx * nx..(j + 1) * nx * nx];
                let blk = |r0: usize, c0: usize| {
                    SMatrix::<f64, N, N>::from_fn(|r, c| aj[(c0 + c) * nx + r0 + r])
                };
                StepJacobian {
                    qq: blk(0, 0),
                    qv: blk(0, N),
                    vq: blk(N, 0),
                    vv: blk(N, N),
                    qu: blk(0, s2),
                    vu: blk(N, s2),
                }
            },
            &mut self.lam,
        );
        self.curved = true;
        let dt = problem.model.dt;
        let mut finite = true;
        for j in 0..np {
            let (lq, lv) = self.lam[j];
            let w = problem.model.step_lagrangian_hessian(
                &self.states[j],
                &self.held[j],
                j as f64 * dt,
                &problem.inputs,
                &lq,
                &lv,
            );
            finite &= w.is_finite();
            if j >= 1 {
                let qj = &mut self.qp.data.q[(j - 1) * nx * nx..j * nx * nx];
                for c in 0..nx {
                    for r in 0..nx {
                        qj[c * nx + r] += w.get(r, c);
                    }
                }
            }
            if j < nc {
                let rj = &mut self.qp.data.r[j * N * N..(j + 1) * N * N];
                for c in 0..N {
                    for r in 0..N {
                        rj[c * N + r] += w.uu[(r, c)];
                    }
                }
                let sj = &mut self.qp.s[j * N * nx..(j + 1) * N * nx];
                for c in 0..nx {
                    for i in 0..N {
                        sj[c * N + i] = w.get(s2 + i, c);
                    }
                }
            }
        }
        if !finite {
            self.reset_curvature();
        }
        finite
    }

    /// The trial point becomes the current one (its torques and gradient; with the exact
    /// Hessian its states and held torques).
    fn accept(&mut self) {
        self.torques.copy_from_slice(&self.torques_trial);
        self.grad.copy_from_slice(&self.qp.data.g);
        if self.exact {
            core::mem::swap(&mut self.states, &mut self.states_trial);
            core::mem::swap(&mut self.held, &mut self.held_trial);
        }
    }

    /// The QP (linear term written by the caller) with the step-space bounds at `z`, its step
    /// copied into `dz`.
    fn solve_step(&mut self, z: &DVector<f64>) -> QpInfo {
        self.shift_bounds(z);
        let qi = self.qp.solve();
        copy_step(&mut self.dz, self.qp.solution());
        qi
    }

    /// Step-space bounds of the QP at `z` (with `torques` the cumulative torques at `z`).
    fn shift_bounds(&mut self, z: &DVector<f64>) {
        let nx = 3 * N;
        let off = self.nc * N;
        self.bounds
            .shift_inputs(z, &mut self.qp.data.lo, &mut self.qp.data.hi);
        for j in 0..self.nc {
            for a in 0..N {
                let i = off + j * nx + 2 * N + a;
                self.qp.data.lo[i] = -self.bounds.tmax - self.torques[j * N + a];
                self.qp.data.hi[i] = self.bounds.tmax - self.torques[j * N + a];
            }
        }
    }

    /// [`adjoint_stationarity`] for any `N` (slices).
    fn stationarity_any_size(&mut self) -> f64 {
        let nx = 3 * N;
        let (np, nc) = (self.np, self.nc);
        let off = nc * N;
        let mult = self.qp.multipliers();
        let mut stat: f64 = 0.0;
        let (mu, next) = self.costate.split_at_mut(nx);
        next.fill(0.0);
        for j in (0..np).rev() {
            // μ_{j+1} = g_x + mult_x + A_{j+1}ᵀ μ_{j+2}.
            let xo = off + j * nx;
            for c in 0..nx {
                let mut s = self.grad[xo + c] + mult[xo + c];
                if j + 1 < np {
                    let a = &self.qp.data.a[(j + 1) * nx * nx..(j + 2) * nx * nx];
                    for t in 0..nx {
                        s += a[c * nx + t] * next[t];
                    }
                }
                mu[c] = s;
            }
            if j < nc {
                let b = &self.qp.data.b[j * nx * N..(j + 1) * nx * N];
                for i in 0..N {
                    let mut s = self.grad[j * N + i] + mult[j * N + i];
                    for t in 0..nx {
                        s += b[i * nx + t] * mu[t];
                    }
                    stat = stat.max(s.abs());
                }
            }
            next.copy_from_slice(mu);
        }
        stat
    }

    /// KKT residual at `z` with the last QP multipliers, from `grad`, the QP's dynamics matrices
    /// (at `z`) and `torques`: stationarity by an adjoint sweep, box and cumulative violation,
    /// complementarity. Returns `(kkt, violation)`.
    fn kkt(&mut self, z: &DVector<f64>) -> (f64, f64) {
        let t = self.kkt_test(z, f64::INFINITY, f64::INFINITY);
        (t.kkt, t.violation)
    }

    /// [`Self::kkt`] for the termination test `kkt ≤ kkt_tol`, `violation ≤ feas_tol`: the
    /// bounds first, then the adjoint sweep, which stops at the first input whose stationarity
    /// residual exceeds `kkt_tol` (the test has failed; `kkt` is then a lower bound and `exact`
    /// false). When the test passes, the same numbers as the full computation.
    fn kkt_test(&mut self, z: &DVector<f64>, kkt_tol: f64, feas_tol: f64) -> KktTest {
        let nx = 3 * N;
        let (np, nc) = (self.np, self.nc);
        let off = nc * N;
        let mult = self.qp.multipliers();
        // The increments' and the torques' bounds as two independent chains, then merged.
        let mut check = BoundCheck::default();
        let mut check_t = BoundCheck::default();
        for k in 0..off {
            check.add(self.bounds.rl - z[k], z[k] - self.bounds.ru, mult[k]);
        }
        for j in 0..nc {
            for a in 0..N {
                let t = self.torques[j * N + a];
                check_t.add(
                    -self.bounds.tmax - t,
                    t - self.bounds.tmax,
                    mult[off + j * nx + 2 * N + a],
                );
            }
        }
        check.merge(&check_t);
        let bounds = check.violation.max(check.complementarity);
        if !(bounds <= kkt_tol && check.violation <= feas_tol) {
            return KktTest {
                kkt: finite_or_inf(bounds),
                violation: check.violation,
                exact: false,
            };
        }
        let (stat, exact) = match N {
            1 => adjoint_stationarity::<3, 1>(&self.qp, &self.grad, np, nc, kkt_tol),
            2 => adjoint_stationarity::<6, 2>(&self.qp, &self.grad, np, nc, kkt_tol),
            _ => (self.stationarity_any_size(), true),
        };
        let k = stat.max(check.violation).max(check.complementarity);
        KktTest {
            kkt: finite_or_inf(k),
            violation: check.violation,
            exact,
        }
    }
}

/// Largest stationarity residual `|g_u + mult_u + B_jᵀ μ_{j+1}|` of the inputs, with the costates
/// `μ_{j+1} = g_x + mult_x + A_{j+1}ᵀ μ_{j+2}` from a backward sweep (fixed-size blocks). The
/// dynamics have the held-input form written by [`StageWork::evaluate`] (`A = [[F, G], [0, I]]`,
/// `B = [G; I]`), so the zero and identity rows are skipped: the same nonzero terms in the same
/// order as the slice version (equal values). The sweep stops once the residual exceeds `limit`
/// (`∞`: never), returning `(residual so far, false)`; `(residual, true)` when complete.
fn adjoint_stationarity<const NX: usize, const NU: usize>(
    qp: &RiccatiQp,
    grad: &[f64],
    np: usize,
    nc: usize,
    limit: f64,
) -> (f64, bool) {
    let ns = NX - NU;
    let nn = NX * NX;
    let off = nc * NU;
    let mult = qp.multipliers();
    let (gu, gx) = grad.split_at(off);
    let (mu_u, mu_x) = mult.split_at(off);
    let mut next = SVector::<f64, NX>::zeros();
    let mut stat: f64 = 0.0;
    for j in (0..np).rev() {
        let (gj, mj) = (&gx[j * NX..(j + 1) * NX], &mu_x[j * NX..(j + 1) * NX]);
        let mut mu = SVector::<f64, NX>::zeros();
        for c in 0..NX {
            mu[c] = gj[c] + mj[c];
        }
        if j + 1 < np {
            let a = &qp.data.a[(j + 1) * nn..(j + 2) * nn];
            for c in 0..NX {
                let mut s = mu[c];
                for (act, nt) in a[c * NX..c * NX + ns].iter().zip(next.iter()) {
                    s += act * nt;
                }
                if c >= ns {
                    s += next[c];
                }
                mu[c] = s;
            }
        }
        if j < nc {
            let b = &qp.data.b[j * NX * NU..(j + 1) * NX * NU];
            let (guj, muj) = (&gu[j * NU..(j + 1) * NU], &mu_u[j * NU..(j + 1) * NU]);
            for i in 0..NU {
                let mut s = guj[i] + muj[i];
                for (bt, mt) in b[i * NX..i * NX + ns].iter().zip(mu.iter()) {
                    s += bt * mt;
                }
                s += mu[ns + i];
                stat = stat.max(s.abs());
            }
            if stat > limit {
                return (stat, false);
            }
        }
        next = mu;
    }
    (stat, true)
}

impl<const N: usize> SqpSteps for StageSteps<'_, N> {
    fn check_inputs(&mut self, z: &DVector<f64>) -> Result<(), SqpStatus> {
        let w = &mut *self.w;
        let p = self.problem;
        if z.len() != w.nc * N || p.np() != w.np || p.nc() != w.nc {
            return Err(SqpStatus::DimensionMismatch);
        }
        if !z.iter().all(|v| v.is_finite()) {
            return Err(SqpStatus::NonFiniteInput);
        }
        w.bounds = StepBounds::of(self.limits, p.t_prev.iter().any(|v| v.is_nan()))?;
        w.shift.reset();
        w.maxdiag_known = false;
        Ok(())
    }

    fn general_violation(&mut self, z: &DVector<f64>) -> f64 {
        let w = &mut *self.w;
        let mut acc = self.problem.t_prev;
        let mut viol: f64 = 0.0;
        for j in 0..w.nc {
            for a in 0..N {
                acc[a] += z[j * N + a];
                w.torques[j * N + a] = acc[a];
                viol = viol.max(acc[a].abs() - w.bounds.tmax);
            }
        }
        viol
    }

    fn projection_qp(&mut self, z: &DVector<f64>) -> QpInfo {
        // min ½|d|² with the same QP: dynamics reduced to T_j = T_{j−1} + u_j, Q = 0 on T.
        let w = &mut *self.w;
        w.reset_curvature();
        // The held layout alone (F_j = G_j = 0) is these dynamics.
        w.write_held_layout();
        w.set_input_weight(1.0);
        w.qp.data.g.fill(0.0);
        w.solve_step(z)
    }

    fn solve_qp(&mut self, z: &DVector<f64>) -> QpInfo {
        // Gauss–Newton: Q, R fixed, dynamics and gradient from the last accepted linearisation.
        let w = &mut *self.w;
        w.reset_curvature();
        let r = w.gauss_newton_input_weight();
        w.set_input_weight(r);
        w.qp.data.g.copy_from_slice(&w.grad);
        w.shift_bounds(z);
        let qi = if w.exact && w.add_curvature(self.problem) {
            let qi = w.qp.solve();
            if qi.status == QpStatus::NumericalError {
                // Not positive definite: the inertia correction, then the Gauss–Newton step (the
                // dense back-end's rule, `HessianShift`).
                let mut shift = w.shift;
                let mut applied = 0.0;
                let shifted = shift.solve(w.maxdiag, |mu| {
                    w.shift_input_weight(mu - applied);
                    applied = mu;
                    w.qp.solve()
                });
                w.shift = shift;
                match shifted {
                    Ok(mut s) => {
                        s.iterations += qi.iterations;
                        s
                    }
                    Err(iterations) => {
                        w.reset_curvature();
                        w.set_input_weight(r);
                        let mut retry = w.qp.solve();
                        retry.iterations += qi.iterations + iterations;
                        retry
                    }
                }
            } else {
                qi
            }
        } else {
            w.reset_curvature();
            w.set_input_weight(r);
            w.qp.solve()
        };
        copy_step(&mut w.dz, w.qp.solution());
        qi
    }

    stage_steps!(problem);

    fn kkt_test(&mut self, z: &DVector<f64>, kkt_tol: f64, feas_tol: f64) -> KktTest {
        self.w.kkt_test(z, kkt_tol, feas_tol)
    }
}

/// The held-input form's constant part of the stage matrices of an `n`-joint chain
/// (`x = (q, qd, T)`, `nx = 3n`, `nu = n`), written into every `A_j` and `B_j` (column-major,
/// concatenated): zeros, with the identity in `A_j`'s last diagonal block and in `B_j`'s last
/// rows. The linearisation fills in the rest; with nothing else written it is the projection
/// QP's dynamics `T_j = T_{j−1} + u_j`.
pub(crate) fn held_layout(a: &mut [f64], b: &mut [f64], n: usize) {
    let nx = 3 * n;
    a.fill(0.0);
    b.fill(0.0);
    for aj in a.chunks_exact_mut(nx * nx) {
        for c in 0..n {
            aj[(2 * n + c) * nx + 2 * n + c] = 1.0;
        }
    }
    for bj in b.chunks_exact_mut(nx * n) {
        for c in 0..n {
            bj[c * nx + 2 * n + c] = 1.0;
        }
    }
}

/// The methods of [`SqpSteps`] that every stage back-end shares, for a workspace `w` that holds
/// the step box `bounds`, the step `dz`, the gradient `grad` and the QP `qp` in trajectory
/// layout, and methods `evaluate` (of the steps' field `$problem`), `accept` and `kkt`: the
/// slope is `gᵀd` over the whole trajectory (states are linear in the increments along the
/// step).
macro_rules! stage_steps {
    ($problem:ident) => {
        fn clamp(&self, z: &mut DVector<f64>) {
            self.w.bounds.clamp(z);
        }

        fn evaluate(&mut self, z: &DVector<f64>, jacobian: bool) -> f64 {
            self.w.evaluate(self.$problem, z.as_slice(), jacobian)
        }

        fn accept(&mut self, _z_old: Option<&DVector<f64>>, _z_new: &DVector<f64>) -> bool {
            // `evaluate` returns a non-finite cost when any linearisation entry is non-finite.
            self.w.accept();
            true
        }

        fn step(&self) -> &DVector<f64> {
            &self.w.dz
        }

        fn slope(&self) -> f64 {
            self.w
                .grad
                .iter()
                .zip(self.w.qp.solution())
                .map(|(g, d)| g * d)
                .sum()
        }

        fn kkt(&mut self, z: &DVector<f64>) -> (f64, f64) {
            self.w.kkt(z)
        }
    };
}
pub(super) use stage_steps;

/// The box of an SQP step in the increments `z` of the torque (paper eq. 7's constraints): each
/// increment within `[rl, ru] = [−Δmax, Δmax]`, each cumulative torque within `±tmax`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct StepBounds {
    /// Lower bound of an increment (N·m per period).
    pub rl: f64,
    /// Upper bound of an increment (N·m per period).
    pub ru: f64,
    /// Bound on the magnitude of a cumulative torque (N·m).
    pub tmax: f64,
}

impl StepBounds {
    /// The box of `limits` (`t_prev_nan`: some previous torque is NaN): `NonFiniteInput` when a
    /// limit or a previous torque is NaN, `Infeasible` when a limit is negative or infinite.
    pub(super) fn of(limits: &TorqueLimits, t_prev_nan: bool) -> Result<Self, SqpStatus> {
        let (rate, tmax) = (limits.rate, limits.max);
        if rate.is_nan() || tmax.is_nan() || t_prev_nan {
            return Err(SqpStatus::NonFiniteInput);
        }
        if !(rate >= 0.0 && rate.is_finite() && tmax >= 0.0 && tmax.is_finite()) {
            return Err(SqpStatus::Infeasible);
        }
        Ok(Self {
            rl: -rate,
            ru: rate,
            tmax,
        })
    }

    /// Each increment of `z` clamped into `[rl, ru]`.
    pub(super) fn clamp(&self, z: &mut DVector<f64>) {
        for v in z.iter_mut() {
            *v = v.max(self.rl).min(self.ru);
        }
    }

    /// The step-space bounds `rl − z_k`, `ru − z_k` of the increments at `z` into the first
    /// `z.len()` entries of `lo`, `hi`.
    pub(super) fn shift_inputs(&self, z: &DVector<f64>, lo: &mut [f64], hi: &mut [f64]) {
        for k in 0..z.len() {
            lo[k] = self.rl - z[k];
            hi[k] = self.ru - z[k];
        }
    }
}

/// The step `dz` (the increments) from the QP's solution in trajectory layout (inputs first).
#[inline]
pub(super) fn copy_step(dz: &mut DVector<f64>, sol: &[f64]) {
    let n = dz.len();
    dz.as_mut_slice().copy_from_slice(&sol[..n]);
}

/// Writes the non-constant entries of the held-input stage `A_j = [[F_j, G_j], [0, I]]`,
/// `B_j = [G_j; I]` (state `[q, qd, T]`, column-major `3N × 3N` and `3N × N`) from the step
/// Jacobian `g`; the zero and identity entries are the caller's.
#[inline]
pub(super) fn write_stage_jacobian<const N: usize>(
    g: &StepJacobian<N>,
    aj: &mut [f64],
    bj: Option<&mut [f64]>,
) {
    let nx = 3 * N;
    for c in 0..N {
        for r in 0..N {
            aj[c * nx + r] = g.qq[(r, c)];
            aj[c * nx + N + r] = g.vq[(r, c)];
            aj[(N + c) * nx + r] = g.qv[(r, c)];
            aj[(N + c) * nx + N + r] = g.vv[(r, c)];
            aj[(2 * N + c) * nx + r] = g.qu[(r, c)];
            aj[(2 * N + c) * nx + N + r] = g.vu[(r, c)];
        }
    }
    if let Some(bj) = bj {
        for c in 0..N {
            for r in 0..N {
                bj[c * nx + r] = g.qu[(r, c)];
                bj[c * nx + N + r] = g.vu[(r, c)];
            }
        }
    }
}

/// The tracking residuals of eq. 7 at the state `x` reached at time `tj` (position against the
/// human's extrapolated angle, velocity through [`NmpcProblem::velocity_residual`]): adds
/// `‖r‖²` to `sum` and, with `grad = (μ, g_x)`, writes the state gradient of `μ ½‖r‖²` into
/// `g_x` (`μ r_q`, `μ √r_d Lᵀ r_v`, zero for the torques). Returns whether every residual is
/// finite.
#[inline]
pub(super) fn stage_residual<const N: usize>(
    problem: &NmpcProblem<N>,
    x: &JointState<f64, N>,
    tj: f64,
    sqrt_rd: f64,
    sum: &mut f64,
    grad: Option<(f64, &mut [f64])>,
) -> bool {
    let inp = &problem.inputs;
    let (rv, ltrv) = problem.velocity_residual(&x.qd, sqrt_rd);
    let mut finite = true;
    let mut grad = grad;
    for a in 0..N {
        let rq = x.q[a] - (inp.q_h[a] + tj * inp.qd_h[a]);
        *sum += rq * rq + rv[a] * rv[a];
        finite &= rq.is_finite() && rv[a].is_finite();
        if let Some((mu, g)) = grad.as_mut() {
            g[a] = *mu * rq;
            g[N + a] = *mu * sqrt_rd * ltrv[a];
            g[2 * N + a] = 0.0;
        }
    }
    finite
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Stage matrices of the held-input form with pseudo-random `F`, `G` (deterministic LCG).
    fn random_work<const N: usize>(np: usize, nc: usize, seed: u64) -> StageWork<N> {
        let s = NmpcSettings {
            np,
            nc,
            ..NmpcSettings::default()
        };
        let mut w = StructuredSqp::<N>::new(&s).unwrap().w;
        let mut next = crate::test_rng::lcg(seed);
        let nx = 3 * N;
        for j in 0..np {
            let a = &mut w.qp.data.a[j * nx * nx..(j + 1) * nx * nx];
            for c in 0..nx {
                for r in 0..nx {
                    a[c * nx + r] = if r < 2 * N {
                        next()
                    } else if r == c {
                        1.0
                    } else {
                        0.0
                    };
                }
            }
            if j < nc {
                let tail = a[2 * N * nx..].to_vec();
                w.qp.data.b[j * nx * N..(j + 1) * nx * N].copy_from_slice(&tail);
            }
        }
        w
    }

    #[test]
    fn held_adjoint_stationarity_equals_the_slice_version() {
        for (np, nc, seed) in [(1, 1, 5), (5, 3, 6), (20, 20, 7), (50, 12, 8)] {
            let mut w1 = random_work::<1>(np, nc, seed);
            let mut next = crate::test_rng::lcg(seed + 100);
            w1.grad.iter_mut().for_each(|g| *g = next());
            let (a, complete) =
                adjoint_stationarity::<3, 1>(&w1.qp, &w1.grad, np, nc, f64::INFINITY);
            assert!(complete);
            assert_eq!(a, w1.stationarity_any_size(), "N = 1");
            let mut w2 = random_work::<2>(np, nc, seed);
            w2.grad.iter_mut().for_each(|g| *g = next());
            let (a, complete) =
                adjoint_stationarity::<6, 2>(&w2.qp, &w2.grad, np, nc, f64::INFINITY);
            assert!(complete);
            assert_eq!(a, w2.stationarity_any_size(), "N = 2");
            assert!(a > 0.0);
        }
    }

    /// The termination test's early exit: the same verdict as the full residual for every
    /// tolerance, and the same numbers whenever the test passes.
    #[test]
    fn kkt_test_stops_early_only_when_the_test_fails() {
        fn run<const N: usize>(np: usize, nc: usize, seed: u64) {
            let mut w = random_work::<N>(np, nc, seed);
            let mut next = crate::test_rng::lcg(seed + 7);
            // Small gradients so that some tolerances pass.
            w.grad.iter_mut().for_each(|g| *g = 1e-6 * next());
            w.bounds = StepBounds {
                rl: -1.0,
                ru: 1.0,
                tmax: 10.0,
            };
            let z = DVector::from_fn(nc * N, |_, _| 0.5 * next());
            for (k, t) in w.torques.iter_mut().enumerate() {
                *t = if k == 1 { 10.0 + 1e-7 } else { 9.0 * next() };
            }
            let (kkt, viol) = w.kkt(&z);
            assert!(viol > 0.0 && kkt > viol);
            let mut passed = 0;
            let mut early = 0;
            for kkt_tol in [
                0.0,
                0.5 * viol,
                viol,
                0.5 * (viol + kkt),
                kkt,
                2.0 * kkt,
                1e3,
            ] {
                for feas_tol in [0.0, viol, 1.0] {
                    let t = w.kkt_test(&z, kkt_tol, feas_tol);
                    let pass = kkt <= kkt_tol && viol <= feas_tol;
                    assert_eq!(t.kkt <= kkt_tol && t.violation <= feas_tol, pass);
                    assert_eq!(t.violation, viol);
                    if pass {
                        passed += 1;
                        assert!(t.exact);
                        assert_eq!(t.kkt, kkt);
                    } else if !t.exact {
                        early += 1;
                        assert!(t.kkt <= kkt);
                    }
                }
            }
            assert!(passed > 0 && early > 0, "{passed} passed, {early} early");
        }
        for (np, nc, seed) in [(5, 3, 11), (20, 20, 12), (50, 12, 13)] {
            run::<1>(np, nc, seed);
            run::<2>(np, nc, seed);
        }
    }

    #[test]
    fn fixed_size_condensed_diagonal_equals_the_slice_version() {
        for (np, nc, seed) in [(1, 1, 1), (5, 3, 2), (20, 20, 3), (50, 50, 4)] {
            let mut w1 = random_work::<1>(np, nc, seed);
            let a = w1.max_condensed_diagonal_fixed::<3, 1>();
            let b = w1.max_condensed_diagonal_any_size();
            assert!((a - b).abs() <= 1e-12 * b.abs(), "N = 1: {a} vs {b}");
            let mut w2 = random_work::<2>(np, nc, seed);
            let a = w2.max_condensed_diagonal_fixed::<6, 2>();
            let b = w2.max_condensed_diagonal_any_size();
            assert!((a - b).abs() <= 1e-12 * b.abs(), "N = 2: {a} vs {b}");
            assert!(b > w2.r_t);
        }
    }
}
