//! Dense strictly convex QP solver (Goldfarb–Idnani dual active-set method).
//!
//! Solves
//!
//! ```text
//! min_x  ½ xᵀ H x + gᵀ x
//! s.t.   lb ≤ x ≤ ub          (box, entries may be ±∞)
//!        bl ≤ A x ≤ bu        (two-sided general rows, entries may be ±∞)
//! ```
//!
//! with `H` symmetric positive definite. The method (Goldfarb & Idnani 1983, as implemented in
//! quadprog/eiquadprog) starts from the unconstrained minimum `-H⁻¹g` and adds the most violated
//! constraint at a time while keeping dual feasibility, so no primal warm start is needed.
//! The factorisation `J = L⁻ᵀ` of `H = L Lᵀ` is updated with Givens rotations when constraints
//! enter or leave the active set; box constraints are special rows whose normals are unit vectors,
//! so their products with `J` are plain row reads.
//!
//! All workspace is allocated by [`DenseQp::new`]; [`DenseQp::solve`] allocates nothing and never
//! panics.

#[cfg(not(feature = "std"))]
use crate::math::Float;
use alloc::{vec, vec::Vec};
use nalgebra::{DMatrix, DVector};

use super::{check_range, SolverError};

/// Settings of the dense QP solver. Use [`QpSettings::default`] and override fields as needed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QpSettings {
    /// Maximum number of active-set changes (constraint additions and removals).
    /// Default `1000`; allowed `≥ 1`.
    pub max_iterations: usize,
    /// A constraint counts as violated when its slack is below
    /// `-feasibility_tolerance · (1 + |bound|)` (general rows measured after scaling by their
    /// Euclidean norm). Default `1e-12`; allowed `[0, 1e-2]`.
    pub feasibility_tolerance: f64,
    /// Relative tolerance for deciding that an entering constraint normal is linearly dependent on
    /// the active ones (sine of the angle in the `H⁻¹` metric). Default `1e-10`; allowed
    /// `[1e-16, 1e-2]`.
    pub dependency_tolerance: f64,
}

impl Default for QpSettings {
    fn default() -> Self {
        Self {
            max_iterations: 1000,
            feasibility_tolerance: 1e-12,
            dependency_tolerance: 1e-10,
        }
    }
}

impl QpSettings {
    /// Checks every field against its allowed range; the error names the field and value.
    pub fn validate(&self) -> Result<(), SolverError> {
        if self.max_iterations < 1 {
            return Err(SolverError::InvalidSetting {
                field: "max_iterations",
                value: self.max_iterations as f64,
                allowed: ">= 1",
            });
        }
        check_range(
            "feasibility_tolerance",
            self.feasibility_tolerance,
            0.0,
            1e-2,
            "[0, 1e-2]",
        )?;
        check_range(
            "dependency_tolerance",
            self.dependency_tolerance,
            1e-16,
            1e-2,
            "[1e-16, 1e-2]",
        )?;
        Ok(())
    }
}

/// Outcome of a QP solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QpStatus {
    /// Optimal solution found; `x` and the multipliers satisfy the KKT conditions.
    Solved,
    /// The active-set iteration limit was reached; `x` is the last (dual-feasible, possibly
    /// primal-infeasible) iterate.
    MaxIterations,
    /// The constraints are infeasible (including `lb > ub`, `bl > bu`, `lb = +∞` or `ub = -∞`).
    Infeasible,
    /// `H`, `g` or `A` contain a non-finite entry, or a bound is NaN.
    NonFiniteInput,
    /// `H` is not numerically positive definite, or the iteration produced non-finite values.
    NumericalError,
    /// Argument dimensions do not match those given to [`DenseQp::new`] (a programming error).
    DimensionMismatch,
}

/// Summary of a QP solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QpInfo {
    /// Termination status.
    pub status: QpStatus,
    /// Number of active-set changes performed.
    pub iterations: usize,
    /// Objective value `½ xᵀHx + gᵀx` at the returned `x` (NaN unless `Solved`/`MaxIterations`).
    pub objective: f64,
}

/// Dense Goldfarb–Idnani QP solver with preallocated workspace.
#[derive(Debug, Clone)]
pub struct DenseQp {
    n: usize,
    m: usize,
    settings: QpSettings,
    /// `J = L⁻ᵀ` rotated so that its first `q` columns span the active normals.
    jm: DMatrix<f64>,
    /// Upper-triangular `R` (first `q` columns used).
    rm: DMatrix<f64>,
    /// Transposed general constraint matrix (columns are constraint normals).
    at: DMatrix<f64>,
    /// Inverse Euclidean norms of the general rows (1 for zero rows).
    inv_norm: DVector<f64>,
    /// `A x` for the current `x`.
    ax: DVector<f64>,
    d: DVector<f64>,
    step: DVector<f64>,
    r: DVector<f64>,
    /// Multipliers of the active constraints (in active-set order).
    u: DVector<f64>,
    /// Active constraint ids (`2k + side`, `k < n` box, `k ≥ n` general row `k - n`).
    active: Vec<usize>,
    /// Per box variable / general row: 0 inactive, 1 lower active, 2 upper active.
    state: Vec<u8>,
    q: usize,
    lam_box: DVector<f64>,
    lam_gen: DVector<f64>,
}

/// Result of choosing the entering constraint.
enum Pick {
    None,
    Violated(usize, f64),
}

impl DenseQp {
    /// Creates a solver for `n` variables and `m_general` general rows with default settings,
    /// allocating all workspace.
    pub fn new(n: usize, m_general: usize) -> Self {
        Self {
            n,
            m: m_general,
            settings: QpSettings::default(),
            jm: DMatrix::zeros(n, n),
            rm: DMatrix::zeros(n, n),
            at: DMatrix::zeros(n, m_general),
            inv_norm: DVector::zeros(m_general),
            ax: DVector::zeros(m_general),
            d: DVector::zeros(n),
            step: DVector::zeros(n),
            r: DVector::zeros(n),
            u: DVector::zeros(n),
            active: vec![0; n],
            state: vec![0; n + m_general],
            q: 0,
            lam_box: DVector::zeros(n),
            lam_gen: DVector::zeros(m_general),
        }
    }

    /// Like [`DenseQp::new`] with the given (validated) settings.
    pub fn with_settings(
        n: usize,
        m_general: usize,
        settings: QpSettings,
    ) -> Result<Self, SolverError> {
        settings.validate()?;
        let mut qp = Self::new(n, m_general);
        qp.settings = settings;
        Ok(qp)
    }

    /// Replaces the settings after validating them.
    pub fn set_settings(&mut self, settings: QpSettings) -> Result<(), SolverError> {
        settings.validate()?;
        self.settings = settings;
        Ok(())
    }

    /// Current settings.
    pub fn settings(&self) -> &QpSettings {
        &self.settings
    }

    /// Number of variables `n`.
    pub fn num_vars(&self) -> usize {
        self.n
    }

    /// Number of general rows.
    pub fn num_general(&self) -> usize {
        self.m
    }

    /// Box multipliers of the last solve (length `n`), signed so that
    /// `H x + g + λ_box + Aᵀ λ_gen = 0`: `λ ≤ 0` at an active lower bound, `λ ≥ 0` at an active
    /// upper bound, `0` for inactive bounds.
    pub fn multipliers_box(&self) -> &DVector<f64> {
        &self.lam_box
    }

    /// General-row multipliers of the last solve (length `m_general`), same sign convention as
    /// [`DenseQp::multipliers_box`].
    pub fn multipliers_general(&self) -> &DVector<f64> {
        &self.lam_gen
    }

    /// Number of constraints in the final active set of the last solve.
    pub fn num_active(&self) -> usize {
        self.q
    }

    /// Solves the QP; `x` receives the solution (its input value is ignored).
    ///
    /// Only the lower triangle of `h` is used for the factorisation. Never panics; see
    /// [`QpStatus`] for the failure modes. Allocates nothing.
    #[allow(clippy::too_many_arguments)]
    pub fn solve(
        &mut self,
        h: &DMatrix<f64>,
        g: &DVector<f64>,
        lb: &DVector<f64>,
        ub: &DVector<f64>,
        a: &DMatrix<f64>,
        bl: &DVector<f64>,
        bu: &DVector<f64>,
        x: &mut DVector<f64>,
    ) -> QpInfo {
        let (n, m) = (self.n, self.m);
        self.q = 0;
        self.lam_box.fill(0.0);
        self.lam_gen.fill(0.0);
        let fail = |status| QpInfo {
            status,
            iterations: 0,
            objective: f64::NAN,
        };
        let dims_ok = h.nrows() == n
            && h.ncols() == n
            && g.len() == n
            && lb.len() == n
            && ub.len() == n
            && a.nrows() == m
            && (a.ncols() == n || m == 0)
            && bl.len() == m
            && bu.len() == m
            && x.len() == n;
        if !dims_ok {
            debug_assert!(false, "DenseQp::solve: dimension mismatch");
            return fail(QpStatus::DimensionMismatch);
        }
        // Input checks.
        if !h.iter().all(|v| v.is_finite())
            || !g.iter().all(|v| v.is_finite())
            || !a.iter().all(|v| v.is_finite())
            || lb.iter().chain(ub.iter()).any(|v| v.is_nan())
            || bl.iter().chain(bu.iter()).any(|v| v.is_nan())
        {
            return fail(QpStatus::NonFiniteInput);
        }
        for (l, u) in lb.iter().zip(ub.iter()).chain(bl.iter().zip(bu.iter())) {
            if *l > *u || *l == f64::INFINITY || *u == f64::NEG_INFINITY {
                return fail(QpStatus::Infeasible);
            }
        }
        if !self.factor(h) {
            return fail(QpStatus::NumericalError);
        }
        if m > 0 {
            a.transpose_to(&mut self.at);
            for j in 0..m {
                let nrm = self.at.column(j).norm();
                self.inv_norm[j] = if nrm > 0.0 { 1.0 / nrm } else { 1.0 };
            }
        }
        // Unconstrained minimum x = -J Jᵀ g.
        self.d.gemv_tr(1.0, &self.jm, g, 0.0);
        x.gemv(-1.0, &self.jm, &self.d, 0.0);
        self.state.fill(0);

        let status = self.iterate(lb, ub, bl, bu, x);
        let iterations = status.1;
        let status = status.0;
        if !x.iter().all(|v| v.is_finite()) {
            return QpInfo {
                status: QpStatus::NumericalError,
                iterations,
                objective: f64::NAN,
            };
        }
        // Multipliers: u ≥ 0 for nᵀx ≥ b; lower side has normal +e/+a, upper side −e/−a.
        for i in 0..self.q {
            let id = self.active[i];
            let k = id >> 1;
            let lam = if id & 1 == 0 { -self.u[i] } else { self.u[i] };
            if k < n {
                self.lam_box[k] = lam;
            } else {
                self.lam_gen[k - n] = lam;
            }
        }
        let objective = match status {
            QpStatus::Solved | QpStatus::MaxIterations => {
                self.d.gemv(1.0, h, x, 0.0);
                0.5 * x.dot(&self.d) + g.dot(x)
            }
            _ => f64::NAN,
        };
        QpInfo {
            status,
            iterations,
            objective,
        }
    }

    /// Cholesky `H = L Lᵀ` and `J = L⁻ᵀ` in place in `jm`. Returns false if not PD.
    fn factor(&mut self, h: &DMatrix<f64>) -> bool {
        let n = self.n;
        self.jm.copy_from(h);
        let a = self.jm.as_mut_slice(); // column-major, a[i + j n] = (i, j)
                                        // Left-looking column Cholesky on the lower triangle.
        for j in 0..n {
            let (left, right) = a.split_at_mut(j * n);
            let colj = &mut right[..n];
            for k in 0..j {
                let colk = &left[k * n..(k + 1) * n];
                let ljk = colk[j];
                if ljk != 0.0 {
                    for (c, l) in colj[j..].iter_mut().zip(&colk[j..]) {
                        *c -= ljk * l;
                    }
                }
            }
            let djj = colj[j];
            if djj.is_nan() || djj <= 0.0 || !djj.is_finite() {
                return false;
            }
            let ljj = djj.sqrt();
            colj[j] = ljj;
            let inv = 1.0 / ljj;
            for c in colj[j + 1..].iter_mut() {
                *c *= inv;
            }
        }
        // Invert the lower-triangular L in place, column j = L⁻¹ e_j (columns k > j of L are
        // still intact while column j is computed).
        for j in 0..n {
            let (left, right) = a.split_at_mut((j + 1) * n);
            let colj = &mut left[j * n..];
            let yj = 1.0 / colj[j];
            colj[j] = yj;
            for c in colj[j + 1..].iter_mut() {
                *c = -*c * yj;
            }
            for k in j + 1..n {
                let colk = &right[(k - j - 1) * n..(k - j) * n];
                let yk = colj[k] / colk[k];
                colj[k] = yk;
                if yk != 0.0 {
                    for (c, l) in colj[k + 1..].iter_mut().zip(&colk[k + 1..]) {
                        *c -= l * yk;
                    }
                }
            }
        }
        // J = (L⁻¹)ᵀ, upper triangular.
        for j in 0..n {
            for i in j + 1..n {
                a[j + i * n] = a[i + j * n];
                a[i + j * n] = 0.0;
            }
        }
        a.iter().all(|v| v.is_finite())
    }

    /// Slack `nᵀx − b` of constraint `id` (negative = violated). Uses `ax` for general rows.
    #[inline]
    fn slack(&self, id: usize, x: &DVector<f64>, bounds: [&DVector<f64>; 4]) -> f64 {
        let k = id >> 1;
        let upper = id & 1 == 1;
        let (v, lo, hi) = if k < self.n {
            (x[k], bounds[0][k], bounds[1][k])
        } else {
            let j = k - self.n;
            (self.ax[j], bounds[2][j], bounds[3][j])
        };
        if upper {
            hi - v
        } else {
            v - lo
        }
    }

    /// Most violated inactive constraint (by normalised violation).
    fn pick(&self, x: &DVector<f64>, bounds: [&DVector<f64>; 4]) -> Pick {
        let tol = self.settings.feasibility_tolerance;
        let mut best = 0.0;
        let mut best_id = usize::MAX;
        let mut best_s = 0.0;
        for k in 0..self.n + self.m {
            if self.state[k] != 0 {
                continue;
            }
            let (v, lo, hi, scale) = if k < self.n {
                (x[k], bounds[0][k], bounds[1][k], 1.0)
            } else {
                let j = k - self.n;
                (self.ax[j], bounds[2][j], bounds[3][j], self.inv_norm[j])
            };
            let s_lo = v - lo;
            if s_lo < 0.0 {
                let viol = -s_lo * scale;
                if viol > tol * (1.0 + lo.abs() * scale) && viol > best {
                    best = viol;
                    best_id = 2 * k;
                    best_s = s_lo;
                }
            }
            let s_hi = hi - v;
            if s_hi < 0.0 {
                let viol = -s_hi * scale;
                if viol > tol * (1.0 + hi.abs() * scale) && viol > best {
                    best = viol;
                    best_id = 2 * k + 1;
                    best_s = s_hi;
                }
            }
        }
        if best_id == usize::MAX {
            Pick::None
        } else {
            Pick::Violated(best_id, best_s)
        }
    }

    /// `d = Jᵀ n_id`.
    #[inline]
    fn compute_d(&mut self, id: usize) {
        let k = id >> 1;
        let sign = if id & 1 == 0 { 1.0 } else { -1.0 };
        let n = self.n;
        let jm = self.jm.as_slice();
        let d = self.d.as_mut_slice();
        if k < n {
            for (i, di) in d.iter_mut().enumerate() {
                *di = sign * jm[k + i * n];
            }
        } else {
            let j = k - n;
            let col = &self.at.as_slice()[j * n..(j + 1) * n];
            for (di, jc) in d.iter_mut().zip(jm.chunks_exact(n)) {
                *di = sign * dot(jc, col);
            }
        }
    }

    /// Main Goldfarb–Idnani loop; returns (status, iterations).
    fn iterate(
        &mut self,
        lb: &DVector<f64>,
        ub: &DVector<f64>,
        bl: &DVector<f64>,
        bu: &DVector<f64>,
        x: &mut DVector<f64>,
    ) -> (QpStatus, usize) {
        let n = self.n;
        let bounds = [lb, ub, bl, bu];
        let dep2 = self.settings.dependency_tolerance * self.settings.dependency_tolerance;
        let mut iter = 0usize;
        loop {
            // Step 1: choose a violated constraint.
            if self.m > 0 {
                self.ax.gemv_tr(1.0, &self.at, x, 0.0);
            }
            let (ip, mut s) = match self.pick(x, bounds) {
                Pick::None => return (QpStatus::Solved, iter),
                Pick::Violated(id, s) => (id, s),
            };
            let mut u_plus = 0.0;
            loop {
                if iter >= self.settings.max_iterations {
                    return (QpStatus::MaxIterations, iter);
                }
                iter += 1;
                let q = self.q;
                // Step 2a: primal direction step = J₂ J₂ᵀ n⁺, dual direction r = R⁻¹ J₁ᵀ n⁺.
                self.compute_d(ip);
                let mut d2sq = 0.0;
                for i in q..n {
                    d2sq += self.d[i] * self.d[i];
                }
                let mut d1sq = 0.0;
                for i in 0..q {
                    d1sq += self.d[i] * self.d[i];
                }
                let dependent = d2sq <= dep2 * (d1sq + d2sq);
                if !dependent {
                    let step = self.step.as_mut_slice();
                    step.fill(0.0);
                    let jm = self.jm.as_slice();
                    for i in q..n {
                        let di = self.d[i];
                        if di != 0.0 {
                            for (s, c) in step.iter_mut().zip(&jm[i * n..(i + 1) * n]) {
                                *s += di * c;
                            }
                        }
                    }
                }
                // Back substitution r = R⁻¹ d[..q].
                for i in 0..q {
                    self.r[i] = self.d[i];
                }
                {
                    let rm = self.rm.as_slice();
                    let r = self.r.as_mut_slice();
                    for k in (0..q).rev() {
                        let colk = &rm[k * n..k * n + k + 1];
                        let rk = r[k] / colk[k];
                        r[k] = rk;
                        for (ri, c) in r[..k].iter_mut().zip(&colk[..k]) {
                            *ri -= c * rk;
                        }
                    }
                }
                // Step 2b: partial (dual) step t1 and full step t2.
                let mut t1 = f64::INFINITY;
                let mut l = usize::MAX;
                for k in 0..q {
                    if self.r[k] > 0.0 {
                        let t = self.u[k] / self.r[k];
                        if t < t1 {
                            t1 = t;
                            l = k;
                        }
                    }
                }
                let t2 = if dependent { f64::INFINITY } else { -s / d2sq };
                let t = t1.min(t2);
                if !t.is_finite() {
                    // No step in primal or dual space possible (or numerical breakdown).
                    return if t.is_nan() {
                        (QpStatus::NumericalError, iter)
                    } else {
                        (QpStatus::Infeasible, iter)
                    };
                }
                for k in 0..q {
                    self.u[k] -= t * self.r[k];
                }
                u_plus += t;
                if dependent {
                    // Step in dual space only: drop constraint l.
                    self.delete_constraint(l);
                    continue;
                }
                x.axpy(t, &self.step, 1.0);
                if t2 <= t1 {
                    // Full step: add ip to the active set.
                    self.add_constraint(ip, u_plus);
                    break;
                }
                // Partial step: drop l and retry with the updated slack of ip.
                self.delete_constraint(l);
                let k = ip >> 1;
                if k >= n {
                    let j = k - n;
                    self.ax[j] = self.at.column(j).dot(x);
                }
                // If rounding made s ≥ 0 the next full step is ≈ 0 and still adds ip, which keeps
                // its accumulated multiplier consistent.
                s = self.slack(ip, x, bounds);
            }
        }
    }

    /// Appends constraint `id` with multiplier `u_plus`, updating `J` and `R` via Givens
    /// rotations that zero `d[q+1..]`.
    fn add_constraint(&mut self, id: usize, u_plus: f64) {
        let n = self.n;
        let q = self.q;
        for j in (q + 1..n).rev() {
            let mut cc = self.d[j - 1];
            let mut ss = self.d[j];
            let h = (cc * cc + ss * ss).sqrt();
            if h == 0.0 {
                continue;
            }
            self.d[j] = 0.0;
            ss /= h;
            cc /= h;
            if cc < 0.0 {
                cc = -cc;
                ss = -ss;
                self.d[j - 1] = -h;
            } else {
                self.d[j - 1] = h;
            }
            let (c0, c1) = adjacent_columns(self.jm.as_mut_slice(), n, j - 1);
            rotate(c0, c1, cc, ss);
        }
        for i in 0..=q {
            self.rm[(i, q)] = self.d[i];
        }
        self.active[q] = id;
        self.u[q] = u_plus;
        self.state[id >> 1] = 1 + (id & 1) as u8;
        self.q = q + 1;
    }

    /// Removes the active constraint at position `l`, restoring the triangular `R`.
    fn delete_constraint(&mut self, l: usize) {
        let n = self.n;
        let q = self.q;
        if l >= q {
            return;
        }
        self.state[self.active[l] >> 1] = 0;
        for i in l..q - 1 {
            self.active[i] = self.active[i + 1];
            self.u[i] = self.u[i + 1];
        }
        let rm = self.rm.as_mut_slice();
        if l + 1 < q {
            rm.copy_within((l + 1) * n..q * n, l * n);
        }
        rm[(q - 1) * n..q * n].fill(0.0);
        let q = q - 1;
        self.q = q;
        for j in l..q {
            let mut cc = self.rm[(j, j)];
            let mut ss = self.rm[(j + 1, j)];
            let h = (cc * cc + ss * ss).sqrt();
            if h == 0.0 {
                continue;
            }
            cc /= h;
            ss /= h;
            self.rm[(j + 1, j)] = 0.0;
            if cc < 0.0 {
                self.rm[(j, j)] = -h;
                cc = -cc;
                ss = -ss;
            } else {
                self.rm[(j, j)] = h;
            }
            let xny = ss / (1.0 + cc);
            let rm = self.rm.as_mut_slice();
            for k in j + 1..q {
                let t1 = rm[j + k * n];
                let t2 = rm[j + 1 + k * n];
                let nt1 = t1 * cc + t2 * ss;
                rm[j + k * n] = nt1;
                rm[j + 1 + k * n] = xny * (t1 + nt1) - t2;
            }
            let (c0, c1) = adjacent_columns(self.jm.as_mut_slice(), n, j);
            rotate(c0, c1, cc, ss);
        }
    }
}

/// Dot product of two equal-length slices.
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Mutable views of columns `j` and `j + 1` of a column-major matrix with `n` rows.
#[inline]
fn adjacent_columns(a: &mut [f64], n: usize, j: usize) -> (&mut [f64], &mut [f64]) {
    let (c0, rest) = a[j * n..(j + 2) * n].split_at_mut(n);
    (c0, rest)
}

/// Applies the Givens rotation `(c s; s −c)` to the column pair (`c0`, `c1`) in the
/// eiquadprog form (`cc ≥ 0`).
#[inline]
fn rotate(c0: &mut [f64], c1: &mut [f64], cc: f64, ss: f64) {
    let xny = ss / (1.0 + cc);
    for (a, b) in c0.iter_mut().zip(c1.iter_mut()) {
        let t1 = *a;
        let t2 = *b;
        let nt1 = t1 * cc + t2 * ss;
        *a = nt1;
        *b = xny * (t1 + nt1) - t2;
    }
}
