//! Building the controllers of one experiment of the paper's simulation study from a
//! [`Experiment`](crate::config::Experiment): the settings each controller takes from it, the PD,
//! the plain NMPC, the multi-stage NMPC and the supervisor's transparent fallback, for either
//! layout ([`Dof`]).

use super::error::RunError;
use super::layout::{prediction_model, scenario_robot, Dof};
use crate::config::{Experiment, Formulation, Method};
use crate::control::{
    Controller, IntentEstimator, MultiStage, MultiStageOptions, Nmpc, NmpcSettings, PdController,
    SafetySettings, SolverChoice, TorqueLimits, Transparent, VelocityTracking, AUTO_TREE_MIN_VARS,
};
use crate::control::{AUTO_K1_PER_STIFFNESS, AUTO_K2_PER_STIFFNESS};
use crate::estimate::EstimatorOptions;
use crate::sim::Trajectory;
use alloc::{boxed::Box, vec};
use nalgebra::SVector;

/// NMPC settings of a scenario.
pub fn nmpc_settings(s: &Experiment) -> NmpcSettings {
    let c = &s.controller;
    NmpcSettings {
        np: c.np,
        nc: c.nc,
        r_d: c.r_d,
        r_t: c.r_t,
        sqp: c.sqp.settings(),
        qp: c.sqp.qp,
        // The paper's eq. 7 (the multi-stage NMPC of the robust method sets its own,
        // `multistage_nmpc_settings`).
        velocity_tracking: VelocityTracking::Joint,
    }
}

/// The NMPC settings of every scenario of the multi-stage NMPC: [`nmpc_settings`] with the
/// robust method's `[controller.robust] velocity_tracking` (the paper's method: joint space).
pub fn multistage_nmpc_settings(s: &Experiment) -> NmpcSettings {
    let mut st = nmpc_settings(s);
    if s.controller.method == Method::Robust {
        st.velocity_tracking = s.controller.robust.velocity_tracking;
    }
    st
}

/// The QP back-end and Hessian model `[controller.sqp] qp` and `hessian` resolve to for the
/// NMPC of scenario `s` with `joints` joints (`control::QpBackend::resolve`): for a
/// `multistage` controller with `multistage.formulation = "coupled"` the scenario tree's, else
/// one scenario's NMPC. The run summary reports it (`solver`).
pub fn solver_choice(s: &Experiment, joints: usize, multistage: bool) -> SolverChoice {
    let c = &s.controller;
    let tree = multistage && s.multistage.formulation == Formulation::Coupled;
    let n_vars = if tree {
        let nr = s.multistage.robust_horizon.clamp(1, c.nc);
        let scenarios = crate::config::scenarios::names(s).len();
        joints * (nr + scenarios * (c.nc - nr))
    } else {
        joints * c.nc
    };
    c.sqp
        .qp
        .resolve(c.sqp.hessian, n_vars, tree, AUTO_TREE_MIN_VARS)
}

/// `settings` with the QP back-end of [`solver_choice`] for `joints` joints (`qp = "auto"`
/// resolved with the Hessian setting, never `Auto`).
fn resolved(
    mut settings: NmpcSettings,
    s: &Experiment,
    joints: usize,
    multistage: bool,
) -> NmpcSettings {
    settings.qp = solver_choice(s, joints, multistage).qp;
    settings
}

/// Torque limits of a scenario (paper eqs. 8-9).
pub fn limits(s: &Experiment) -> TorqueLimits {
    TorqueLimits {
        max: s.controller.torque_max,
        rate: s.rate_limit_per_step(),
    }
}

/// Intent-estimate gains of a scenario (paper eqs. 5-6; `"auto"` = `κ / ks`, `control::IntentGain`).
pub fn intent(s: &Experiment) -> IntentEstimator {
    IntentEstimator {
        k1: s.controller.k1.gain(AUTO_K1_PER_STIFFNESS),
        k2: s.controller.k2.gain(AUTO_K2_PER_STIFFNESS),
    }
}

/// Initial previous torque `T_R(−1) = G_R(q(0))` of the nominal robot (MODEL.md §7).
pub fn initial_torque<D: Dof<N>, const N: usize>(s: &Experiment) -> SVector<f64, N> {
    let q0 = D::trajectory(s).eval(0.0).0;
    scenario_robot::<D, N>(s, 0.0).chain.gravity_torque(&q0)
}

/// The PD baseline of scenario `s` (`[controller.pd]` gains), previous torque `t0`.
pub fn build_pd<D: Dof<N>, const N: usize>(
    s: &Experiment,
    t0: SVector<f64, N>,
) -> Result<Box<dyn Controller<N>>, RunError> {
    Ok(Box::new(PdController::new(
        scenario_robot::<D, N>(s, 0.0),
        intent(s),
        D::straps(s),
        limits(s),
        s.controller.pd.kp,
        s.controller.pd.kd,
        t0,
    )))
}

/// The plain NMPC of scenario `s` on the nominal (0 kg) model, previous torque `t0`.
pub fn build_nmpc<D: Dof<N>, const N: usize>(
    s: &Experiment,
    t0: SVector<f64, N>,
) -> Result<Box<dyn Controller<N>>, RunError> {
    Ok(Box::new(Nmpc::new(
        prediction_model::<D, N>(s, 0.0),
        &resolved(nmpc_settings(s), s, N, false),
        intent(s),
        limits(s),
        t0,
    )?))
}

/// The transparent fallback controller of scenario `s` (the supervisor's `fallback` response,
/// and what `hold` and `ramp_to_zero` hand over to):
/// the bare robot and the robot with 1 kg at `robot.payload_position_m`, the straps, and the
/// known measurement filter window.
pub fn fallback<D: Dof<N>, const N: usize>(s: &Experiment) -> Transparent<N> {
    Transparent::new(
        scenario_robot::<D, N>(s, 0.0),
        scenario_robot::<D, N>(s, 1.0),
        &D::straps(s),
        s.timing.dt,
        s.uncertainty.filter_window,
        s.monitors.fallback,
    )
}

/// Build the multi-stage controller of scenario `s` for layout `D`.
pub fn build_multistage<D, const N: usize, const NA: usize, const NY: usize>(
    s: &Experiment,
    t0: SVector<f64, N>,
) -> Result<Box<dyn Controller<N>>, RunError>
where
    D: Dof<N>,
{
    let models = super::multistage::prediction_models::<D, N>(s);
    let ekf = s.ekf;
    let est = EstimatorOptions {
        dt: s.timing.dt,
        substeps: s.timing.prediction_substeps,
        innovation: s.multistage.innovation,
        c1: s.multistage.c1,
        floor: s.multistage.probability_floor,
    };
    let options = MultiStageOptions {
        formulation: s.multistage.formulation,
        robust_horizon: s.multistage.robust_horizon,
        parallel: s.multistage.parallel,
    };
    // The robust method's intent gains follow the strap stiffness (`[controller.robust]
    // intent_gains`); the paper's are the configured ones.
    let intent = match s.controller.method {
        Method::Paper => intent(s),
        Method::Robust => {
            let g = s.controller.robust.intent_gains;
            IntentEstimator {
                k1: g.gain(s.controller.k1, AUTO_K1_PER_STIFFNESS),
                k2: g.gain(s.controller.k2, AUTO_K2_PER_STIFFNESS),
            }
        }
    };
    let ms = MultiStage::<N, NA, NY>::new(
        models,
        &resolved(multistage_nmpc_settings(s), s, N, true),
        &ekf,
        &est,
        options,
        intent,
        limits(s),
        t0,
    )?;
    let ms = match s.controller.method {
        Method::Paper => ms,
        Method::Robust => ms.with_robust(&s.controller.robust, s.uncertainty.filter_window),
    };
    Ok(Box::new(ms))
}

impl SafetySettings {
    /// The settings of scenario `s` (`[monitors]`, `[faults] saturation_n`, limits, K1, dt).
    pub fn from_scenario(s: &Experiment) -> Self {
        SafetySettings {
            limits: TorqueLimits {
                max: s.controller.torque_max,
                rate: s.rate_limit_per_step(),
            },
            dt: s.timing.dt,
            k1: s
                .controller
                .k1
                .value()
                .unwrap_or(AUTO_K1_PER_STIFFNESS / s.straps.stiffness),
            strap_levers_m: vec![s.straps.ls1_m, s.straps.ls2_m],
            strap_stiffness: s.straps.stiffness,
            strap_damping: s.straps.damping,
            saturation_n: s.faults.saturation_n,
            angle_max: Self::ANGLE_MAX,
            velocity_max: Self::VELOCITY_MAX,
            monitors: s.monitors.clone(),
            clear_after_s: Self::CLEAR_AFTER_S,
            max_events: 4096,
            filter_window: s.uncertainty.filter_window,
        }
    }
}
