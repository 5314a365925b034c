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
//! Gauss–Newton iteration has stage costs `Q = diag(I, r_d I, 0)`, `R = r_t I` and the linearised
//! dynamics `A_j = [[Φ_x, Φ_u], [0, I]]`, `B_j = [Φ_u; I]`; its condensed form is exactly the dense
//! QP `min ½dᵀ(JᵀJ)d + (Jᵀr)ᵀd` of [`crate::solver::Sqp`] with the Gauss–Newton Hessian.
//!
//! The structured path always uses the Gauss–Newton Hessian: the structured secant `S` of the
//! dense path is a dense matrix in the condensed variables and would destroy the stage structure.

use std::time::Instant;

use super::nmpc::{NmpcProblem, NmpcSettings};
use super::prediction::StepJacobian;
use super::TorqueLimits;
use crate::model::JointState;
use crate::solver::{QpStatus, RiccatiQp, SolverError, SqpInfo, SqpSettings, SqpStatus};
use nalgebra::DVector;
use serde::{Deserialize, Serialize};

/// Which QP solver the NMPC's SQP uses (`[controller.sqp] qp`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QpBackend {
    /// Condensed dense Goldfarb–Idnani QP ([`crate::solver::DenseQp`]) with the configured
    /// Hessian model: `O((N·Nc)³)` per iteration. The oracle.
    Dense,
    /// Multiple-shooting stages with the Riccati QP ([`crate::solver::RiccatiQp`]) and the
    /// Gauss–Newton Hessian: `O(Np·N³)` per iteration.
    Structured,
    /// `Structured` when `N·Nc ≥` [`AUTO_STRUCTURED_MIN_VARS`], else `Dense` (the default).
    #[default]
    Auto,
}

/// Smallest number of decision variables `N·Nc` for which [`QpBackend::Auto`] picks the
/// structured solver (measured with `exompc bench --qp`, docs/PERFORMANCE.md).
pub const AUTO_STRUCTURED_MIN_VARS: usize = 16;

impl QpBackend {
    /// Whether this backend resolves to the structured solver for `n_vars = N·Nc` variables.
    pub fn is_structured(self, n_vars: usize) -> bool {
        match self {
            QpBackend::Dense => false,
            QpBackend::Structured => true,
            QpBackend::Auto => n_vars >= AUTO_STRUCTURED_MIN_VARS,
        }
    }
}

/// Gauss–Newton SQP over the multiple-shooting form of eq. 7 with the Riccati QP. Same
/// termination tests, line search and warm-start projection as [`crate::solver::Sqp`] (whose
/// iterates it reproduces with `HessianModel::GaussNewton`), but every iteration costs
/// `O(Np·N³)` instead of `O((N·Nc)³ + Np·(N·Nc)²)`. All workspace is allocated in
/// [`StructuredSqp::new`]; [`StructuredSqp::solve`] allocates nothing and never panics.
#[derive(Clone, Debug)]
pub struct StructuredSqp<const N: usize> {
    np: usize,
    nc: usize,
    r_d: f64,
    r_t: f64,
    settings: SqpSettings,
    qp: RiccatiQp,
    /// `T` part of `x_1..x_Nc` (the cumulative torques) at the current iterate.
    torques: Vec<f64>,
    torques_trial: Vec<f64>,
    dz: DVector<f64>,
    z_trial: DVector<f64>,
    /// Gradient of the cost in trajectory layout at the current point (`qp.g` is overwritten by
    /// trial linearisations).
    grad: Vec<f64>,
    costate: Vec<f64>,
    rl: f64,
    ru: f64,
    tmax: f64,
}

impl<const N: usize> StructuredSqp<N> {
    /// Allocates the workspace for the horizon and weights of `s`.
    pub fn new(s: &NmpcSettings) -> Result<Self, SolverError> {
        s.sqp.validate()?;
        let (np, nc) = (s.np, s.nc);
        let nx = 3 * N;
        let mut qp = RiccatiQp::new(nx, N, np, nc, s.sqp.qp)?;
        // Q = diag(I, r_d I, 0) for every state; R set per solve.
        for j in 0..np {
            let qj = &mut qp.q[j * nx * nx..(j + 1) * nx * nx];
            for a in 0..N {
                qj[a * nx + a] = 1.0;
                qj[(N + a) * nx + N + a] = s.r_d;
            }
        }
        let len = qp.len();
        Ok(Self {
            np,
            nc,
            r_d: s.r_d,
            r_t: s.r_t,
            settings: s.sqp,
            qp,
            torques: vec![0.0; nc * N],
            torques_trial: vec![0.0; nc * N],
            dz: DVector::zeros(nc * N),
            z_trial: DVector::zeros(nc * N),
            grad: vec![0.0; len],
            costate: vec![0.0; 2 * nx],
            rl: 0.0,
            ru: 0.0,
            tmax: 0.0,
        })
    }

    /// The QP solver (its last solution and multipliers).
    pub fn qp(&self) -> &RiccatiQp {
        &self.qp
    }

    /// Simulates from `problem.x0` with increments `z`; with `jac`, fills the QP's dynamics
    /// matrices and gradient. Writes the cumulative torques into `torques_trial` and returns the
    /// cost `½‖r‖²` (non-finite when anything is).
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
        for j in 0..np {
            if j < nc {
                for a in 0..N {
                    u[a] += z[j * N + a];
                    self.torques_trial[j * N + a] = u[a];
                }
            }
            let tau = j as f64 * dt;
            let xn = if jac {
                let (xn, g): (JointState<f64, N>, StepJacobian<N>) =
                    problem.model.step_with_jacobian(&x, &u, tau, &inp);
                let aj = &mut self.qp.a[j * nx * nx..(j + 1) * nx * nx];
                aj.fill(0.0);
                for c in 0..N {
                    for r in 0..N {
                        aj[c * nx + r] = g.qq[(r, c)];
                        aj[c * nx + N + r] = g.vq[(r, c)];
                        aj[(N + c) * nx + r] = g.qv[(r, c)];
                        aj[(N + c) * nx + N + r] = g.vv[(r, c)];
                        aj[(2 * N + c) * nx + r] = g.qu[(r, c)];
                        aj[(2 * N + c) * nx + N + r] = g.vu[(r, c)];
                    }
                    aj[(2 * N + c) * nx + 2 * N + c] = 1.0;
                }
                if j < nc {
                    let bj = &mut self.qp.b[j * nx * N..(j + 1) * nx * N];
                    bj.fill(0.0);
                    for c in 0..N {
                        for r in 0..N {
                            bj[c * nx + r] = g.qu[(r, c)];
                            bj[c * nx + N + r] = g.vu[(r, c)];
                        }
                        bj[c * nx + 2 * N + c] = 1.0;
                    }
                }
                xn
            } else {
                problem.model.step(&x, &u, tau, &inp)
            };
            x = xn;
            let tj = (j + 1) as f64 * dt;
            let xo = off + j * nx;
            for a in 0..N {
                let rq = x.q[a] - (inp.q_h[a] + tj * inp.qd_h[a]);
                let rv = sqrt_rd * (x.qd[a] - inp.qd_h[a]);
                sum += rq * rq + rv * rv;
                finite &= rq.is_finite() && rv.is_finite();
                if jac {
                    self.qp.g[xo + a] = rq;
                    self.qp.g[xo + N + a] = sqrt_rd * rv;
                    self.qp.g[xo + 2 * N + a] = 0.0;
                }
            }
        }
        for (k, zk) in z.iter().enumerate() {
            let rz = sqrt_rt * zk;
            sum += rz * rz;
            if jac {
                self.qp.g[k] = sqrt_rt * rz;
            }
        }
        if jac {
            finite &=
                self.qp.a.iter().all(|v| v.is_finite()) && self.qp.b.iter().all(|v| v.is_finite());
        }
        if finite {
            0.5 * sum
        } else {
            f64::NAN
        }
    }

    /// Step-space bounds of the QP at `z` (with `torques` the cumulative torques at `z`).
    fn shift_bounds(&mut self, z: &DVector<f64>) {
        let nx = 3 * N;
        let off = self.nc * N;
        for k in 0..off {
            self.qp.lo[k] = self.rl - z[k];
            self.qp.hi[k] = self.ru - z[k];
        }
        for j in 0..self.nc {
            for a in 0..N {
                let i = off + j * nx + 2 * N + a;
                self.qp.lo[i] = -self.tmax - self.torques[j * N + a];
                self.qp.hi[i] = self.tmax - self.torques[j * N + a];
            }
        }
    }

    /// KKT residual at `z` with the last QP multipliers, from `grad`, the QP's dynamics matrices
    /// (at `z`) and `torques`: stationarity by an adjoint sweep, box and cumulative violation,
    /// complementarity. Returns `(kkt, violation)`.
    fn kkt(&mut self, z: &DVector<f64>) -> (f64, f64) {
        let nx = 3 * N;
        let (np, nc) = (self.np, self.nc);
        let off = nc * N;
        let mult = self.qp.multipliers();
        let (mu, next) = self.costate.split_at_mut(nx);
        next.fill(0.0);
        let mut stat: f64 = 0.0;
        for j in (0..np).rev() {
            // μ_{j+1} = g_x + mult_x + A_{j+1}ᵀ μ_{j+2}.
            let xo = off + j * nx;
            for c in 0..nx {
                let mut s = self.grad[xo + c] + mult[xo + c];
                if j + 1 < np {
                    let a = &self.qp.a[(j + 1) * nx * nx..(j + 2) * nx * nx];
                    for t in 0..nx {
                        s += a[c * nx + t] * next[t];
                    }
                }
                mu[c] = s;
            }
            if j < nc {
                let b = &self.qp.b[j * nx * N..(j + 1) * nx * N];
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
        let mut viol: f64 = 0.0;
        let mut comp: f64 = 0.0;
        let mut check = |lo: f64, hi: f64, l: f64| {
            viol = viol.max(lo).max(hi);
            if l < 0.0 {
                comp = comp.max(-l * (-lo).max(0.0));
            } else if l > 0.0 {
                comp = comp.max(l * (-hi).max(0.0));
            }
        };
        for k in 0..off {
            check(self.rl - z[k], z[k] - self.ru, mult[k]);
        }
        for j in 0..nc {
            for a in 0..N {
                let t = self.torques[j * N + a];
                check(
                    -self.tmax - t,
                    t - self.tmax,
                    mult[off + j * nx + 2 * N + a],
                );
            }
        }
        let k = stat.max(viol).max(comp);
        (if k.is_nan() { f64::INFINITY } else { k }, viol)
    }

    /// Solves eq. 7 for `problem` (its `x0`, `t_prev`, `inputs`) under `limits` from the warm
    /// start `z` (overwritten with the result). Statuses as in [`crate::solver::Sqp::solve`].
    pub fn solve(
        &mut self,
        problem: &NmpcProblem<N>,
        limits: &TorqueLimits,
        z: &mut DVector<f64>,
    ) -> SqpInfo {
        let start = Instant::now();
        let mut info = SqpInfo {
            status: SqpStatus::MaxIterations,
            iterations: 0,
            qp_iterations: 0,
            cost: f64::NAN,
            kkt_residual: f64::INFINITY,
            solve_time: std::time::Duration::ZERO,
        };
        info.status = self.solve_inner(problem, limits, z, &mut info, start);
        info.solve_time = start.elapsed();
        info
    }

    fn solve_inner(
        &mut self,
        problem: &NmpcProblem<N>,
        limits: &TorqueLimits,
        z: &mut DVector<f64>,
        info: &mut SqpInfo,
        start: Instant,
    ) -> SqpStatus {
        let nx = 3 * N;
        let (np, nc) = (self.np, self.nc);
        let n = nc * N;
        if z.len() != n || problem.np() != np || problem.nc() != nc {
            return SqpStatus::DimensionMismatch;
        }
        if !z.iter().all(|v| v.is_finite()) {
            return SqpStatus::NonFiniteInput;
        }
        let (rate, tmax) = (limits.rate, limits.max);
        if rate.is_nan() || tmax.is_nan() || problem.t_prev.iter().any(|v| v.is_nan()) {
            return SqpStatus::NonFiniteInput;
        }
        if !(rate >= 0.0 && rate.is_finite() && tmax >= 0.0 && tmax.is_finite()) {
            return SqpStatus::Infeasible;
        }
        self.rl = -rate;
        self.ru = rate;
        self.tmax = tmax;
        let s = self.settings;
        // R = (r_t + δ) I, δ as in the dense path with the increment weight as the Hessian scale.
        let rdiag = self.r_t + s.hessian_regularization * (1.0 + self.r_t);
        for j in 0..nc {
            let rj = &mut self.qp.r[j * N * N..(j + 1) * N * N];
            rj.fill(0.0);
            for a in 0..N {
                rj[a * N + a] = rdiag;
            }
        }

        // Warm start: clamp into the box; if a cumulative bound is still violated, project the
        // original point (min ½|d|² with the same QP, dynamics reduced to T_{j} = T_{j−1} + u_j).
        self.z_trial.copy_from(z);
        for v in z.iter_mut() {
            *v = v.max(self.rl).min(self.ru);
        }
        let cum_viol = |z: &DVector<f64>, t: &mut [f64]| {
            let mut acc = problem.t_prev;
            let mut viol: f64 = 0.0;
            for j in 0..nc {
                for a in 0..N {
                    acc[a] += z[j * N + a];
                    t[j * N + a] = acc[a];
                    viol = viol.max(acc[a].abs() - tmax);
                }
            }
            viol
        };
        if cum_viol(z, &mut self.torques) > 0.1 * s.feasibility_tolerance {
            z.copy_from(&self.z_trial);
            cum_viol(z, &mut self.torques);
            self.qp.a.fill(0.0);
            self.qp.b.fill(0.0);
            for j in 0..np {
                let aj = &mut self.qp.a[j * nx * nx..(j + 1) * nx * nx];
                for a in 0..N {
                    aj[(2 * N + a) * nx + 2 * N + a] = 1.0;
                }
            }
            for j in 0..nc {
                let bj = &mut self.qp.b[j * nx * N..(j + 1) * nx * N];
                let rj = &mut self.qp.r[j * N * N..(j + 1) * N * N];
                for a in 0..N {
                    bj[a * nx + 2 * N + a] = 1.0;
                    rj[a * N + a] = 1.0;
                }
            }
            self.qp.g.fill(0.0);
            self.shift_bounds(z);
            let qi = self.qp.solve();
            info.qp_iterations += qi.iterations;
            match qi.status {
                QpStatus::Solved => {}
                QpStatus::Infeasible => {
                    z.copy_from(&self.z_trial);
                    return SqpStatus::Infeasible;
                }
                _ => {
                    z.copy_from(&self.z_trial);
                    return SqpStatus::QpFailed;
                }
            }
            for k in 0..n {
                z[k] = (z[k] + self.qp.solution()[k]).max(self.rl).min(self.ru);
            }
            for j in 0..nc {
                let rj = &mut self.qp.r[j * N * N..(j + 1) * N * N];
                for a in 0..N {
                    rj[a * N + a] = rdiag;
                }
            }
        }

        let mut cost = self.evaluate(problem, z.as_slice(), true);
        if !cost.is_finite() {
            return SqpStatus::NonFiniteInput;
        }
        self.torques.copy_from_slice(&self.torques_trial);
        self.grad.copy_from_slice(&self.qp.g);
        info.cost = cost;

        for it in 0..s.max_iterations {
            if it > 0 {
                if let Some(tmax) = s.max_time {
                    if start.elapsed() > tmax {
                        return SqpStatus::MaxTime;
                    }
                }
            }
            self.qp.g.copy_from_slice(&self.grad);
            self.shift_bounds(z);
            let qi = self.qp.solve();
            info.qp_iterations += qi.iterations;
            info.iterations = it + 1;
            match qi.status {
                QpStatus::Solved => {}
                QpStatus::NonFiniteInput => return SqpStatus::NonFiniteInput,
                _ => return SqpStatus::QpFailed,
            }
            let (kkt, viol) = self.kkt(z);
            info.kkt_residual = kkt;
            if kkt <= s.kkt_tolerance && viol <= s.feasibility_tolerance {
                return SqpStatus::Converged;
            }
            // Armijo backtracking on ½‖r(z + α d)‖²; slope gᵀd over the whole trajectory.
            let slack = 1e3 * f64::EPSILON * cost;
            let slope: f64 = self
                .grad
                .iter()
                .zip(self.qp.solution())
                .map(|(g, d)| g * d)
                .sum();
            if slope.is_nan() || slope >= slack {
                return SqpStatus::LineSearchFailed;
            }
            let slope = slope.min(0.0);
            self.dz
                .as_mut_slice()
                .copy_from_slice(&self.qp.solution()[..n]);
            let mut alpha = 1.0;
            let mut accepted = false;
            let mut have_jac = false;
            let mut any_finite = false;
            let mut c_trial = f64::NAN;
            for ls in 0..=s.max_line_search_steps {
                self.z_trial.copy_from(z);
                self.z_trial.axpy(alpha, &self.dz, 1.0);
                for v in self.z_trial.iter_mut() {
                    *v = v.max(self.rl).min(self.ru);
                }
                let zt = std::mem::replace(&mut self.z_trial, DVector::zeros(0));
                c_trial = self.evaluate(problem, zt.as_slice(), ls == 0);
                self.z_trial = zt;
                if c_trial.is_finite() {
                    any_finite = true;
                    if c_trial <= cost + s.armijo_constant * alpha * slope + slack {
                        accepted = true;
                        have_jac = ls == 0;
                        break;
                    }
                }
                alpha *= s.backtracking_factor;
            }
            if !accepted {
                return if any_finite {
                    SqpStatus::LineSearchFailed
                } else {
                    SqpStatus::NonFiniteInput
                };
            }
            if !have_jac {
                let zt = std::mem::replace(&mut self.z_trial, DVector::zeros(0));
                c_trial = self.evaluate(problem, zt.as_slice(), true);
                self.z_trial = zt;
                if !c_trial.is_finite() {
                    return SqpStatus::NonFiniteInput;
                }
            }
            z.copy_from(&self.z_trial);
            self.torques.copy_from_slice(&self.torques_trial);
            self.grad.copy_from_slice(&self.qp.g);
            cost = c_trial;
            info.cost = cost;
            let (kkt, viol) = self.kkt(z);
            info.kkt_residual = kkt;
            if kkt <= s.kkt_tolerance && viol <= s.feasibility_tolerance {
                return SqpStatus::Converged;
            }
        }
        SqpStatus::MaxIterations
    }
}
