//! The SQP's settings, termination status and summary: shared by the engine
//! (`solver/engine.rs`) and its back-ends, the dense [`Sqp`](super::Sqp) and the stage-structured
//! `control::StructuredSqp`.

use core::time::Duration;

use super::qp::QpSettings;
use super::{check_range, SolverError};

/// Settings of the SQP solver. Use [`SqpSettings::default`] and override fields as needed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SqpSettings {
    /// Maximum number of SQP iterations (QP subproblems, not counting the projection of an
    /// infeasible warm start). Default `20`; allowed `1..=1000`.
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
    /// returned with [`SqpStatus::MaxTime`]. Checked once per iteration (a zero budget stops
    /// after the first). Default `None`; allowed at most 10 s.
    pub max_time: Option<Duration>,
    /// Settings of the inner QP solver (see [`QpSettings`]). Default `QpSettings::default()`.
    pub qp: QpSettings,
    /// Real-time iteration (Diehl's RTI scheme): when the KKT test fails at the warm start,
    /// take the full step of one QP (clamped into the box; it satisfies the linear rows) and
    /// stop with [`SqpStatus::RealTimeIteration`] — one linearisation and one QP per solve, no
    /// line search. Meant for a controller whose warm start is the shifted previous solution,
    /// so the iterate is refined from period to period. Default `false`.
    pub real_time_iteration: bool,
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
            real_time_iteration: false,
        }
    }
}

impl SqpSettings {
    /// Largest allowed `max_iterations`.
    pub const MAX_ITERATIONS: usize = 1000;
    /// Longest allowed `max_time` (10 s).
    pub const MAX_TIME: Duration = Duration::from_secs(10);

    /// Checks every field against its allowed range; the error names the field and value.
    pub fn validate(&self) -> Result<(), SolverError> {
        #[cfg(not(feature = "std"))]
        if self.hessian == HessianModel::Exact {
            return Err(SolverError::InvalidSetting {
                field: "hessian",
                value: f64::NAN,
                allowed: "gauss_newton or structured_secant (exact needs the `std` feature)",
            });
        }
        if !(1..=Self::MAX_ITERATIONS).contains(&self.max_iterations) {
            return Err(SolverError::InvalidSetting {
                field: "max_iterations",
                value: self.max_iterations as f64,
                allowed: "integer in 1..=1000",
            });
        }
        check_range(
            "kkt_tolerance",
            self.kkt_tolerance,
            0.0,
            1.0,
            "finite, in [0, 1]",
        )?;
        if let Some(t) = self.max_time {
            if t > Self::MAX_TIME {
                return Err(SolverError::InvalidSetting {
                    field: "max_time",
                    value: t.as_nanos() as f64 / 1e3,
                    allowed: "at most 10 s (0..=10000000 µs), or none",
                });
            }
        }
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
    /// The exact Hessian `JᵀJ + Σ rᵢ ∇²rᵢ` (the constraints are linear, so this is the
    /// Lagrangian Hessian): for the NMPC problem the stage blocks `W_j = ∇²(λ_{j+1}ᵀ Φ_j)` of the
    /// RK4 prediction step with the adjoint `λ` (forward-mode AD; `control::StepHessian`),
    /// condensed in the dense back-end and passed as `Q_j`, `R_j`, `S_j` blocks to the Riccati QP
    /// in the structured one, as in acados/HPIPM. Locally quadratic convergence. Safeguard,
    /// identical in both back-ends: when the QP reports a Hessian that is not positive definite
    /// (`QpStatus::NumericalError`), the QP is solved with `H + μ I` on the decision variables,
    /// `μ` by IPOPT's inertia-correction rule (from `1e-8·(1 + max diag JᵀJ)`, ×100 / ×8, the
    /// last `μ/3` remembered within a solve); beyond `μ = 1 + max diag JᵀJ` that iteration takes
    /// the Gauss–Newton step. Problems that do not provide the curvature
    /// ([`LeastSquares::add_residual_curvature`](super::LeastSquares::add_residual_curvature)) and the coupled scenario tree use Gauss–Newton.
    Exact,
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
    /// `real_time_iteration` is set and the one full QP step was taken (the KKT test failed at
    /// the warm start); `z` is feasible. `cost`, `kkt_residual` and the residuals refer to the
    /// warm start.
    RealTimeIteration,
    /// `z`, the constraints or the problem dimensions differ from those given to
    /// [`Sqp::new`](super::Sqp::new) (a programming error); `z` is unchanged.
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
