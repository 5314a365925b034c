//! Non-robust NMPC (paper §3.1, eq. 7 with constraints 8-9) on the SQP of [`crate::solver`].

use super::limits::LimitsError;
use super::nmpc_problem::{NmpcProblem, NmpcSettings};
use super::ocp::StructuredSqp;
use super::prediction::{HorizonInputs, PredictionModel};
use super::{ControlOutput, Controller, IntentEstimator, Measurement, StepStatus, TorqueLimits};
use crate::model::JointState;
use crate::solver::{Constraints, LeastSquares, SolverError, Sqp, SqpInfo, SqpStatus};
use alloc::boxed::Box;
use nalgebra::{DVector, SVector};

/// The SQP of one scenario, with the QP back-end the settings' [`QpBackend`] resolves to (only
/// that one is allocated).
#[derive(Clone, Debug)]
enum CoreSolver<const N: usize> {
    /// Condensed dense SQP and its constraint rows.
    Dense(Box<(Sqp, Constraints)>),
    /// Multiple-shooting SQP with the Riccati QP.
    Structured(Box<StructuredSqp<N>>),
}

/// Solver state of one scenario's NMPC: problem, SQP workspace, constraints and warm start.
/// Allocates only in [`NmpcCore::new`].
#[derive(Clone, Debug)]
pub struct NmpcCore<const N: usize> {
    /// The problem (model and per-step data).
    pub problem: NmpcProblem<N>,
    solver: CoreSolver<N>,
    z: DVector<f64>,
    /// Info of the last solve.
    pub info: SqpInfo,
}

impl<const N: usize> NmpcCore<N> {
    /// Build the problem and allocate the SQP workspace.
    pub fn new(model: PredictionModel<N>, settings: &NmpcSettings) -> Result<Self, SolverError> {
        let problem = NmpcProblem::new(model, settings);
        let n = problem.num_vars();
        let m = problem.num_residuals();
        let solver = if settings.qp.is_structured(n) {
            CoreSolver::Structured(Box::new(StructuredSqp::new(settings)?))
        } else {
            CoreSolver::Dense(Box::new((
                Sqp::new(n, m, n, settings.sqp)?,
                Constraints::unbounded(n, n),
            )))
        };
        Ok(NmpcCore {
            problem,
            solver,
            z: DVector::zeros(n),
            info: SqpInfo {
                status: SqpStatus::Converged,
                iterations: 0,
                qp_iterations: 0,
                cost: 0.0,
                kkt_residual: 0.0,
                solve_time: core::time::Duration::ZERO,
            },
        })
    }

    /// Solve eq. 7 from state `x0` with previous torque `t_prev` and horizon inputs; the
    /// previous solution, shifted by one step, is the warm start. Returns the solver info; the
    /// solution is [`Self::solution`].
    pub fn solve(
        &mut self,
        x0: JointState<f64, N>,
        t_prev: SVector<f64, N>,
        inputs: HorizonInputs<N>,
        limits: &TorqueLimits,
    ) -> SqpInfo {
        self.problem.x0 = x0;
        self.problem.t_prev = t_prev;
        self.problem.inputs = inputs;
        // Warm start: shift the previous increments by one step, last one zero.
        let n = self.z.len();
        for k in 0..n {
            self.z[k] = if k + N < n { self.z[k + N] } else { 0.0 };
        }
        if !self.z.iter().all(|v| v.is_finite()) {
            self.z.fill(0.0);
        }
        self.info = match &mut self.solver {
            CoreSolver::Structured(st) => st.solve(&self.problem, limits, &mut self.z),
            CoreSolver::Dense(dense) => {
                let (sqp, constraints) = &mut **dense;
                self.problem.write_constraints(limits, constraints);
                sqp.solve(&mut self.problem, constraints, &mut self.z)
            }
        };
        if !matches!(
            self.info.status,
            SqpStatus::Converged
                | SqpStatus::MaxIterations
                | SqpStatus::MaxTime
                | SqpStatus::RealTimeIteration
        ) {
            // Forget a failed plan so the next warm start is clean.
            self.z.fill(0.0);
        }
        self.info
    }

    /// The current decision vector (torque increments, `N·Nc`).
    pub fn solution(&self) -> &DVector<f64> {
        &self.z
    }

    /// The first increment `dT(k)` of the current solution.
    pub fn first_increment(&self) -> SVector<f64, N> {
        SVector::from_fn(|a, _| self.z[a])
    }

    /// The increment `dT(k+j)` of the current solution (`None` past the control horizon).
    pub fn increment(&self, j: usize) -> Option<SVector<f64, N>> {
        if (j + 1) * N > self.z.len() {
            return None;
        }
        Some(SVector::from_fn(|a, _| self.z[j * N + a]))
    }

    /// Whether the structured (Riccati) QP path is in use.
    pub fn is_structured(&self) -> bool {
        matches!(self.solver, CoreSolver::Structured(_))
    }

    /// Reset the warm start.
    pub fn reset(&mut self) {
        self.z.fill(0.0);
    }
}

/// Map a solver status to the step status and whether its iterate may be applied.
pub fn classify(status: SqpStatus) -> (StepStatus, bool) {
    match status {
        SqpStatus::Converged | SqpStatus::RealTimeIteration => (StepStatus::Ok, true),
        SqpStatus::MaxIterations => (StepStatus::MaxIterations, true),
        SqpStatus::MaxTime => (StepStatus::MaxTime, true),
        _ => (StepStatus::SolverFailed, false),
    }
}

/// The non-robust NMPC controller of paper §3.1: one scenario (the nominal model, no
/// disturbance estimate), torque `T(k) = T(k−1) + dT(k)`.
#[derive(Clone, Debug)]
pub struct Nmpc<const N: usize> {
    core: NmpcCore<N>,
    intent: IntentEstimator,
    limits: TorqueLimits,
    prev: SVector<f64, N>,
}

/// Why an [`Nmpc`] could not be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum NmpcError {
    /// Invalid torque limits.
    #[error(transparent)]
    Limits(#[from] LimitsError),
    /// Invalid solver settings or dimensions.
    #[error(transparent)]
    Solver(#[from] SolverError),
}

impl<const N: usize> Nmpc<N> {
    /// A controller for `model` with initial previous torque `t0` (MODEL.md §7: the nominal gravity
    /// torque at the initial state).
    pub fn new(
        model: PredictionModel<N>,
        settings: &NmpcSettings,
        intent: IntentEstimator,
        limits: TorqueLimits,
        t0: SVector<f64, N>,
    ) -> Result<Self, NmpcError> {
        limits.validate()?;
        Ok(Nmpc {
            core: NmpcCore::new(model, settings)?,
            intent,
            limits,
            prev: limits.admissible(&t0),
        })
    }

    /// The solver core (problem, last info, solution).
    pub fn core(&self) -> &NmpcCore<N> {
        &self.core
    }
}

/// Horizon inputs from a filtered measurement (MODEL.md §8).
pub fn horizon_inputs<const N: usize>(
    intent: &IntentEstimator,
    model: &PredictionModel<N>,
    m: &Measurement<N>,
    disturbance: SVector<f64, N>,
) -> HorizonInputs<N> {
    let (q_h, qd_h) = intent.estimate(m, &model.straps);
    HorizonInputs {
        q_h,
        qd_h,
        t_int_measured: model.straps.torque(&m.force),
        disturbance,
    }
}

impl<const N: usize> Controller<N> for Nmpc<N> {
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N> {
        if !m.is_finite() {
            return ControlOutput {
                torque: self.prev,
                status: StepStatus::BadMeasurement,
                iterations: 0,
            };
        }
        let inputs = horizon_inputs(&self.intent, &self.core.problem.model, m, SVector::zeros());
        let x0 = JointState { q: m.q, qd: m.qd };
        let info = self.core.solve(x0, self.prev, inputs, &self.limits);
        let (status, usable) = classify(info.status);
        let desired = if usable {
            self.prev + self.core.first_increment()
        } else {
            self.prev
        };
        let torque = self.limits.clamp(&self.prev, &desired);
        self.prev = torque;
        ControlOutput {
            torque,
            status,
            iterations: info.iterations as u32,
        }
    }

    fn name(&self) -> &'static str {
        "nmpc"
    }

    fn planned_torques(&self, out: &mut [SVector<f64, N>]) -> usize {
        if !classify(self.core.info.status).1 {
            return 0;
        }
        super::plan_from(&self.prev, &self.limits, out, |j| self.core.increment(j))
    }

    fn previous_torque(&self) -> SVector<f64, N> {
        self.prev
    }

    fn set_previous_torque(&mut self, t: SVector<f64, N>) {
        self.prev = self.limits.admissible(&t);
    }
}
