//! The SQP engine shared by every QP back-end: one solve is a fixed sequence of named steps
//! (input checks → feasibility projection → first linearisation → per iteration: Hessian model
//! and QP → termination test → line search → termination test), as OpEn's engine reads. With
//! `real_time_iteration` the first iteration ends after the QP with the full step.
//!
//! A back-end ([`SqpSteps`]) says how the problem is evaluated and linearised, how the QP of one
//! iteration is built and solved, and how the KKT residual of the nonlinear problem is measured:
//! the dense condensed form ([`super::Sqp`] with [`super::DenseQp`]) and the multiple-shooting
//! stage form (`control::ocp::StructuredSqp` with [`super::RiccatiQp`]) run the same engine, so
//! warm-start projection, Armijo line search and termination are written once.

#[cfg(not(feature = "std"))]
use crate::clock::Instant;
use core::time::Duration;
#[cfg(feature = "std")]
use std::time::Instant;

use nalgebra::DVector;

use super::qp::{QpInfo, QpStatus};
use super::settings::{SqpInfo, SqpSettings, SqpStatus};

/// What an SQP back-end provides to [`solve`]. Every method allocates nothing and never panics.
pub(crate) trait SqpSteps {
    /// Checks dimensions and finiteness of the warm start `z` and the constraint data (crossed
    /// bounds are `Infeasible`), and prepares the per-solve data.
    fn check_inputs(&mut self, z: &DVector<f64>) -> Result<(), SqpStatus>;
    /// Clamps `z` into the box constraints (the exact projection onto the box).
    fn clamp(&self, z: &mut DVector<f64>);
    /// Largest violation of the non-box constraints at `z`; caches what the step bounds and the
    /// KKT test need at `z` (`A z`, cumulative torques).
    fn general_violation(&mut self, z: &DVector<f64>) -> f64;
    /// Solves the Euclidean projection QP `min ½|d|²` s.t. the constraints on `z + d` (with the
    /// data cached by [`Self::general_violation`] at `z`); `d` in [`Self::step`].
    fn projection_qp(&mut self, z: &DVector<f64>) -> QpInfo;
    /// Evaluates the cost `½‖r(z)‖²` into the trial buffers, with the linearisation at `z` when
    /// `jacobian`; a non-finite value when anything evaluated is non-finite.
    fn evaluate(&mut self, z: &DVector<f64>, jacobian: bool) -> f64;
    /// Makes the last evaluation (which included the linearisation, at `z_new`) the current
    /// point: gradient, cached constraint data and the Hessian model update from `z_old` (`None`
    /// for the first point). Returns `false` when the gradient is non-finite.
    fn accept(&mut self, z_old: Option<&DVector<f64>>, z_new: &DVector<f64>) -> bool;
    /// Builds the Hessian model at the current point and solves the step QP (bounds shifted to
    /// `z`); the step in [`Self::step`], iterations summed over any retry.
    fn solve_qp(&mut self, z: &DVector<f64>) -> QpInfo;
    /// The last QP step in the decision variables.
    fn step(&self) -> &DVector<f64>;
    /// Directional derivative `∇φᵀd` of the cost along the last QP step.
    fn slope(&self) -> f64;
    /// Called once per iteration between a QP that did not terminate and the line search.
    fn before_line_search(&mut self) {}
    /// KKT residual of the nonlinear problem at `z` (current point) with the last QP
    /// multipliers: `(max(stationarity, violation, complementarity), violation)`; `∞` for NaN.
    fn kkt(&mut self, z: &DVector<f64>) -> (f64, f64);
    /// The termination test's use of [`Self::kkt`]: the same `(kkt, violation)` whenever
    /// `kkt ≤ kkt_tol` and `violation ≤ feas_tol` (the test passes), and the same verdict
    /// otherwise; a back-end may then stop early and return a `kkt` that is only a lower bound
    /// above `kkt_tol` (or the exact violation above `feas_tol`), with `exact = false`. The
    /// default computes [`Self::kkt`] in full.
    fn kkt_test(&mut self, z: &DVector<f64>, kkt_tol: f64, feas_tol: f64) -> KktTest {
        let _ = (kkt_tol, feas_tol);
        let (kkt, violation) = self.kkt(z);
        KktTest {
            kkt,
            violation,
            exact: true,
        }
    }
}

/// Outcome of [`SqpSteps::kkt_test`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct KktTest {
    /// The KKT residual, or a lower bound of it when not `exact`.
    pub kkt: f64,
    /// The constraint violation (always exact).
    pub violation: f64,
    /// Whether `kkt` is the full residual of [`SqpSteps::kkt`].
    pub exact: bool,
}

/// Runs the engine on `steps` from the warm start `z` (overwritten with the result); `z_trial`
/// is a work vector of the same length. Times the solve and fills [`SqpInfo`].
pub(crate) fn solve<B: SqpSteps + ?Sized>(
    steps: &mut B,
    s: &SqpSettings,
    z_trial: &mut DVector<f64>,
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
    info.status = run(steps, s, z_trial, z, &mut info, start);
    info.solve_time = start.elapsed();
    #[cfg(not(feature = "std"))]
    crate::clock::account(crate::clock::Part::Solver, info.solve_time);
    info
}

fn run<B: SqpSteps + ?Sized>(
    b: &mut B,
    s: &SqpSettings,
    z_trial: &mut DVector<f64>,
    z: &mut DVector<f64>,
    info: &mut SqpInfo,
    start: Instant,
) -> SqpStatus {
    if z_trial.len() != z.len() {
        return SqpStatus::DimensionMismatch;
    }
    if let Err(status) = b.check_inputs(z) {
        return status;
    }
    if let Err(status) = project_feasible(b, s, z_trial, z, info) {
        return status;
    }
    let mut cost = b.evaluate(z, true);
    if !cost.is_finite() || !b.accept(None, z) {
        return SqpStatus::NonFiniteInput;
    }
    info.cost = cost;
    for it in 0..s.max_iterations {
        if it > 0 && out_of_time(s, start) {
            return SqpStatus::MaxTime;
        }
        let qi = b.solve_qp(z);
        info.qp_iterations += qi.iterations;
        info.iterations = it + 1;
        match qi.status {
            QpStatus::Solved => {}
            QpStatus::NonFiniteInput => return SqpStatus::NonFiniteInput,
            _ => return SqpStatus::QpFailed,
        }
        // KKT at the current point with the fresh multipliers (in full when the solve ends
        // here with a real-time iteration).
        let (passed, exact) = terminated(b, s, z, info, !s.real_time_iteration);
        if passed {
            return SqpStatus::Converged;
        }
        if s.real_time_iteration {
            *z += b.step();
            b.clamp(z);
            return SqpStatus::RealTimeIteration;
        }
        b.before_line_search();
        cost = match line_search(b, s, cost, z_trial, z) {
            Ok(c) => c,
            Err(status) => {
                exact_residual(b, z, info, exact);
                return status;
            }
        };
        info.cost = cost;
        // KKT at the new point with the last multipliers (exact for linear residuals after a
        // full step; avoids one QP per solve near convergence). In full: the solve may end
        // after the next QP, which replaces the multipliers.
        if terminated(b, s, z, info, false).0 {
            return SqpStatus::Converged;
        }
    }
    SqpStatus::MaxIterations
}

/// After a failed line search: makes `info.kkt_residual` the full residual at `z` when the
/// termination test before it stopped early (`exact == false`). The trial evaluations replaced
/// the linearisation at `z`, so `z` is evaluated again with it (the QP multipliers are still
/// the last ones).
fn exact_residual<B: SqpSteps + ?Sized>(
    b: &mut B,
    z: &DVector<f64>,
    info: &mut SqpInfo,
    exact: bool,
) {
    if exact {
        return;
    }
    b.evaluate(z, true);
    info.kkt_residual = b.kkt(z).0;
}

/// Whether the wall-clock budget of the solve is spent.
fn out_of_time(s: &SqpSettings, start: Instant) -> bool {
    s.max_time.is_some_and(|t| start.elapsed() > t)
}

/// Feasibility projection of the warm start: clamping is the exact projection onto the box; if
/// the clamped point still violates a general constraint, the original point is projected with
/// the back-end's projection QP. On failure `z` is restored.
fn project_feasible<B: SqpSteps + ?Sized>(
    b: &mut B,
    s: &SqpSettings,
    z_orig: &mut DVector<f64>,
    z: &mut DVector<f64>,
    info: &mut SqpInfo,
) -> Result<(), SqpStatus> {
    z_orig.copy_from(z);
    b.clamp(z);
    if b.general_violation(z) <= 0.1 * s.feasibility_tolerance {
        return Ok(());
    }
    z.copy_from(z_orig);
    b.general_violation(z);
    let qi = b.projection_qp(z);
    info.qp_iterations += qi.iterations;
    match qi.status {
        QpStatus::Solved => {}
        QpStatus::Infeasible => {
            z.copy_from(z_orig);
            return Err(SqpStatus::Infeasible);
        }
        _ => {
            z.copy_from(z_orig);
            return Err(SqpStatus::QpFailed);
        }
    }
    *z += b.step();
    b.clamp(z);
    b.general_violation(z);
    Ok(())
}

/// Termination test: KKT residual within `kkt_tolerance` and violation within
/// `feasibility_tolerance`; records the residual in `info`. With `early`, a back-end may stop
/// once the test has failed ([`SqpSteps::kkt_test`]); returns `(passed, residual exact)`.
fn terminated<B: SqpSteps + ?Sized>(
    b: &mut B,
    s: &SqpSettings,
    z: &DVector<f64>,
    info: &mut SqpInfo,
    early: bool,
) -> (bool, bool) {
    let t = if early {
        b.kkt_test(z, s.kkt_tolerance, s.feasibility_tolerance)
    } else {
        let (kkt, violation) = b.kkt(z);
        KktTest {
            kkt,
            violation,
            exact: true,
        }
    };
    info.kkt_residual = t.kkt;
    (
        t.kkt <= s.kkt_tolerance && t.violation <= s.feasibility_tolerance,
        t.exact,
    )
}

/// Armijo backtracking on `φ(α) = ½‖r(z + α d)‖²` (trial points clamped into the box); the full
/// step is evaluated with its linearisation right away (it is usually accepted). On success the
/// accepted point is the new `z` (linearised, accepted by the back-end) and its cost returned.
fn line_search<B: SqpSteps + ?Sized>(
    b: &mut B,
    s: &SqpSettings,
    cost: f64,
    z_trial: &mut DVector<f64>,
    z: &mut DVector<f64>,
) -> Result<f64, SqpStatus> {
    // Allow for rounding noise in evaluating ½‖r‖² so that tiny steps near a KKT point
    // (predicted decrease below the noise level) are not rejected.
    let slack = 1e3 * f64::EPSILON * cost;
    let slope = b.slope();
    if slope.is_nan() || slope >= slack {
        return Err(SqpStatus::LineSearchFailed);
    }
    let slope = slope.min(0.0);
    let mut alpha = 1.0;
    let mut accepted = None;
    let mut any_finite = false;
    for ls in 0..=s.max_line_search_steps {
        z_trial.copy_from(z);
        z_trial.axpy(alpha, b.step(), 1.0);
        b.clamp(z_trial);
        let c_trial = b.evaluate(z_trial, ls == 0);
        if c_trial.is_finite() {
            any_finite = true;
            if c_trial <= cost + s.armijo_constant * alpha * slope + slack {
                accepted = Some((c_trial, ls == 0));
                break;
            }
        }
        alpha *= s.backtracking_factor;
    }
    let Some((mut c_new, have_jacobian)) = accepted else {
        return Err(if any_finite {
            SqpStatus::LineSearchFailed
        } else {
            SqpStatus::NonFiniteInput
        });
    };
    if !have_jacobian {
        c_new = b.evaluate(z_trial, true);
        if !c_new.is_finite() {
            return Err(SqpStatus::NonFiniteInput);
        }
    }
    if !b.accept(Some(z), z_trial) {
        return Err(SqpStatus::NonFiniteInput);
    }
    z.copy_from(z_trial);
    Ok(c_new)
}

/// Inertia correction of the exact Hessian (the rule of IPOPT, Wächter & Biegler 2006, §3.1),
/// shared by both back-ends so that they shift identically: when the QP with the exact Hessian
/// `H` reports it not positive definite, the QP is solved with `H + μ I` on the decision
/// variables (the torque increments; in the stage form `R_j + μ I`, which condenses to the same
/// matrix), `μ` starting at `max(μ_min, μ_last/3)` (or `μ_min` when no shift was needed before in
/// this solve) and growing ×8 (×100 the first time) until the QP is solved; beyond `μ_max` the
/// iteration takes the Gauss–Newton step. `μ_min = 1e-8·(1 + d)`, `μ_max = 1·(1 + d)` with `d`
/// the largest diagonal entry of `JᵀJ` (the scale of the Hessian regularisation).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct HessianShift {
    last: f64,
}

impl HessianShift {
    /// `μ_min / (1 + d)`.
    pub const MIN: f64 = 1e-8;
    /// `μ_max / (1 + d)`.
    pub const MAX: f64 = 1.0;

    /// Forgets the last shift (at the start of every solve).
    pub fn reset(&mut self) {
        self.last = 0.0;
    }

    /// Solves the QP with the shifts of the rule after the unshifted one failed as not positive
    /// definite: `solve(μ)` solves with `H + μ I`. Returns the first QP that did not fail so
    /// (iterations summed over the tries), or `None` with the summed iterations when `μ_max` was
    /// exceeded.
    pub fn solve(
        &mut self,
        maxdiag: f64,
        mut solve: impl FnMut(f64) -> QpInfo,
    ) -> Result<QpInfo, usize> {
        let scale = 1.0 + maxdiag;
        let (lo, hi) = (Self::MIN * scale, Self::MAX * scale);
        if !(lo.is_finite() && hi.is_finite()) {
            return Err(0);
        }
        let fresh = self.last == 0.0;
        let mut mu = if fresh { lo } else { (self.last / 3.0).max(lo) };
        let mut iterations = 0;
        loop {
            let mut qi = solve(mu);
            iterations += qi.iterations;
            if qi.status != QpStatus::NumericalError {
                self.last = mu;
                qi.iterations = iterations;
                return Ok(qi);
            }
            mu *= if fresh { 100.0 } else { 8.0 };
            // The slack keeps rounding differences of `d` between the back-ends from deciding
            // (the first sequence reaches `μ_max` exactly).
            if mu > hi * (1.0 + 1e-9) {
                return Err(iterations);
            }
        }
    }
}

/// Running maxima of the primal violation and complementarity of bound pairs, for the KKT
/// tests of the back-ends.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct BoundCheck {
    /// Largest violation `max(lo, hi)` seen.
    pub violation: f64,
    /// Largest complementarity product `|λ|·slack` seen.
    pub complementarity: f64,
}

impl BoundCheck {
    /// Adds the bound pair with gaps `lo = l − v`, `hi = v − u` and multiplier `λ` (negative on
    /// the lower bound, positive on the upper one).
    ///
    /// The running maxima are never NaN (they start at zero and a NaN argument is ignored, as by
    /// `f64::max`), so each is updated by one comparison ([`max_into`]) with `lo.max(hi)`, formed
    /// beside the chain: the same maxima as `violation.max(lo).max(hi)`, with a dependency chain
    /// of one `maxsd` a pair instead of two NaN-testing `f64::max`.
    #[inline]
    pub fn add(&mut self, lo: f64, hi: f64, l: f64) {
        self.violation = max_into(self.violation, lo.max(hi));
        if l < 0.0 {
            self.complementarity = max_into(self.complementarity, -l * (-lo).max(0.0));
        } else if l > 0.0 {
            self.complementarity = max_into(self.complementarity, l * (-hi).max(0.0));
        }
    }

    /// The maxima over the pairs of `self` and of `other` (checks of disjoint pair sets, built
    /// as independent chains).
    #[inline]
    pub fn merge(&mut self, other: &BoundCheck) {
        self.violation = max_into(self.violation, other.violation);
        self.complementarity = max_into(self.complementarity, other.complementarity);
    }
}

/// `max(v, x)` for a `v` that is not NaN: `x` when larger, else `v` (a NaN `x` is ignored, as by
/// `f64::max`; of `±0` either may be returned, as by `f64::max`). One comparison, where `f64::max`
/// also tests `v` for NaN.
#[inline(always)]
fn max_into(v: f64, x: f64) -> f64 {
    if x > v {
        x
    } else {
        v
    }
}

/// `k`, or `∞` when `k` is NaN.
#[inline]
pub(crate) fn finite_or_inf(k: f64) -> f64 {
    if k.is_nan() {
        f64::INFINITY
    } else {
        k
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A back-end whose QP step always increases the cost (the line search fails) and whose
    /// termination test stops early; its full residual is right only at the point of the last
    /// linearisation.
    struct UphillSteps {
        step: DVector<f64>,
        linearised_at: f64,
        early_tests: usize,
    }

    impl SqpSteps for UphillSteps {
        fn check_inputs(&mut self, _z: &DVector<f64>) -> Result<(), SqpStatus> {
            Ok(())
        }
        fn clamp(&self, _z: &mut DVector<f64>) {}
        fn general_violation(&mut self, _z: &DVector<f64>) -> f64 {
            0.0
        }
        fn projection_qp(&mut self, _z: &DVector<f64>) -> QpInfo {
            qp(QpStatus::Solved)
        }
        fn evaluate(&mut self, z: &DVector<f64>, jacobian: bool) -> f64 {
            if jacobian {
                self.linearised_at = z[0];
            }
            1.0 + z[0] * z[0]
        }
        fn accept(&mut self, _z_old: Option<&DVector<f64>>, _z_new: &DVector<f64>) -> bool {
            true
        }
        fn solve_qp(&mut self, _z: &DVector<f64>) -> QpInfo {
            qp(QpStatus::Solved)
        }
        fn step(&self) -> &DVector<f64> {
            &self.step
        }
        fn slope(&self) -> f64 {
            -1.0
        }
        fn kkt(&mut self, z: &DVector<f64>) -> (f64, f64) {
            (if self.linearised_at == z[0] { 0.5 } else { 9.0 }, 0.0)
        }
        fn kkt_test(&mut self, _z: &DVector<f64>, _kkt_tol: f64, _feas_tol: f64) -> KktTest {
            self.early_tests += 1;
            KktTest {
                kkt: 0.25,
                violation: 0.0,
                exact: false,
            }
        }
    }

    #[test]
    fn a_failed_line_search_reports_the_full_residual_at_the_point() {
        let mut b = UphillSteps {
            step: DVector::from_element(1, 1.0),
            linearised_at: f64::NAN,
            early_tests: 0,
        };
        let s = SqpSettings {
            max_line_search_steps: 3,
            ..SqpSettings::default()
        };
        let mut z = DVector::zeros(1);
        let mut z_trial = DVector::zeros(1);
        let info = solve(&mut b, &s, &mut z_trial, &mut z);
        assert_eq!(info.status, SqpStatus::LineSearchFailed);
        assert_eq!(b.early_tests, 1);
        assert_eq!(z[0], 0.0);
        // Not the early test's lower bound (0.25), nor the residual with the trial point's
        // linearisation (9.0).
        assert_eq!(info.kkt_residual, 0.5);
        // A real-time iteration reports the full residual without an early test.
        b.early_tests = 0;
        let rti = SqpSettings {
            real_time_iteration: true,
            ..s
        };
        let info = solve(&mut b, &rti, &mut z_trial, &mut z);
        assert_eq!(info.status, SqpStatus::RealTimeIteration);
        assert_eq!((b.early_tests, info.kkt_residual), (0, 0.5));
    }

    fn qp(status: QpStatus) -> QpInfo {
        QpInfo {
            status,
            iterations: 1,
            objective: 0.0,
        }
    }

    #[test]
    fn hessian_shift_follows_the_inertia_correction_rule() {
        // First correction of a solve: μ_min, ×100 up to μ_max (= μ_min·1e8, reached although
        // rounding may put it a hair above), then give up.
        let mut sh = HessianShift::default();
        let mut tried = vec![];
        let r = sh.solve(2.0, |mu| {
            tried.push(mu);
            qp(QpStatus::NumericalError)
        });
        assert_eq!(r.unwrap_err(), 5);
        let want = [3e-8, 3e-6, 3e-4, 3e-2, 3.0];
        assert_eq!(tried.len(), want.len());
        for (a, b) in tried.iter().zip(want) {
            assert!((a - b).abs() <= 1e-12 * b, "{a} vs {b}");
        }
        // Success at 3e-4: remembered; the next correction starts at a third of it, ×8.
        tried.clear();
        let r = sh.solve(2.0, |mu| {
            tried.push(mu);
            qp(if mu > 1e-4 {
                QpStatus::Solved
            } else {
                QpStatus::NumericalError
            })
        });
        assert_eq!(r.unwrap().iterations, 3);
        tried.clear();
        let r = sh.solve(2.0, |mu| {
            tried.push(mu);
            qp(if mu > 5e-4 {
                QpStatus::Solved
            } else {
                QpStatus::NumericalError
            })
        });
        assert!(r.is_ok());
        assert!((tried[0] - 1e-4).abs() < 1e-16 && (tried[1] - 8e-4).abs() < 1e-16);
        // A reset forgets it; a non-finite scale never shifts.
        sh.reset();
        assert_eq!(sh.solve(f64::NAN, |_| qp(QpStatus::Solved)).unwrap_err(), 0);
    }
}
