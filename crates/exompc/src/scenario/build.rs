//! Building the plant, trajectory, models and controllers of one experiment of the paper's
//! simulation study from a [`Scenario`](crate::config::Scenario): the 2-DOF swing ([`TwoDof`])
//! or the 1-DOF knee ([`OneDof`], hip locked) variant.

use super::registry::{controller_info, Builder, ControllerInfo};
use super::RunError;
use crate::config::{ControllerKind, Method, MonitorResponse, Scenario};
use crate::control::{
    Controller, IntentEstimator, MultiStage, MultiStageOptions, Nmpc, NmpcSettings, PdController,
    PredictionModel, SafetySettings, Supervisor, TorqueLimits, Transparent, VelocityTracking,
};
use crate::control::{AUTO_K1_PER_STIFFNESS, AUTO_K2_PER_STIFFNESS};
use crate::estimate::EstimatorOptions;
use crate::model::{Friction, HumanSegment, Link, RobotModel, Straps};
use crate::sim::{
    actuator_demand, robot_model, ActuatorDemand, GaitTrajectory, HumanLeg, KneeTrajectory,
    PlantParams, SwingTrajectory, Trajectory, Uncertainty,
};
use nalgebra::SVector;

/// One of the paper's two experiment layouts, with `N` joints.
pub trait Dof<const N: usize> {
    /// The desired trajectory type.
    type Traj: Trajectory<N> + Clone;
    /// Number of joints, as reported in summaries.
    const DOF: usize = N;
    /// Bare robot links (hip outwards).
    fn robot_links(s: &Scenario) -> [Link; N];
    /// Human Winter segments.
    fn human_segments(s: &Scenario) -> [HumanSegment; N];
    /// Strap model.
    fn straps(s: &Scenario) -> Straps<N>;
    /// The human's desired trajectory.
    fn trajectory(s: &Scenario) -> Self::Traj;
    /// The builder of controller `c` for this layout (see [`controllers`](super::controllers)).
    fn builder(c: &ControllerInfo) -> Builder<N>;
}

/// The 2-DOF hip-knee experiment (paper §4.1, MODEL.md §6).
#[derive(Clone, Copy, Debug)]
pub struct TwoDof;

/// The 1-DOF knee experiment with the hip locked at 0 (paper §4.1 end, MODEL.md §6).
#[derive(Clone, Copy, Debug)]
pub struct OneDof;

impl Dof<2> for TwoDof {
    type Traj = GaitTrajectory<SwingTrajectory, 2>;
    fn robot_links(s: &Scenario) -> [Link; 2] {
        [s.robot.thigh, s.robot.shank]
    }
    fn human_segments(s: &Scenario) -> [HumanSegment; 2] {
        [s.human.thigh, s.human.shank]
    }
    fn straps(s: &Scenario) -> Straps<2> {
        Straps::two_dof(
            s.straps.ls1_m,
            s.straps.ls2_m,
            s.straps.stiffness,
            s.straps.damping,
        )
    }
    fn trajectory(s: &Scenario) -> GaitTrajectory<SwingTrajectory, 2> {
        s.trajectory.two_dof()
    }
    fn builder(c: &ControllerInfo) -> Builder<2> {
        c.build_2dof
    }
}

impl Dof<1> for OneDof {
    type Traj = GaitTrajectory<KneeTrajectory, 1>;
    fn robot_links(s: &Scenario) -> [Link; 1] {
        [s.robot.shank]
    }
    fn human_segments(s: &Scenario) -> [HumanSegment; 1] {
        [s.human.shank]
    }
    fn straps(s: &Scenario) -> Straps<1> {
        Straps::one_dof(s.straps.ls2_m, s.straps.stiffness, s.straps.damping)
    }
    fn trajectory(s: &Scenario) -> GaitTrajectory<KneeTrajectory, 1> {
        s.trajectory.one_dof()
    }
    fn builder(c: &ControllerInfo) -> Builder<1> {
        c.build_1dof
    }
}

/// The plant's uncertainty settings of a scenario: its `[uncertainty]` table, which is the
/// simulator's own [`Uncertainty`] type.
pub fn uncertainty(s: &Scenario) -> Uncertainty {
    s.uncertainty
}

/// Plant parameters of a scenario for layout `D` (MODEL.md §2-7).
pub fn plant_params<D: Dof<N>, const N: usize>(s: &Scenario) -> PlantParams<N> {
    let duration = s.duration_s(D::DOF);
    let ramp = D::DOF == 2 && s.uncertainty.human_mass_ramp;
    PlantParams {
        robot_links: D::robot_links(s),
        viscous: s.robot.viscous_friction,
        coulomb: s.robot.coulomb_friction,
        payload_kg: s.uncertainty.payload_kg,
        payload_position: s.robot.payload_position_m,
        human: HumanLeg {
            segments: D::human_segments(s),
            height: s.human.height_m,
        },
        body_mass_start: s.human.body_mass_kg,
        body_mass_end: if ramp {
            s.human.final_body_mass_kg
        } else {
            s.human.body_mass_kg
        },
        ramp_duration: duration,
        nominal_body_mass: s.human.body_mass_kg,
        brain_gains: (s.human.kp, s.human.kd),
        straps: D::straps(s),
        uncertainty: s.uncertainty,
        dt: s.timing.dt,
        substeps: s.timing.plant_substeps,
    }
}

/// What the gait of `s` asks of the actuator in layout `D`: [`crate::sim::actuator_demand`]
/// of the desired trajectory on the true robot (payload `uncertainty.payload_kg`, mass
/// perturbation, friction, disturbance) at the run's control instants, against
/// `controller.torque_max`. It depends on the scenario, not on the controller.
pub fn gait_demand<D: Dof<N>, const N: usize>(s: &Scenario) -> ActuatorDemand<N> {
    actuator_demand(
        &plant_params::<D, N>(s),
        &D::trajectory(s),
        s.control_steps(D::DOF),
        s.controller.torque_max,
    )
}

/// The controller's robot model for a payload scenario `payload_kg` (smooth friction).
pub fn scenario_robot<D: Dof<N>, const N: usize>(s: &Scenario, payload_kg: f64) -> RobotModel<N> {
    robot_model(
        &D::robot_links(s),
        s.robot.viscous_friction,
        s.robot.coulomb_friction,
        Friction::Tanh {
            width: s.robot.coulomb_smoothing,
        },
        payload_kg,
        s.robot.payload_position_m,
        0.0,
    )
}

/// The NMPC prediction model of a payload scenario (MODEL.md §8).
pub fn prediction_model<D: Dof<N>, const N: usize>(
    s: &Scenario,
    payload_kg: f64,
) -> PredictionModel<N> {
    PredictionModel {
        robot: scenario_robot::<D, N>(s, payload_kg),
        straps: D::straps(s),
        interaction: s.controller.interaction,
        dt: s.timing.dt,
        substeps: s.timing.prediction_substeps,
    }
}

/// NMPC settings of a scenario.
pub fn nmpc_settings(s: &Scenario) -> NmpcSettings {
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
pub fn multistage_nmpc_settings(s: &Scenario) -> NmpcSettings {
    let mut st = nmpc_settings(s);
    if s.controller.method == Method::Robust {
        st.velocity_tracking = s.controller.robust.velocity_tracking;
    }
    st
}

/// Torque limits of a scenario (paper eqs. 8-9).
pub fn limits(s: &Scenario) -> TorqueLimits {
    TorqueLimits {
        max: s.controller.torque_max,
        rate: s.rate_limit_per_step(),
    }
}

/// Intent-estimate gains of a scenario (paper eqs. 5-6; `"auto"` = `κ / ks`, `control::IntentGain`).
pub fn intent(s: &Scenario) -> IntentEstimator {
    IntentEstimator {
        k1: s.controller.k1.gain(AUTO_K1_PER_STIFFNESS),
        k2: s.controller.k2.gain(AUTO_K2_PER_STIFFNESS),
    }
}

/// Initial previous torque `T_R(−1) = G_R(q(0))` of the nominal robot (MODEL.md §7).
pub fn initial_torque<D: Dof<N>, const N: usize>(s: &Scenario) -> SVector<f64, N> {
    let q0 = D::trajectory(s).eval(0.0).0;
    scenario_robot::<D, N>(s, 0.0).chain.gravity_torque(&q0)
}

/// The controller `kind` for scenario `s`, built by its registry entry
/// ([`controllers`](super::controllers)); [`RunError::Config`] naming `controller.kind` if no
/// controller of that name is registered.
pub fn build_controller<D: Dof<N>, const N: usize>(
    s: &Scenario,
    kind: ControllerKind,
) -> Result<Box<dyn Controller<N>>, RunError> {
    let info = controller_info(kind)?;
    let t0 = initial_torque::<D, N>(s);
    D::builder(info)(s, t0)
}

/// The PD baseline of scenario `s` (`[controller.pd]` gains), previous torque `t0`.
pub fn build_pd<D: Dof<N>, const N: usize>(
    s: &Scenario,
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
    s: &Scenario,
    t0: SVector<f64, N>,
) -> Result<Box<dyn Controller<N>>, RunError> {
    Ok(Box::new(Nmpc::new(
        prediction_model::<D, N>(s, 0.0),
        &nmpc_settings(s),
        intent(s),
        limits(s),
        t0,
    )?))
}

/// The transparent fallback controller of scenario `s` (the supervisor's `fallback` response):
/// the bare robot and the robot with 1 kg at `robot.payload_position_m`, the straps, and the
/// known measurement filter window.
pub fn fallback<D: Dof<N>, const N: usize>(s: &Scenario) -> Transparent<N> {
    Transparent::new(
        scenario_robot::<D, N>(s, 0.0),
        scenario_robot::<D, N>(s, 1.0),
        &D::straps(s),
        s.timing.dt,
        s.uncertainty.filter_window,
        s.monitors.fallback,
    )
}

/// The controller `kind` of scenario `s` wrapped in the safety [`Supervisor`]
/// (plausibility checks and the `[monitors]` of `s`).
pub fn build_supervised<D: Dof<N>, const N: usize>(
    s: &Scenario,
    kind: ControllerKind,
) -> Result<Supervisor<N, Box<dyn Controller<N>>>, RunError> {
    let sup = Supervisor::new(
        build_controller::<D, N>(s, kind)?,
        SafetySettings::from_scenario(s),
    );
    Ok(if s.monitors.response == MonitorResponse::Fallback {
        sup.with_fallback(fallback::<D, N>(s))
    } else {
        sup
    })
}

/// Build the multi-stage controller of scenario `s` for layout `D`.
pub fn build_multistage<D, const N: usize, const NA: usize, const NY: usize>(
    s: &Scenario,
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
        &multistage_nmpc_settings(s),
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
    pub fn from_scenario(s: &Scenario) -> Self {
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
