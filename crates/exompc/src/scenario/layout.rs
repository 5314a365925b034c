//! The paper's two experiment layouts ([`TwoDof`], [`OneDof`] with the hip locked) and what a
//! [`Experiment`] means for them: the plant's parameters, the robot, the trajectory and the
//! prediction models.

use super::info::{Builder, ControllerInfo};
use crate::config::Experiment;
use crate::control::PredictionModel;
use crate::model::{Friction, HumanSegment, Link, RobotModel, Straps};
use crate::sim::{
    actuator_demand, robot_model, ActuatorDemand, GaitTrajectory, HumanLeg, KneeTrajectory,
    PlantParams, SwingTrajectory, Trajectory, Uncertainty,
};

/// One of the paper's two experiment layouts, with `N` joints.
pub trait Dof<const N: usize> {
    /// The desired trajectory type.
    type Traj: Trajectory<N> + Clone;
    /// Number of joints, as reported in summaries.
    const DOF: usize = N;
    /// Bare robot links (hip outwards).
    fn robot_links(s: &Experiment) -> [Link; N];
    /// Human Winter segments.
    fn human_segments(s: &Experiment) -> [HumanSegment; N];
    /// Strap model.
    fn straps(s: &Experiment) -> Straps<N>;
    /// The human's desired trajectory.
    fn trajectory(s: &Experiment) -> Self::Traj;
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
    fn robot_links(s: &Experiment) -> [Link; 2] {
        [s.robot.thigh, s.robot.shank]
    }
    fn human_segments(s: &Experiment) -> [HumanSegment; 2] {
        [s.human.thigh, s.human.shank]
    }
    fn straps(s: &Experiment) -> Straps<2> {
        Straps::two_dof(
            s.straps.ls1_m,
            s.straps.ls2_m,
            s.straps.stiffness,
            s.straps.damping,
        )
    }
    fn trajectory(s: &Experiment) -> GaitTrajectory<SwingTrajectory, 2> {
        s.trajectory.two_dof()
    }
    fn builder(c: &ControllerInfo) -> Builder<2> {
        c.build_2dof
    }
}

impl Dof<1> for OneDof {
    type Traj = GaitTrajectory<KneeTrajectory, 1>;
    fn robot_links(s: &Experiment) -> [Link; 1] {
        [s.robot.shank]
    }
    fn human_segments(s: &Experiment) -> [HumanSegment; 1] {
        [s.human.shank]
    }
    fn straps(s: &Experiment) -> Straps<1> {
        Straps::one_dof(s.straps.ls2_m, s.straps.stiffness, s.straps.damping)
    }
    fn trajectory(s: &Experiment) -> GaitTrajectory<KneeTrajectory, 1> {
        s.trajectory.one_dof()
    }
    fn builder(c: &ControllerInfo) -> Builder<1> {
        c.build_1dof
    }
}

/// The plant's uncertainty settings of a scenario: its `[uncertainty]` table, which is the
/// simulator's own [`Uncertainty`] type.
pub fn uncertainty(s: &Experiment) -> Uncertainty {
    s.uncertainty
}

/// Plant parameters of a scenario for layout `D` (MODEL.md §2-7).
pub fn plant_params<D: Dof<N>, const N: usize>(s: &Experiment) -> PlantParams<N> {
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
pub fn gait_demand<D: Dof<N>, const N: usize>(s: &Experiment) -> ActuatorDemand<N> {
    actuator_demand(
        &plant_params::<D, N>(s),
        &D::trajectory(s),
        s.control_steps(D::DOF),
        s.controller.torque_max,
    )
}

/// The controller's robot model for a payload scenario `payload_kg` (smooth friction).
pub fn scenario_robot<D: Dof<N>, const N: usize>(s: &Experiment, payload_kg: f64) -> RobotModel<N> {
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
    s: &Experiment,
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
