//! Numerical optimisation back end of the NMPC controller.
//!
//! * [`qp`] — a dense, allocation-free Goldfarb–Idnani dual active-set solver for strictly
//!   convex QPs with box and two-sided general linear constraints.
//! * [`riccati`] — the same kind of QP in optimal-control stage form, solved by a Riccati
//!   factorisation inside the Goldfarb–Idnani method: linear in the horizon.
//! * [`arrowhead`] — the scenario tree of the coupled multi-stage NMPC (shared first inputs):
//!   per-scenario Riccati recursions and a dense block on the shared inputs; linear in the
//!   horizon and in the number of scenarios.
//! * `active_set` (internal) — the Goldfarb–Idnani loop on box constraints that [`riccati`] and
//!   [`arrowhead`] share; each supplies its own solve with a bound normal.
//! * [`sqp`] — a Gauss–Newton SQP method for box- and linearly-constrained nonlinear least
//!   squares, the form of the paper's NMPC problem (eq. 7 with constraints eqs. 8–9).
//!
//! Both solvers follow the Clarabel/OpEn style: all workspace is allocated at construction,
//! settings are plain structs with documented defaults and a `validate()` method, and a solve
//! never panics. Not converging is reported through a status enum, never as an error;
//! [`SolverError`] is only returned for invalid settings or dimensions at construction time.

mod active_set;
pub mod arrowhead;
mod cholesky;
pub(crate) mod engine;
pub mod qp;
pub mod riccati;
mod settings;
pub mod sqp;
mod stage;
mod stage_data;

pub use arrowhead::TreeQp;
pub use qp::{DenseQp, QpInfo, QpSettings, QpStatus};
pub use riccati::RiccatiQp;
pub use settings::{HessianModel, SqpInfo, SqpSettings, SqpStatus};
pub use sqp::{Constraints, LeastSquares, Sqp};
pub use stage_data::{StageDims, StageQpData};

/// Error returned when a solver is configured with invalid settings or dimensions.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolverError {
    /// A setting is outside its allowed range.
    #[error("invalid solver setting `{field}` = {value}: allowed range is {allowed}")]
    InvalidSetting {
        /// Name of the offending settings field.
        field: &'static str,
        /// The rejected value (integers are converted to `f64`).
        value: f64,
        /// Human-readable description of the allowed range.
        allowed: &'static str,
    },
    /// A problem dimension is invalid.
    #[error("invalid solver dimension `{what}` = {value}: {allowed}")]
    InvalidDimension {
        /// Name of the offending dimension.
        what: &'static str,
        /// The rejected value.
        value: usize,
        /// Human-readable description of the allowed range.
        allowed: &'static str,
    },
}

/// Checks `lo <= v <= hi` (and `v` finite), naming the field on failure.
pub(crate) fn check_range(
    field: &'static str,
    v: f64,
    lo: f64,
    hi: f64,
    allowed: &'static str,
) -> Result<(), SolverError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(SolverError::InvalidSetting {
            field,
            value: v,
            allowed,
        })
    }
}
