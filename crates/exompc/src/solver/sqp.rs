//! Gauss–Newton SQP for box- and linearly-constrained nonlinear least squares.
//!
//! ```text
//! min_z ½‖r(z)‖²   s.t.  zl ≤ z ≤ zu,   bl ≤ A z ≤ bu
//! ```
//!
//! This is the form of the NMPC problem of the paper (Aliyari & Vossoughi, eq. 7, with the input
//! and torque constraints of eqs. 8–9 written as box and linear rows).

use alloc::{vec, vec::Vec};
use nalgebra::{DMatrix, DVector};

use super::engine::{self, finite_or_inf, BoundCheck, HessianShift, SqpSteps};
use super::qp::{DenseQp, QpInfo, QpStatus};
pub use super::settings::{HessianModel, SqpInfo, SqpSettings, SqpStatus};
use super::SolverError;

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
    /// Adds the second-order term `Σᵢ rᵢ ∇²rᵢ(z)` of the cost Hessian (`n × n`) to `hess`, with
    /// `r = r(z)`; used by [`HessianModel::Exact`]. Returns `false` when the problem does not
    /// provide it (the default) or anything is non-finite; the SQP then takes the
    /// Gauss–Newton step.
    fn add_residual_curvature(&mut self, z: &[f64], r: &[f64], hess: &mut DMatrix<f64>) -> bool {
        let _ = (z, r, hess);
        false
    }
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
/// The steps are those of the shared SQP engine (`solver/engine.rs`): input checks,
/// feasibility projection, Hessian model, QP, termination test, line search.
///
/// All work vectors are allocated by [`Sqp::new`]; [`Sqp::solve`] allocates nothing and never
/// panics. Not converging is a status ([`SqpStatus`]), never an error.
#[derive(Debug, Clone)]
pub struct Sqp {
    settings: SqpSettings,
    z_trial: DVector<f64>,
    w: DenseWork,
}

/// Workspace of the dense back-end.
#[derive(Debug, Clone)]
struct DenseWork {
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
    /// Structured secant correction `S`, whether it is in use, and its update buffers.
    secant: DMatrix<f64>,
    secant_active: bool,
    jac_prev: DMatrix<f64>,
    grad_prev: DVector<f64>,
    sec_s: DVector<f64>,
    sec_y: DVector<f64>,
    sec_w: DVector<f64>,
    kkt_stationarity: f64,
    kkt_violation: f64,
    kkt_complementarity: f64,
    /// Largest diagonal entry of `JᵀJ` at the last Gauss–Newton Hessian.
    maxdiag: f64,
    /// Inertia correction of the exact Hessian.
    shift: HessianShift,
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
            settings,
            z_trial: DVector::zeros(n),
            w: DenseWork {
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
                dlb: DVector::zeros(n),
                dub: DVector::zeros(n),
                dbl: DVector::zeros(p),
                dbu: DVector::zeros(p),
                az: DVector::zeros(p),
                work: DVector::zeros(n),
                nz: vec![(0, 0); n],
                secant: DMatrix::zeros(n, n),
                secant_active: false,
                jac_prev: DMatrix::zeros(m, n),
                grad_prev: DVector::zeros(n),
                sec_s: DVector::zeros(n),
                sec_y: DVector::zeros(n),
                sec_w: DVector::zeros(n),
                kkt_stationarity: f64::INFINITY,
                kkt_violation: f64::INFINITY,
                kkt_complementarity: f64::INFINITY,
                maxdiag: 0.0,
                shift: HessianShift::default(),
            },
        })
    }

    /// Current settings.
    pub fn settings(&self) -> &SqpSettings {
        &self.settings
    }

    /// Replaces the settings after validating them.
    pub fn set_settings(&mut self, settings: SqpSettings) -> Result<(), SolverError> {
        settings.validate()?;
        self.w.qp.set_settings(settings.qp)?;
        self.settings = settings;
        self.w.settings = settings;
        Ok(())
    }

    /// Box multipliers of the last QP subproblem (sign convention of
    /// [`DenseQp::multipliers_box`]: `Jᵀr + λ_box + Aᵀλ_gen ≈ 0` at a KKT point).
    pub fn multipliers_box(&self) -> &DVector<f64> {
        self.w.qp.multipliers_box()
    }

    /// General-row multipliers of the last QP subproblem.
    pub fn multipliers_general(&self) -> &DVector<f64> {
        self.w.qp.multipliers_general()
    }

    /// Residuals `r(z)` at the returned iterate (valid after a solve that evaluated them).
    pub fn residuals(&self) -> &DVector<f64> {
        &self.w.r
    }

    /// Gradient `Jᵀr` of the cost at the returned iterate (valid when the last KKT residual is
    /// finite).
    pub fn gradient(&self) -> &DVector<f64> {
        &self.w.grad
    }

    /// Components of the last KKT residual: (stationarity, primal violation, complementarity).
    pub fn kkt_components(&self) -> (f64, f64, f64) {
        (
            self.w.kkt_stationarity,
            self.w.kkt_violation,
            self.w.kkt_complementarity,
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
        self.w.kkt_stationarity = f64::INFINITY;
        self.w.kkt_violation = f64::INFINITY;
        self.w.kkt_complementarity = f64::INFINITY;
        let mut steps = DenseSteps {
            w: &mut self.w,
            problem,
            cons,
        };
        engine::solve(&mut steps, &self.settings, &mut self.z_trial, z)
    }
}

/// The dense back-end of the engine for one solve: the condensed problem, its constraints and
/// the workspace.
struct DenseSteps<'a, P: ?Sized> {
    w: &'a mut DenseWork,
    problem: &'a mut P,
    cons: &'a Constraints,
}

impl<P: LeastSquares + ?Sized> SqpSteps for DenseSteps<'_, P> {
    fn check_inputs(&mut self, z: &DVector<f64>) -> Result<(), SqpStatus> {
        let (w, cons) = (&mut *self.w, self.cons);
        let (n, m, p) = (w.n, w.m, w.p);
        if z.len() != n
            || self.problem.num_vars() != n
            || self.problem.num_residuals() != m
            || cons.zl.len() != n
            || cons.zu.len() != n
            || cons.a.nrows() != p
            || cons.a.ncols() != n
            || cons.bl.len() != p
            || cons.bu.len() != p
        {
            return Err(SqpStatus::DimensionMismatch);
        }
        if !z.iter().all(|v| v.is_finite()) || !cons.a.iter().all(|v| v.is_finite()) {
            return Err(SqpStatus::NonFiniteInput);
        }
        for (l, u) in cons
            .zl
            .iter()
            .zip(cons.zu.iter())
            .chain(cons.bl.iter().zip(cons.bu.iter()))
        {
            if l.is_nan() || u.is_nan() {
                return Err(SqpStatus::NonFiniteInput);
            }
            if *l > *u || *l == f64::INFINITY || *u == f64::NEG_INFINITY {
                return Err(SqpStatus::Infeasible);
            }
        }
        // Each solve starts from S = 0 (its first step is the Gauss–Newton step).
        w.secant_active = false;
        w.shift.reset();
        if w.settings.hessian == HessianModel::StructuredSecant {
            w.secant.fill(0.0);
        }
        Ok(())
    }

    fn clamp(&self, z: &mut DVector<f64>) {
        clamp(z, &self.cons.zl, &self.cons.zu);
    }

    fn general_violation(&mut self, z: &DVector<f64>) -> f64 {
        if self.w.p > 0 {
            self.w.az.gemv(1.0, &self.cons.a, z, 0.0);
        }
        row_violation(&self.w.az, &self.cons.bl, &self.cons.bu)
    }

    fn projection_qp(&mut self, z: &DVector<f64>) -> QpInfo {
        self.w.hess.fill_with_identity();
        self.w.grad.fill(0.0);
        self.w.shift_bounds(self.cons, z);
        self.w.solve_step_qp(self.cons)
    }

    fn evaluate(&mut self, z: &DVector<f64>, jacobian: bool) -> f64 {
        let w = &mut *self.w;
        let ok = if jacobian {
            self.problem
                .residuals_jacobian(z.as_slice(), w.r_trial.as_mut_slice(), &mut w.jac)
        } else {
            self.problem
                .residuals(z.as_slice(), w.r_trial.as_mut_slice())
        };
        if ok {
            0.5 * w.r_trial.norm_squared()
        } else {
            f64::NAN
        }
    }

    fn accept(&mut self, z_old: Option<&DVector<f64>>, z_new: &DVector<f64>) -> bool {
        let w = &mut *self.w;
        w.grad.gemv_tr(1.0, &w.jac, &w.r_trial, 0.0);
        // g = Jᵀr is NaN/∞ whenever J (or r) has a non-finite entry.
        if !w.grad.iter().all(|v| v.is_finite()) {
            return false;
        }
        if let Some(z_old) = z_old {
            if w.settings.hessian == HessianModel::StructuredSecant {
                w.secant_active = w.update_secant(z_old, z_new) || w.secant_active;
            }
            if w.p > 0 {
                w.az.gemv(1.0, &self.cons.a, z_new, 0.0);
            }
        }
        core::mem::swap(&mut w.r, &mut w.r_trial);
        true
    }

    fn solve_qp(&mut self, z: &DVector<f64>) -> QpInfo {
        let w = &mut *self.w;
        w.gauss_newton_hessian();
        w.shift_bounds(self.cons, z);
        if w.settings.hessian == HessianModel::Exact {
            return w.solve_exact_qp(&mut *self.problem, self.cons, z);
        }
        if w.secant_active {
            w.hess += &w.secant;
        }
        let qi = w.solve_step_qp(self.cons);
        if w.secant_active && qi.status == QpStatus::NumericalError {
            // JᵀJ + S not positive definite: drop S, take the Gauss–Newton step.
            w.hess -= &w.secant;
            w.secant.fill(0.0);
            w.secant_active = false;
            let mut retry = w.solve_step_qp(self.cons);
            retry.iterations += qi.iterations;
            return retry;
        }
        qi
    }

    fn step(&self) -> &DVector<f64> {
        &self.w.dz
    }

    fn slope(&self) -> f64 {
        self.w.grad.dot(&self.w.dz)
    }

    fn before_line_search(&mut self) {
        let w = &mut *self.w;
        if w.settings.hessian == HessianModel::StructuredSecant {
            w.jac_prev.copy_from(&w.jac);
            w.grad_prev.copy_from(&w.grad);
        }
    }

    fn kkt(&mut self, z: &DVector<f64>) -> (f64, f64) {
        let k = self.w.kkt(self.cons, z);
        (k, self.w.kkt_violation)
    }
}

impl DenseWork {
    /// Gauss–Newton Hessian `JᵀJ + δI` (lower triangle via column dots, then mirrored), each
    /// dot restricted to the rows where both columns can be nonzero (condensed NMPC Jacobians
    /// are block lower triangular, scenario trees block sparse).
    fn gauss_newton_hessian(&mut self) {
        let (n, m) = (self.n, self.m);
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
        self.maxdiag = maxdiag;
        let delta = self.settings.hessian_regularization * (1.0 + maxdiag);
        for j in 0..n {
            self.hess[(j, j)] += delta;
        }
    }

    /// Dennis–Gay–Welsch update of the structured secant `S` for the step `z → z_new`, with
    /// `self.grad`, `self.jac`, `self.r_trial` at the new point and `grad_prev`, `jac_prev` at
    /// the old one. Returns whether `S` was updated (skipped when `yᵀs ≤ 0`).
    fn update_secant(&mut self, z: &DVector<f64>, z_new: &DVector<f64>) -> bool {
        // s = z₊ − z, y = g₊ − g, y♯ = g₊ − J_prevᵀ r₊ = (J₊ − J)ᵀ r₊.
        self.sec_s.copy_from(z_new);
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
        // Column by column over slices, each entry the same expression in the same order as
        // `(w_i y_j + y_i w_j)/ys − ws y_i y_j/ys²` (bit-identical): only the factors that do
        // not change a rounding are hoisted (`ws·y_i` into `work`, `ys²`, the column's `y_j`,
        // `w_j`); the divisions stay per entry.
        let ws = self.sec_w.dot(&self.sec_s);
        let ys2 = ys * ys;
        let n = self.n;
        for (wy, &y) in self.work.iter_mut().zip(self.sec_y.iter()) {
            *wy = ws * y;
        }
        let (w, y, wsy) = (
            self.sec_w.as_slice(),
            self.sec_y.as_slice(),
            self.work.as_slice(),
        );
        let mut finite = true;
        for (col, (&yj, &wj)) in self
            .secant
            .as_mut_slice()
            .chunks_exact_mut(n)
            .zip(y.iter().zip(w))
        {
            for (((s, &wi), &yi), &wsyi) in col.iter_mut().zip(w).zip(y).zip(wsy) {
                *s += (wi * yj + yi * wj) / ys - wsyi * yj / ys2;
                finite &= s.is_finite();
            }
        }
        if finite {
            true
        } else {
            self.secant.fill(0.0);
            false
        }
    }

    /// The QP of one iteration with the exact Hessian `JᵀJ + δI + Σ rᵢ∇²rᵢ` (`hess` holds the
    /// Gauss–Newton part on entry), with the inertia correction of [`HessianShift`] when it is
    /// not positive definite and the Gauss–Newton QP as the last resort (also when the problem
    /// does not provide the curvature).
    fn solve_exact_qp<P: LeastSquares + ?Sized>(
        &mut self,
        problem: &mut P,
        cons: &Constraints,
        z: &DVector<f64>,
    ) -> QpInfo {
        if !problem.add_residual_curvature(z.as_slice(), self.r.as_slice(), &mut self.hess) {
            self.gauss_newton_hessian();
            return self.solve_step_qp(cons);
        }
        let qi = self.solve_step_qp(cons);
        if qi.status != QpStatus::NumericalError {
            return qi;
        }
        let mut shift = self.shift;
        let mut applied = 0.0;
        let shifted = shift.solve(self.maxdiag, |mu| {
            for i in 0..self.n {
                self.hess[(i, i)] += mu - applied;
            }
            applied = mu;
            self.solve_step_qp(cons)
        });
        self.shift = shift;
        match shifted {
            Ok(mut s) => {
                s.iterations += qi.iterations;
                s
            }
            Err(iterations) => {
                // Not positive definite even shifted: the Gauss–Newton step this iteration.
                self.gauss_newton_hessian();
                let mut retry = self.solve_step_qp(cons);
                retry.iterations += qi.iterations + iterations;
                retry
            }
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
        sub_into(&mut self.dlb, &cons.zl, z);
        sub_into(&mut self.dub, &cons.zu, z);
        sub_into(&mut self.dbl, &cons.bl, &self.az);
        sub_into(&mut self.dbu, &cons.bu, &self.az);
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
        let mut check = BoundCheck::default();
        for i in 0..self.n {
            check.add(cons.zl[i] - z[i], z[i] - cons.zu[i], lb[i]);
        }
        for j in 0..self.p {
            check.add(cons.bl[j] - self.az[j], self.az[j] - cons.bu[j], lg[j]);
        }
        self.kkt_stationarity = stat;
        self.kkt_violation = check.violation;
        self.kkt_complementarity = check.complementarity;
        finite_or_inf(stat.max(check.violation).max(check.complementarity))
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

/// `d ← b − x` entrywise (equally long vectors).
#[inline]
fn sub_into(d: &mut DVector<f64>, b: &DVector<f64>, x: &DVector<f64>) {
    for ((d, &b), &x) in d
        .as_mut_slice()
        .iter_mut()
        .zip(b.as_slice())
        .zip(x.as_slice())
    {
        *d = b - x;
    }
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
    for ((zi, &l), &u) in z
        .as_mut_slice()
        .iter_mut()
        .zip(zl.as_slice())
        .zip(zu.as_slice())
    {
        *zi = zi.max(l).min(u);
    }
}
