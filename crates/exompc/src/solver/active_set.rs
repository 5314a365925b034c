//! The Goldfarb–Idnani dual active-set loop on box constraints, shared by the stage QP
//! ([`super::RiccatiQp`]) and the scenario-tree QP ([`super::TreeQp`]).
//!
//! Both solvers start from the unconstrained minimiser `w = −H⁻¹g` (their factorisation) and
//! add the most violated bound `σ e_p` one at a time (Goldfarb & Idnani 1983): the only thing
//! that differs between them is how `H⁻¹ n` is computed for a bound normal `n = σ e_p`
//! ([`BoxDual::normal_solve`], a vector sweep of the respective factorisation). The active set,
//! its multipliers and the columns `H⁻¹ nᵢ` live in the solver's workspace, reached through
//! [`BoxDual::parts`]; nothing here allocates.

use super::cholesky::{chol_solve, cholesky};
use super::qp::{QpInfo, QpSettings, QpStatus};
use alloc::{vec, vec::Vec};

/// The loop's workspace for a trajectory of `len` entries, owned by the solver: the point, the
/// multipliers, the unit right-hand side of the normal solves and the active set.
#[derive(Debug, Clone)]
pub(crate) struct BoxWork {
    /// Current primal point (the solution after a solve).
    pub sol: Vec<f64>,
    /// Multipliers in trajectory layout.
    pub mult: Vec<f64>,
    /// Zero but for the one entry of a normal solve's right-hand side.
    pub unit: Vec<f64>,
    /// Active bounds `(index, σ)`.
    pub act: Vec<(usize, f64)>,
    /// Multipliers of the active bounds.
    pub mu: Vec<f64>,
    /// Columns `H⁻¹ nᵢ` of the active bounds.
    pub ycols: Vec<f64>,
    /// `H⁻¹ n_p` of the entering bound.
    pub yp: Vec<f64>,
    /// Primal direction of the current dual step.
    pub zdir: Vec<f64>,
    /// `M = N_Wᵀ H⁻¹ N_W`.
    pub mmat: Vec<f64>,
    /// `r = M⁻¹ N_Wᵀ H⁻¹ n_p`.
    pub rvec: Vec<f64>,
}

impl BoxWork {
    /// Workspace for `len` trajectory entries and at most `cap` active bounds.
    pub(crate) fn new(len: usize, cap: usize) -> Self {
        Self {
            sol: vec![0.0; len],
            mult: vec![0.0; len],
            unit: vec![0.0; len],
            act: Vec::with_capacity(cap),
            mu: vec![0.0; cap],
            ycols: vec![0.0; cap * len],
            yp: vec![0.0; len],
            zdir: vec![0.0; len],
            mmat: vec![0.0; cap * cap],
            rvec: vec![0.0; cap],
        }
    }

    /// The loop's view, with the solver's bounds.
    pub(crate) fn parts<'a>(&'a mut self, lo: &'a [f64], hi: &'a [f64]) -> BoxParts<'a> {
        BoxParts {
            lo,
            hi,
            sol: &mut self.sol,
            mult: &mut self.mult,
            act: &mut self.act,
            mu: &mut self.mu,
            ycols: &mut self.ycols,
            yp: &self.yp,
            zdir: &mut self.zdir,
            mmat: &mut self.mmat,
            rvec: &mut self.rvec,
        }
    }
}

/// One solve of a box-constrained QP: clears the active set and the multipliers, reports
/// non-finite data (`data_finite` false) and unusable bounds, runs `start` (the factorisation
/// and the unconstrained minimiser into `sol`; `false` when not positive definite), then adds
/// the violated bounds. `Ok` when the loop ran to its end (the caller adds the objective), `Err`
/// with the status of an earlier stop.
pub(crate) fn solve_box<Q: BoxDual>(
    q: &mut Q,
    settings: &QpSettings,
    data_finite: bool,
    start: impl FnOnce(&mut Q) -> bool,
) -> Result<QpInfo, QpInfo> {
    let mut info = QpInfo {
        status: QpStatus::Solved,
        iterations: 0,
        objective: f64::NAN,
    };
    let stop = |status| {
        Err(QpInfo {
            status,
            iterations: 0,
            objective: f64::NAN,
        })
    };
    {
        let w = q.parts();
        w.act.clear();
        w.mult.fill(0.0);
        if !data_finite {
            return stop(QpStatus::NonFiniteInput);
        }
        if let Some(status) = bounds_status(w.lo, w.hi) {
            return stop(status);
        }
    }
    if !start(q) {
        return stop(QpStatus::NumericalError);
    }
    if !add_violated_bounds(q, settings, &mut info) {
        info.status = QpStatus::NumericalError;
        return Err(info);
    }
    Ok(info)
}

/// The workspace the loop reads and writes, borrowed from the solver.
pub(crate) struct BoxParts<'a> {
    /// Lower bounds in trajectory layout.
    pub lo: &'a [f64],
    /// Upper bounds in trajectory layout.
    pub hi: &'a [f64],
    /// Current primal point `w` (on entry the unconstrained minimiser).
    pub sol: &'a mut [f64],
    /// Multipliers in trajectory layout (set on exit; zero on entry).
    pub mult: &'a mut [f64],
    /// Active bounds `(index, σ)`; empty on entry.
    pub act: &'a mut Vec<(usize, f64)>,
    /// Multipliers of the active bounds; its length is the capacity of the active set.
    pub mu: &'a mut [f64],
    /// Columns `H⁻¹ nᵢ` of the active bounds, each of the trajectory's length.
    pub ycols: &'a mut [f64],
    /// `H⁻¹ n_p` of the entering bound, written by [`BoxDual::normal_solve`].
    pub yp: &'a [f64],
    /// Primal direction of the current dual step.
    pub zdir: &'a mut [f64],
    /// `M = N_Wᵀ H⁻¹ N_W` (capacity squared).
    pub mmat: &'a mut [f64],
    /// `r = M⁻¹ N_Wᵀ H⁻¹ n_p` (capacity).
    pub rvec: &'a mut [f64],
}

/// A factorised strictly convex QP with box constraints, as the loop sees it.
pub(crate) trait BoxDual {
    /// The workspace of the loop.
    fn parts(&mut self) -> BoxParts<'_>;
    /// `H⁻¹ n` for the bound normal `n = σ e_id` into the `yp` of [`Self::parts`].
    fn normal_solve(&mut self, id: usize, sigma: f64);
}

/// Whether every bound pair is usable: neither bound NaN, `lo ≤ hi`, `lo < +∞`, `hi > −∞`
/// (one pass without a branch per entry; [`bounds_status`] finds the offending pair when not).
#[inline]
pub(crate) fn bounds_ordered(lo: &[f64], hi: &[f64]) -> bool {
    let mut ok = true;
    for (l, h) in lo.iter().zip(hi) {
        // `l <= h` is false when either is NaN.
        ok &= (*l <= *h) & (*l != f64::INFINITY) & (*h != f64::NEG_INFINITY);
    }
    ok
}

/// Implements [`BoxDual`] for a solver with a [`BoxWork`] field `w`, its problem data in a
/// field `data` ([`super::StageQpData`], bounds `lo`, `hi`) and an inherent
/// `normal_solve(&mut self, id, sigma)`; the accessors of the solution; and `Deref` to the data
/// (`qp.a` for `qp.data.a`).
macro_rules! box_dual_from_fields {
    ($qp:ty) => {
        impl $crate::solver::active_set::BoxDual for $qp {
            fn parts(&mut self) -> $crate::solver::active_set::BoxParts<'_> {
                self.w.parts(&self.data.lo, &self.data.hi)
            }

            fn normal_solve(&mut self, id: usize, sigma: f64) {
                <$qp>::normal_solve(self, id, sigma);
            }
        }

        impl core::ops::Deref for $qp {
            type Target = $crate::solver::StageQpData;

            fn deref(&self) -> &Self::Target {
                &self.data
            }
        }

        impl core::ops::DerefMut for $qp {
            fn deref_mut(&mut self) -> &mut Self::Target {
                &mut self.data
            }
        }

        impl $qp {
            /// The solution of the last solve, in trajectory layout.
            pub fn solution(&self) -> &[f64] {
                &self.w.sol
            }

            /// Multipliers of the bounds in trajectory layout, with the sign convention of
            /// [`super::DenseQp`]: negative for an active lower bound, positive for an active
            /// upper bound, so that `∇(objective) + Σ multᵢ ∇(trajectoryᵢ) = 0` at the solution.
            pub fn multipliers(&self) -> &[f64] {
                &self.w.mult
            }

            /// Number of active bounds at the last solution.
            pub fn num_active(&self) -> usize {
                self.w.act.len()
            }
        }
    };
}
pub(crate) use box_dual_from_fields;

/// The status a bound pair `[l, h]` gives a QP before it is solved: `NonFiniteInput` for a NaN,
/// `Infeasible` for `l > h` or a bound that excludes every finite value; `None` when every
/// pair is usable.
pub(crate) fn bounds_status(lo: &[f64], hi: &[f64]) -> Option<QpStatus> {
    if bounds_ordered(lo, hi) {
        return None;
    }
    // Some pair is NaN or crossed: the first one decides.
    for (&l, &h) in lo.iter().zip(hi) {
        if l.is_nan() || h.is_nan() {
            return Some(QpStatus::NonFiniteInput);
        }
        if l > h || l == f64::INFINITY || h == f64::NEG_INFINITY {
            return Some(QpStatus::Infeasible);
        }
    }
    None
}

/// Runs the dual active-set iterations from the unconstrained minimiser in `sol` until no bound
/// is violated by more than `feasibility_tolerance·(1 + |bound|)`, then writes the multipliers
/// of the active bounds into `mult` (`−σ μ`, the solvers' sign convention). Iterations, and
/// `MaxIterations`, `NumericalError` (a singular `M` or a full active set) or `Infeasible`
/// (no dual step bounded), go into `info`. Returns whether the final point is finite.
pub(crate) fn add_violated_bounds<Q: BoxDual + ?Sized>(
    q: &mut Q,
    settings: &QpSettings,
    info: &mut QpInfo,
) -> bool {
    let tol = settings.feasibility_tolerance;
    let dep2 = settings.dependency_tolerance * settings.dependency_tolerance;
    'outer: loop {
        let (p, sp, bp) = {
            let w = q.parts();
            // Most violated bound not in the active set.
            let mut best = 0.0;
            let mut entering: Option<(usize, f64)> = None;
            for (i, ((&wi, &l), &h)) in w.sol.iter().zip(w.lo).zip(w.hi).enumerate() {
                let (v, sigma, bound) = if wi < l {
                    (l - wi, 1.0, l)
                } else if wi > h {
                    (wi - h, -1.0, h)
                } else {
                    continue;
                };
                if v > tol * (1.0 + bound.abs())
                    && v > best
                    && !w.act.iter().any(|&(id, _)| id == i)
                {
                    best = v;
                    entering = Some((i, sigma));
                }
            }
            let Some((p, sp)) = entering else {
                break;
            };
            (p, sp, if sp > 0.0 { w.lo[p] } else { -w.hi[p] })
        };
        q.normal_solve(p, sp);
        let w = q.parts();
        let len = w.sol.len();
        let cap = w.mu.len();
        let npp = sp * w.yp[p];
        let mut mu_p = 0.0;
        loop {
            if info.iterations >= settings.max_iterations {
                info.status = QpStatus::MaxIterations;
                break 'outer;
            }
            info.iterations += 1;
            let k = w.act.len();
            // r = M⁻¹ N_Wᵀ H⁻¹ n_p, M = N_Wᵀ H⁻¹ N_W.
            for (a, &(ida, sa)) in w.act.iter().enumerate() {
                w.rvec[a] = sa * w.yp[ida];
                for c in 0..k {
                    w.mmat[c * k + a] = sa * w.ycols[c * len + ida];
                }
            }
            if k > 0 {
                if !cholesky(&mut w.mmat[..k * k], k) {
                    info.status = QpStatus::NumericalError;
                    break 'outer;
                }
                chol_solve(&w.mmat[..k * k], k, &mut w.rvec[..k]);
            }
            // z = H⁻¹ n_p − Σ rᵢ H⁻¹ nᵢ.
            w.zdir.copy_from_slice(w.yp);
            for c in 0..k {
                let rc = w.rvec[c];
                let col = &w.ycols[c * len..(c + 1) * len];
                for (z, y) in w.zdir.iter_mut().zip(col) {
                    *z -= rc * y;
                }
            }
            let nz = sp * w.zdir[p];
            let full = nz > dep2 * npp.abs().max(f64::MIN_POSITIVE);
            // Largest dual step keeping the active multipliers nonnegative.
            let mut t1 = f64::INFINITY;
            let mut block = usize::MAX;
            for c in 0..k {
                let rc = w.rvec[c];
                if rc > 0.0 {
                    let t = w.mu[c] / rc;
                    if t < t1 {
                        t1 = t;
                        block = c;
                    }
                }
            }
            let slack = sp * w.sol[p] - bp;
            let t2 = if full { -slack / nz } else { f64::INFINITY };
            let t = t1.min(t2);
            if !t.is_finite() {
                info.status = QpStatus::Infeasible;
                break 'outer;
            }
            for c in 0..k {
                w.mu[c] -= t * w.rvec[c];
            }
            mu_p += t;
            if full {
                for (s, z) in w.sol.iter_mut().zip(w.zdir.iter()) {
                    *s += t * z;
                }
            }
            if full && t2 <= t1 {
                if k + 1 > cap {
                    info.status = QpStatus::NumericalError;
                    break 'outer;
                }
                w.act.push((p, sp));
                w.mu[k] = mu_p;
                w.ycols[k * len..(k + 1) * len].copy_from_slice(w.yp);
                continue 'outer;
            }
            // Drop the blocking constraint (order of the active set is irrelevant).
            let last = k - 1;
            w.act.swap(block, last);
            w.act.pop();
            w.mu[block] = w.mu[last];
            if block != last {
                let (lo_part, hi_part) = w.ycols.split_at_mut(last * len);
                lo_part[block * len..(block + 1) * len].copy_from_slice(&hi_part[..len]);
            }
        }
    }
    let w = q.parts();
    for (c, &(id, s)) in w.act.iter().enumerate() {
        w.mult[id] = -s * w.mu[c];
    }
    w.sol.iter().all(|v| v.is_finite())
}
