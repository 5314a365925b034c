//! Gauss–Newton SQP for box- and linearly-constrained nonlinear least squares.
//!
//! ```text
//! min_z ½‖r(z)‖²   s.t.  zl ≤ z ≤ zu,   bl ≤ A z ≤ bu
//! ```
//!
//! This is the form of the NMPC problem of the paper (Aliyari & Vossoughi, eq. 7, with the input
//! and torque constraints of eqs. 8–9 written as box and linear rows).

use std::time::{Duration, Instant};

use nalgebra::{DMatrix, DVector};

use super::qp::{DenseQp, QpInfo, QpSettings, QpStatus};
use super::{check_range, SolverError};

/// A nonlinear least-squares objective `½‖r(z)‖²` with `r: ℝⁿ → ℝᵐ`.
pub trait LeastSquares {
    /// Number of decision variables `n`.
    fn num_vars(&self) -> usize;
    /// Number of residuals `m`.
    fn num_residuals(&self) -> usize;
    /// Writes `r(z)` into `r` (length `m`); returns `false` if anything is non-finite.
    fn residuals(&mut self, z: &[f64], r: &mut [f64]) -> bool;
    /// Writes `r(z)` into `r` and its Jacobian `∂r/∂z` (`m × n`) into `jac`; returns `false` if
    /// anything is non-finite.
    fn residuals_jacobian(&mut self, z: &[f64], r: &mut [f64], jac: &mut DMatrix<f64>) -> bool;
}

/// Box and general linear constraints `zl ≤ z ≤ zu`, `bl ≤ A z ≤ bu` (entries may be ±∞;
/// `bl[i] = bu[i]` gives an equality row).
#[derive(Debug, Clone, PartialEq)]
pub struct Constraints {
    /// Lower bounds on `z` (length `n`).
    pub zl: DVector<f64>,
    /// Upper bounds on `z` (length `n`).
    pub zu: DVector<f64>,
    /// General constraint matrix (`p × n`).
    pub a: DMatrix<f64>,
    /// Lower bounds on `A z` (length `p`).
    pub bl: DVector<f64>,
    /// Upper bounds on `A z` (length `p`).
    pub bu: DVector<f64>,
}

impl Constraints {
    /// Unbounded constraints for `n` variables and `p` general rows (`A = 0`, all bounds ±∞).
    pub fn unbounded(n: usize, p: usize) -> Self {
        Self {
            zl: DVector::from_element(n, f64::NEG_INFINITY),
            zu: DVector::from_element(n, f64::INFINITY),
            a: DMatrix::zeros(p, n),
            bl: DVector::from_element(p, f64::NEG_INFINITY),
            bu: DVector::from_element(p, f64::INFINITY),
        }
    }
}

/// Settings of the SQP solver. Use [`SqpSettings::default`] and override fields as needed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SqpSettings {
    /// Maximum number of SQP iterations (QP subproblems, not counting the projection of an
    /// infeasible warm start). Default `20`; allowed `≥ 1`.
    pub max_iterations: usize,
    /// Converged when the KKT residual (max of stationarity `‖Jᵀr + λ_box + Aᵀλ‖∞`, primal
    /// violation and complementarity `max |λᵢ|·slackᵢ`) is at most this. Default `1e-8`;
    /// allowed `[0, 1]` (`0` disables convergence, useful for fixed iteration counts).
    pub kkt_tolerance: f64,
    /// Maximum absolute constraint violation accepted for a `Converged` result; warm starts
    /// violating general rows by more than a tenth of this are projected. Default `1e-9`;
    /// allowed `[1e-15, 1e-3]`.
    pub feasibility_tolerance: f64,
    /// Gauss–Newton Hessian regularisation: `H = JᵀJ + δ I` with
    /// `δ = hessian_regularization · (1 + maxᵢ (JᵀJ)ᵢᵢ)`. Default `1e-12`; allowed `[0, 1]`.
    /// (The QP needs `H` positive definite; with `0` a rank-deficient `J` gives `QpFailed`.)
    pub hessian_regularization: f64,
    /// Armijo sufficient-decrease constant `c₁` in `φ(α) ≤ φ(0) + c₁ α ∇φᵀd`.
    /// Default `1e-4`; allowed `(0, 0.5)`.
    pub armijo_constant: f64,
    /// Step-length reduction factor of the backtracking line search. Default `0.5`;
    /// allowed `[0.01, 0.9]`.
    pub backtracking_factor: f64,
    /// Maximum number of step-length reductions per line search. Default `30`; allowed `≥ 0`.
    pub max_line_search_steps: usize,
    /// Hessian model of the QP subproblems. Default [`HessianModel::StructuredSecant`].
    pub hessian: HessianModel,
    /// Wall-clock budget for one solve; when exceeded the current (best, feasible) iterate is
    /// returned with [`SqpStatus::MaxTime`]. Checked once per iteration. Default `None`.
    pub max_time: Option<Duration>,
    /// Settings of the inner QP solver (see [`QpSettings`]). Default `QpSettings::default()`.
    pub qp: QpSettings,
}

impl Default for SqpSettings {
    fn default() -> Self {
        Self {
            max_iterations: 20,
            kkt_tolerance: 1e-8,
            feasibility_tolerance: 1e-9,
            hessian_regularization: 1e-12,
            armijo_constant: 1e-4,
            backtracking_factor: 0.5,
            max_line_search_steps: 30,
            hessian: HessianModel::StructuredSecant,
            max_time: None,
            qp: QpSettings::default(),
        }
    }
}

impl SqpSettings {
    /// Checks every field against its allowed range; the error names the field and value.
    pub fn validate(&self) -> Result<(), SolverError> {
        if self.max_iterations < 1 {
            return Err(SolverError::InvalidSetting {
                field: "max_iterations",
                value: self.max_iterations as f64,
                allowed: ">= 1",
            });
        }
        check_range("kkt_tolerance", self.kkt_tolerance, 0.0, 1.0, "[0, 1]")?;
        check_range(
            "feasibility_tolerance",
            self.feasibility_tolerance,
            1e-15,
            1e-3,
            "[1e-15, 1e-3]",
        )?;
        check_range(
            "hessian_regularization",
            self.hessian_regularization,
            0.0,
            1.0,
            "[0, 1]",
        )?;
        if !(self.armijo_constant > 0.0 && self.armijo_constant < 0.5) {
            return Err(SolverError::InvalidSetting {
                field: "armijo_constant",
                value: self.armijo_constant,
                allowed: "(0, 0.5)",
            });
        }
        check_range(
            "backtracking_factor",
            self.backtracking_factor,
            0.01,
            0.9,
            "[0.01, 0.9]",
        )?;
        self.qp.validate()
    }
}

/// The Hessian model of the QP subproblems.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HessianModel {
    /// Gauss–Newton `JᵀJ`: exact for zero residuals, linear convergence otherwise.
    GaussNewton,
    /// `JᵀJ + S`, with `S` a structured secant (Dennis–Gay–Welsch, as in NL2SOL) estimate of the
    /// neglected second-order term `Σ rᵢ ∇²rᵢ`, updated from `y♯ = (J₊ − J)ᵀ r₊` after each
    /// step and sized as in NL2SOL. Superlinear on large-residual problems; when `JᵀJ + S` is
    /// not positive definite the iteration falls back to Gauss–Newton (`S` reset). Each solve
    /// starts from `S = 0`, so its first step is the Gauss–Newton step.
    StructuredSecant,
}

/// Termination status of an SQP solve. Only `Converged` certifies a KKT point; every other
/// status still leaves a finite, feasible `z` (the best iterate found) except where noted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SqpStatus {
    /// KKT residual ≤ `kkt_tolerance` and constraint violation ≤ `feasibility_tolerance`.
    Converged,
    /// `max_iterations` reached; `z` is the last (best) feasible iterate.
    MaxIterations,
    /// `max_time` exceeded; `z` is the last (best) feasible iterate.
    MaxTime,
    /// A QP subproblem failed (numerical error or iteration limit); `z` is the last iterate.
    QpFailed,
    /// The constraints are infeasible (projection QP infeasible, or crossed/NaN bounds);
    /// `z` is left unchanged.
    Infeasible,
    /// Non-finite warm start or constraint data, or `r`/`J` non-finite at an iterate (or at
    /// every line-search trial point); `z` is the last finite feasible iterate (or unchanged
    /// if the data itself is non-finite).
    NonFiniteInput,
    /// The line search found no sufficient decrease (or the QP step was not a descent
    /// direction) although the KKT test failed; `z` is the last feasible iterate.
    LineSearchFailed,
    /// `z`, the constraints or the problem dimensions differ from those given to
    /// [`Sqp::new`] (a programming error); `z` is unchanged.
    DimensionMismatch,
}

/// Summary of an SQP solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SqpInfo {
    /// Termination status.
    pub status: SqpStatus,
    /// Number of SQP iterations (QP subproblems solved, excluding the warm-start projection).
    pub iterations: usize,
    /// Total number of QP active-set iterations, including the projection.
    pub qp_iterations: usize,
    /// `½‖r(z)‖²` at the returned `z` (NaN if never evaluated).
    pub cost: f64,
    /// KKT residual at the returned `z` with the last QP multipliers (∞ if not computed).
    pub kkt_residual: f64,
    /// Wall-clock duration of the solve.
    pub solve_time: Duration,
}

/// Gauss–Newton SQP solver for the NMPC problem of the paper's eq. 7 with the constraints of
/// eqs. 8–9 (Aliyari & Vossoughi), posed as constrained nonlinear least squares
/// `min ½‖r(z)‖² s.t. zl ≤ z ≤ zu, bl ≤ A z ≤ bu`.
///
/// Each iteration solves the QP `min ½dᵀ(JᵀJ + δI)d + (Jᵀr)ᵀd` subject to the constraints
/// shifted to the current point with [`DenseQp`], then performs an Armijo backtracking line
/// search on `½‖r‖²`. Infeasible warm starts are first projected onto the feasible set (the same
/// QP with `H = I`), so every iterate is feasible. Termination uses the KKT residual of the
/// nonlinear problem computed from the exact gradient `Jᵀr` and the QP multipliers.
///
/// All work vectors are allocated by [`Sqp::new`]; [`Sqp::solve`] allocates nothing and never
/// panics. Not converging is a status ([`SqpStatus`]), never an error.
#[derive(Debug, Clone)]
pub struct Sqp {
    n: usize,
    m: usize,
    p: usize,
    settings: SqpSettings,
    qp: DenseQp,
    r: DVector<f64>,
    r_trial: DVector<f64>,
    jac: DMatrix<f64>,
    hess: DMatrix<f64>,
    grad: DVector<f64>,
    dz: DVector<f64>,
    z_trial: DVector<f64>,
    /// Step-space bounds for the QP.
    dlb: DVector<f64>,
    dub: DVector<f64>,
    dbl: DVector<f64>,
    dbu: DVector<f64>,
    /// `A z` at the current iterate.
    az: DVector<f64>,
    work: DVector<f64>,
    /// Per Jacobian column: the row range `[first, last)` holding its nonzeros.
    nz: Vec<(usize, usize)>,
    /// Structured secant correction `S` and its update buffers.
    secant: DMatrix<f64>,
    jac_prev: DMatrix<f64>,
    grad_prev: DVector<f64>,
    sec_s: DVector<f64>,
    sec_y: DVector<f64>,
    sec_w: DVector<f64>,
    kkt_stationarity: f64,
    kkt_violation: f64,
    kkt_complementarity: f64,
}

impl Sqp {
    /// Creates a solver for `n` variables, `m` residuals and `p` general constraint rows,
    /// validating `settings` and allocating all workspace.
    pub fn new(n: usize, m: usize, p: usize, settings: SqpSettings) -> Result<Self, SolverError> {
        settings.validate()?;
        if n == 0 {
            return Err(SolverError::InvalidDimension {
                what: "n",
                value: n,
                allowed: "at least one variable",
            });
        }
        Ok(Self {
            n,
            m,
            p,
            settings,
            qp: DenseQp::with_settings(n, p, settings.qp)?,
            r: DVector::zeros(m),
            r_trial: DVector::zeros(m),
            jac: DMatrix::zeros(m, n),
            hess: DMatrix::zeros(n, n),
            grad: DVector::zeros(n),
            dz: DVector::zeros(n),
            z_trial: DVector::zeros(n),
            dlb: DVector::zeros(n),
            dub: DVector::zeros(n),
            dbl: DVector::zeros(p),
            dbu: DVector::zeros(p),
            az: DVector::zeros(p),
            work: DVector::zeros(n),
            nz: vec![(0, 0); n],
            secant: DMatrix::zeros(n, n),
            jac_prev: DMatrix::zeros(m, n),
            grad_prev: DVector::zeros(n),
            sec_s: DVector::zeros(n),
            sec_y: DVector::zeros(n),
            sec_w: DVector::zeros(n),
            kkt_stationarity: f64::INFINITY,
            kkt_violation: f64::INFINITY,
            kkt_complementarity: f64::INFINITY,
        })
    }

    /// Current settings.
    pub fn settings(&self) -> &SqpSettings {
        &self.settings
    }

    /// Replaces the settings after validating them.
    pub fn set_settings(&mut self, settings: SqpSettings) -> Result<(), SolverError> {
        settings.validate()?;
        self.qp.set_settings(settings.qp)?;
        self.settings = settings;
        Ok(())
    }

    /// Box multipliers of the last QP subproblem (sign convention of
    /// [`DenseQp::multipliers_box`]: `Jᵀr + λ_box + Aᵀλ_gen ≈ 0` at a KKT point).
    pub fn multipliers_box(&self) -> &DVector<f64> {
        self.qp.multipliers_box()
    }

    /// General-row multipliers of the last QP subproblem.
    pub fn multipliers_general(&self) -> &DVector<f64> {
        self.qp.multipliers_general()
    }

    /// Residuals `r(z)` at the returned iterate (valid after a solve that evaluated them).
    pub fn residuals(&self) -> &DVector<f64> {
        &self.r
    }

    /// Gradient `Jᵀr` of the cost at the returned iterate (valid when the last KKT residual is
    /// finite).
    pub fn gradient(&self) -> &DVector<f64> {
        &self.grad
    }

    /// Components of the last KKT residual: (stationarity, primal violation, complementarity).
    pub fn kkt_components(&self) -> (f64, f64, f64) {
        (
            self.kkt_stationarity,
            self.kkt_violation,
            self.kkt_complementarity,
        )
    }

    /// Solves the problem; `z` is the warm start on entry and the result on exit.
    ///
    /// Allocates nothing and never panics; see [`SqpStatus`] for the outcomes.
    pub fn solve<P: LeastSquares + ?Sized>(
        &mut self,
        problem: &mut P,
        cons: &Constraints,
        z: &mut DVector<f64>,
    ) -> SqpInfo {
        let start = Instant::now();
        let mut info = SqpInfo {
            status: SqpStatus::DimensionMismatch,
            iterations: 0,
            qp_iterations: 0,
            cost: f64::NAN,
            kkt_residual: f64::INFINITY,
            solve_time: Duration::ZERO,
        };
        self.kkt_stationarity = f64::INFINITY;
        self.kkt_violation = f64::INFINITY;
        self.kkt_complementarity = f64::INFINITY;
        info.status = self.run(problem, cons, z, &mut info, start);
        info.solve_time = start.elapsed();
        info
    }

    fn run<P: LeastSquares + ?Sized>(
        &mut self,
        problem: &mut P,
        cons: &Constraints,
        z: &mut DVector<f64>,
        info: &mut SqpInfo,
        start: Instant,
    ) -> SqpStatus {
        let (n, m, p) = (self.n, self.m, self.p);
        if z.len() != n
            || problem.num_vars() != n
            || problem.num_residuals() != m
            || cons.zl.len() != n
            || cons.zu.len() != n
            || cons.a.nrows() != p
            || cons.a.ncols() != n
            || cons.bl.len() != p
            || cons.bu.len() != p
        {
            return SqpStatus::DimensionMismatch;
        }
        if !z.iter().all(|v| v.is_finite()) || !cons.a.iter().all(|v| v.is_finite()) {
            return SqpStatus::NonFiniteInput;
        }
        for (l, u) in cons
            .zl
            .iter()
            .zip(cons.zu.iter())
            .chain(cons.bl.iter().zip(cons.bu.iter()))
        {
            if l.is_nan() || u.is_nan() {
                return SqpStatus::NonFiniteInput;
            }
            if *l > *u || *l == f64::INFINITY || *u == f64::NEG_INFINITY {
                return SqpStatus::Infeasible;
            }
        }
        let s = self.settings;

        // Make the warm start feasible: clamping is the exact projection onto the box; if the
        // clamped point still violates a general row, project the original point with a QP.
        self.z_trial.copy_from(z);
        clamp(z, &cons.zl, &cons.zu);
        if p > 0 {
            self.az.gemv(1.0, &cons.a, z, 0.0);
        }
        if row_violation(&self.az, &cons.bl, &cons.bu) > 0.1 * s.feasibility_tolerance {
            // Euclidean projection: min ½|d|² s.t. constraints on z + d.
            z.copy_from(&self.z_trial);
            if p > 0 {
                self.az.gemv(1.0, &cons.a, z, 0.0);
            }
            self.hess.fill_with_identity();
            self.grad.fill(0.0);
            self.shift_bounds(cons, z);
            let qi = self.solve_step_qp(cons);
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
            *z += &self.dz;
            clamp(z, &cons.zl, &cons.zu);
            if p > 0 {
                self.az.gemv(1.0, &cons.a, z, 0.0);
            }
        }

        // Residuals and Jacobian at the (feasible) start.
        if !problem.residuals_jacobian(z.as_slice(), self.r.as_mut_slice(), &mut self.jac)
            || !self.r.iter().all(|v| v.is_finite())
        {
            return SqpStatus::NonFiniteInput;
        }
        let mut cost = 0.5 * self.r.norm_squared();
        self.grad.gemv_tr(1.0, &self.jac, &self.r, 0.0);
        // g = Jᵀr is NaN/∞ whenever J (or r) has a non-finite entry.
        if !cost.is_finite() || !self.grad.iter().all(|v| v.is_finite()) {
            return SqpStatus::NonFiniteInput;
        }
        info.cost = cost;

        let mut status = SqpStatus::MaxIterations;
        let secant = s.hessian == HessianModel::StructuredSecant;
        let mut secant_active = false;
        if secant {
            self.secant.fill(0.0);
        }
        for it in 0..s.max_iterations {
            if it > 0 {
                if let Some(tmax) = s.max_time {
                    if start.elapsed() > tmax {
                        status = SqpStatus::MaxTime;
                        break;
                    }
                }
            }
            // Gauss–Newton Hessian JᵀJ + δI (lower triangle via column dots, then mirrored),
            // each dot restricted to the rows where both columns can be nonzero (condensed
            // NMPC Jacobians are block lower triangular, scenario trees block sparse).
            for j in 0..n {
                let col = &self.jac.as_slice()[j * m..(j + 1) * m];
                let first = col.iter().position(|v| *v != 0.0).unwrap_or(m);
                let last = col.iter().rposition(|v| *v != 0.0).map_or(0, |l| l + 1);
                self.nz[j] = (first, last.max(first));
            }
            let mut maxdiag: f64 = 0.0;
            let js = self.jac.as_slice();
            for j in 0..n {
                let (fj, lj) = self.nz[j];
                let cj = &js[j * m..(j + 1) * m];
                for i in j..n {
                    let (fi, li) = self.nz[i];
                    let (lo, hi) = (fi.max(fj), li.min(lj));
                    let v = if lo < hi {
                        dot(&js[i * m + lo..i * m + hi], &cj[lo..hi])
                    } else {
                        0.0
                    };
                    self.hess[(i, j)] = v;
                    self.hess[(j, i)] = v;
                }
                maxdiag = maxdiag.max(self.hess[(j, j)]);
            }
            let delta = s.hessian_regularization * (1.0 + maxdiag);
            for j in 0..n {
                self.hess[(j, j)] += delta;
            }
            self.shift_bounds(cons, z);
            if secant_active {
                self.hess += &self.secant;
            }
            let mut qi = self.solve_step_qp(cons);
            if secant_active && qi.status == QpStatus::NumericalError {
                // JᵀJ + S not positive definite: drop S, take the Gauss–Newton step.
                self.hess -= &self.secant;
                self.secant.fill(0.0);
                secant_active = false;
                info.qp_iterations += qi.iterations;
                qi = self.solve_step_qp(cons);
            }
            info.qp_iterations += qi.iterations;
            info.iterations = it + 1;
            match qi.status {
                QpStatus::Solved => {}
                QpStatus::NonFiniteInput => return SqpStatus::NonFiniteInput,
                _ => return SqpStatus::QpFailed,
            }
            // KKT at the current point with the fresh multipliers.
            let kkt = self.kkt(cons, z);
            info.kkt_residual = kkt;
            if kkt <= s.kkt_tolerance && self.kkt_violation <= s.feasibility_tolerance {
                return SqpStatus::Converged;
            }
            // Armijo backtracking on φ(α) = ½‖r(z + α d)‖².
            // Allow for rounding noise in evaluating ½‖r‖² so that tiny steps near a KKT point
            // (predicted decrease below the noise level) are not rejected.
            let slack = 1e3 * f64::EPSILON * cost;
            let slope = self.grad.dot(&self.dz);
            if slope.is_nan() || slope >= slack {
                return SqpStatus::LineSearchFailed;
            }
            let slope = slope.min(0.0);
            if secant {
                self.jac_prev.copy_from(&self.jac);
                self.grad_prev.copy_from(&self.grad);
            }
            let mut alpha = 1.0;
            let mut accepted = false;
            let mut have_jac = false;
            let mut any_finite = false;
            for ls in 0..=s.max_line_search_steps {
                self.z_trial.copy_from(z);
                self.z_trial.axpy(alpha, &self.dz, 1.0);
                clamp(&mut self.z_trial, &cons.zl, &cons.zu);
                let ok = if ls == 0 {
                    // The full step is usually accepted: evaluate the Jacobian right away.
                    problem.residuals_jacobian(
                        self.z_trial.as_slice(),
                        self.r_trial.as_mut_slice(),
                        &mut self.jac,
                    )
                } else {
                    problem.residuals(self.z_trial.as_slice(), self.r_trial.as_mut_slice())
                };
                let c_trial = 0.5 * self.r_trial.norm_squared();
                if ok && c_trial.is_finite() {
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
            if !have_jac
                && !problem.residuals_jacobian(
                    self.z_trial.as_slice(),
                    self.r_trial.as_mut_slice(),
                    &mut self.jac,
                )
            {
                return SqpStatus::NonFiniteInput;
            }
            let c_new = 0.5 * self.r_trial.norm_squared();
            self.grad.gemv_tr(1.0, &self.jac, &self.r_trial, 0.0);
            if !c_new.is_finite() || !self.grad.iter().all(|v| v.is_finite()) {
                return SqpStatus::NonFiniteInput;
            }
            if secant {
                secant_active = self.update_secant(z) || secant_active;
            }
            // Accept the step.
            z.copy_from(&self.z_trial);
            std::mem::swap(&mut self.r, &mut self.r_trial);
            cost = c_new;
            info.cost = cost;
            if p > 0 {
                self.az.gemv(1.0, &cons.a, z, 0.0);
            }
            // KKT at the new point with the last multipliers (exact for linear residuals after a
            // full step; avoids one QP per solve near convergence).
            let kkt = self.kkt(cons, z);
            info.kkt_residual = kkt;
            if kkt <= s.kkt_tolerance && self.kkt_violation <= s.feasibility_tolerance {
                return SqpStatus::Converged;
            }
        }
        status
    }

    /// Dennis–Gay–Welsch update of the structured secant `S` for the step `z → z_trial`, with
    /// `self.grad`, `self.jac`, `self.r_trial` at the new point and `grad_prev`, `jac_prev` at
    /// the old one. Returns whether `S` was updated (skipped when `yᵀs ≤ 0`).
    fn update_secant(&mut self, z: &DVector<f64>) -> bool {
        // s = z₊ − z, y = g₊ − g, y♯ = g₊ − J_prevᵀ r₊ = (J₊ − J)ᵀ r₊.
        self.sec_s.copy_from(&self.z_trial);
        self.sec_s -= z;
        self.sec_y.copy_from(&self.grad);
        self.sec_y -= &self.grad_prev;
        let ys = self.sec_y.dot(&self.sec_s);
        let ss = self.sec_s.norm_squared();
        if ys.is_nan() || ys <= 1e-14 * ss.max(f64::MIN_POSITIVE) || !ys.is_finite() {
            return false;
        }
        // w = y♯ − S s, with NL2SOL's sizing S ← τ S, τ = min(1, |sᵀy♯| / |sᵀ S s|).
        self.sec_w.copy_from(&self.grad);
        self.sec_w.gemv_tr(-1.0, &self.jac_prev, &self.r_trial, 1.0);
        let sy_sharp = self.sec_s.dot(&self.sec_w);
        self.work.gemv(1.0, &self.secant, &self.sec_s, 0.0);
        let sss = self.sec_s.dot(&self.work);
        if sss.abs() > 0.0 {
            let tau = (sy_sharp.abs() / sss.abs()).min(1.0);
            self.secant *= tau;
            self.work *= tau;
        }
        self.sec_w -= &self.work;
        // S ← S + (w yᵀ + y wᵀ)/(yᵀs) − (wᵀs) y yᵀ/(yᵀs)².
        let ws = self.sec_w.dot(&self.sec_s);
        let n = self.n;
        for j in 0..n {
            for i in 0..n {
                self.secant[(i, j)] +=
                    (self.sec_w[i] * self.sec_y[j] + self.sec_y[i] * self.sec_w[j]) / ys
                        - ws * self.sec_y[i] * self.sec_y[j] / (ys * ys);
            }
        }
        if self.secant.iter().all(|v| v.is_finite()) {
            true
        } else {
            self.secant.fill(0.0);
            false
        }
    }

    /// The QP in step space with the current `hess`, `grad` and shifted bounds; the step goes
    /// into `dz`.
    fn solve_step_qp(&mut self, cons: &Constraints) -> QpInfo {
        self.qp.solve(
            &self.hess,
            &self.grad,
            &self.dlb,
            &self.dub,
            &cons.a,
            &self.dbl,
            &self.dbu,
            &mut self.dz,
        )
    }

    /// QP bounds in step space at `z` (uses `self.az = A z`).
    fn shift_bounds(&mut self, cons: &Constraints, z: &DVector<f64>) {
        for i in 0..self.n {
            self.dlb[i] = cons.zl[i] - z[i];
            self.dub[i] = cons.zu[i] - z[i];
        }
        for j in 0..self.p {
            self.dbl[j] = cons.bl[j] - self.az[j];
            self.dbu[j] = cons.bu[j] - self.az[j];
        }
    }

    /// KKT residual at `z` (with `self.grad = Jᵀr(z)`, `self.az = A z`) and the current QP
    /// multipliers; stores the components.
    fn kkt(&mut self, cons: &Constraints, z: &DVector<f64>) -> f64 {
        let lb = self.qp.multipliers_box();
        let lg = self.qp.multipliers_general();
        self.work.copy_from(&self.grad);
        self.work += lb;
        if self.p > 0 {
            self.work.gemv_tr(1.0, &cons.a, lg, 1.0);
        }
        let stat = self.work.amax();
        let mut viol: f64 = 0.0;
        let mut comp: f64 = 0.0;
        for i in 0..self.n {
            let (lo, hi) = (cons.zl[i] - z[i], z[i] - cons.zu[i]);
            viol = viol.max(lo).max(hi);
            let l = lb[i];
            if l < 0.0 {
                comp = comp.max(-l * (-lo).max(0.0));
            } else if l > 0.0 {
                comp = comp.max(l * (-hi).max(0.0));
            }
        }
        for j in 0..self.p {
            let (lo, hi) = (cons.bl[j] - self.az[j], self.az[j] - cons.bu[j]);
            viol = viol.max(lo).max(hi);
            let l = lg[j];
            if l < 0.0 {
                comp = comp.max(-l * (-lo).max(0.0));
            } else if l > 0.0 {
                comp = comp.max(l * (-hi).max(0.0));
            }
        }
        self.kkt_stationarity = stat;
        self.kkt_violation = viol;
        self.kkt_complementarity = comp;
        let k = stat.max(viol).max(comp);
        if k.is_nan() {
            f64::INFINITY
        } else {
            k
        }
    }
}

/// `aᵀb` of two equally long slices, four partial sums.
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    let mut acc = [0.0f64; 4];
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// Largest violation of `bl ≤ v ≤ bu`.
fn row_violation(v: &DVector<f64>, bl: &DVector<f64>, bu: &DVector<f64>) -> f64 {
    let mut viol: f64 = 0.0;
    for j in 0..v.len() {
        viol = viol.max(bl[j] - v[j]).max(v[j] - bu[j]);
    }
    viol
}

/// Clamps `z` into `[zl, zu]` (removes rounding errors of steps between feasible points).
fn clamp(z: &mut DVector<f64>, zl: &DVector<f64>, zu: &DVector<f64>) {
    for i in 0..z.len() {
        z[i] = z[i].max(zl[i]).min(zu[i]);
    }
}
