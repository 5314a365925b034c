//! Building and running one experiment of the paper's simulation study from a
//! [`Scenario`](crate::config::Scenario): the 2-DOF swing ([`TwoDof`]) or the 1-DOF knee
//! ([`OneDof`], hip locked) variant.

use super::closed_loop::{run_closed_loop, Recorder, StepRecord};
use super::gait::GaitTrajectory;
use super::human::HumanLeg;
use super::metrics::{Metrics, Summary};
use super::plant::{robot_model, Plant, PlantParams};
use super::trajectory::{KneeTrajectory, SwingTrajectory, Trajectory};
use super::uncertainty::Uncertainty;
use super::Sensors;
use crate::config::{self, ConfigError, ControllerKind, Scenario};
use crate::control::{
    Controller, IntentEstimator, Nmpc, NmpcSettings, PdController, PredictionModel, SafetyReport,
    SafetySettings, Supervisor, TorqueLimits,
};
use crate::model::{Friction, Link, RobotModel, Straps, WinterFractions};
use crate::solver::{SolverError, SqpSettings};
use nalgebra::SVector;
use std::time::Duration;

/// Why an experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The scenario is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The solver settings are invalid.
    #[error("solver settings: {0}")]
    Solver(#[from] SolverError),
    /// A controller could not be built.
    #[error("controller: {0}")]
    Build(String),
    /// The simulated plant diverged (its state stopped being finite) at time `t`.
    #[error(
        "the simulated plant diverged at t = {t} s (its state is no longer finite); \
         a shorter plant step (timing.dt / timing.plant_substeps) keeps RK4 stable"
    )]
    Diverged {
        /// Time (s) of the first non-finite state.
        t: f64,
    },
    /// A recorder failed (e.g. a trace file could not be written).
    #[error("recording failed: {0}")]
    Io(#[from] std::io::Error),
}

fn link(l: &config::RobotLink) -> Link {
    Link {
        length: l.length_m,
        mass: l.mass_kg,
        com: l.com_m,
        inertia: l.inertia_kgm2,
    }
}

fn winter(h: &config::HumanSegment) -> WinterFractions {
    WinterFractions {
        mass: h.mass_fraction,
        length: h.length_fraction,
        com: h.com_fraction,
        gyration: h.gyration_fraction,
    }
}

/// One of the paper's two experiment layouts, with `N` joints.
pub trait Dof<const N: usize> {
    /// The desired trajectory type.
    type Traj: Trajectory<N> + Clone;
    /// Number of joints, as reported in summaries.
    const DOF: usize = N;
    /// Bare robot links (hip outwards).
    fn robot_links(s: &Scenario) -> [Link; N];
    /// Human Winter segments.
    fn human_segments(s: &Scenario) -> [WinterFractions; N];
    /// Strap model.
    fn straps(s: &Scenario) -> Straps<N>;
    /// The human's desired trajectory.
    fn trajectory(s: &Scenario) -> Self::Traj;
    /// Builds the multi-stage controller (needs the EKF's augmented dimensions).
    fn multistage(s: &Scenario, t0: SVector<f64, N>) -> Result<Box<dyn Controller<N>>, RunError>;
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
        [link(&s.robot.thigh), link(&s.robot.shank)]
    }
    fn human_segments(s: &Scenario) -> [WinterFractions; 2] {
        [winter(&s.human.thigh), winter(&s.human.shank)]
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
    fn multistage(s: &Scenario, t0: SVector<f64, 2>) -> Result<Box<dyn Controller<2>>, RunError> {
        crate::control::build_multistage::<Self, 2, 6, 4>(s, t0)
    }
}

impl Dof<1> for OneDof {
    type Traj = GaitTrajectory<KneeTrajectory, 1>;
    fn robot_links(s: &Scenario) -> [Link; 1] {
        [link(&s.robot.shank)]
    }
    fn human_segments(s: &Scenario) -> [WinterFractions; 1] {
        [winter(&s.human.shank)]
    }
    fn straps(s: &Scenario) -> Straps<1> {
        Straps::one_dof(s.straps.ls2_m, s.straps.stiffness, s.straps.damping)
    }
    fn trajectory(s: &Scenario) -> GaitTrajectory<KneeTrajectory, 1> {
        s.trajectory.one_dof()
    }
    fn multistage(s: &Scenario, t0: SVector<f64, 1>) -> Result<Box<dyn Controller<1>>, RunError> {
        crate::control::build_multistage::<Self, 1, 3, 2>(s, t0)
    }
}

/// The plant's uncertainty settings of a scenario.
pub fn uncertainty(s: &Scenario) -> Uncertainty {
    let u = &s.uncertainty;
    Uncertainty {
        mass_perturbation: u.mass_perturbation,
        disturbance: u.disturbance,
        velocity_noise: u.velocity_noise,
        force_noise: u.force_noise,
        noise_frequency: u.noise_frequency,
    }
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
        uncertainty: uncertainty(s),
        dt: s.timing.dt,
        substeps: s.timing.plant_substeps,
    }
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
        sqp: SqpSettings {
            max_iterations: c.sqp.max_iterations,
            kkt_tolerance: c.sqp.kkt_tolerance,
            max_time: c.sqp.max_time_us.map(Duration::from_micros),
            hessian: c.sqp.hessian,
            ..SqpSettings::default()
        },
        qp: c.sqp.qp,
    }
}

/// Torque limits of a scenario (paper eqs. 8-9).
pub fn limits(s: &Scenario) -> TorqueLimits {
    TorqueLimits {
        max: s.controller.torque_max,
        rate: s.rate_limit_per_step(),
    }
}

/// Intent-estimate gains of a scenario (paper eqs. 5-6).
pub fn intent(s: &Scenario) -> IntentEstimator {
    IntentEstimator {
        k1: s.controller.k1,
        k2: s.controller.k2,
    }
}

/// Initial previous torque `T_R(−1) = G_R(q(0))` of the nominal robot (MODEL.md §7).
pub fn initial_torque<D: Dof<N>, const N: usize>(s: &Scenario) -> SVector<f64, N> {
    let q0 = D::trajectory(s).eval(0.0).0;
    scenario_robot::<D, N>(s, 0.0).chain.gravity_torque(&q0)
}

/// The controller `kind` for scenario `s`.
pub fn build_controller<D: Dof<N>, const N: usize>(
    s: &Scenario,
    kind: ControllerKind,
) -> Result<Box<dyn Controller<N>>, RunError> {
    let t0 = initial_torque::<D, N>(s);
    Ok(match kind {
        ControllerKind::Pd => Box::new(PdController::new(
            scenario_robot::<D, N>(s, 0.0),
            intent(s),
            limits(s),
            s.controller.pd.kp,
            s.controller.pd.kd,
            t0,
        )),
        ControllerKind::Nmpc => Box::new(Nmpc::new(
            prediction_model::<D, N>(s, 0.0),
            &nmpc_settings(s),
            intent(s),
            limits(s),
            t0,
        )?),
        ControllerKind::Msnmpc => D::multistage(s, t0)?,
    })
}

/// The controller `kind` of scenario `s` wrapped in the safety [`Supervisor`]
/// (plausibility checks and the `[monitors]` of `s`).
pub fn build_supervised<D: Dof<N>, const N: usize>(
    s: &Scenario,
    kind: ControllerKind,
) -> Result<Supervisor<N, Box<dyn Controller<N>>>, RunError> {
    Ok(Supervisor::new(
        build_controller::<D, N>(s, kind)?,
        SafetySettings::from_scenario(s),
    ))
}

/// Run the closed loop of scenario `s` with controller `s.controller.kind` in layout `D` for
/// `s.duration_s(D::DOF)`, feeding every step to `recorders`; returns the summary (paper
/// Table 2 metrics). The sensors inject the `[faults]` of `s`; the controller runs under the
/// safety [`Supervisor`] (see [`run_experiment_report`] for its event log).
pub fn run_experiment<D: Dof<N>, const N: usize>(
    s: &Scenario,
    recorders: &mut [&mut dyn Recorder<N>],
) -> Result<Summary, RunError> {
    run_experiment_report::<D, N>(s, recorders).map(|(summary, _)| summary)
}

/// Stops a run whose plant state stops being finite (e.g. a plant step too long for RK4).
struct DivergenceGuard {
    diverged_at: Option<f64>,
}

impl<const N: usize> Recorder<N> for DivergenceGuard {
    fn record(&mut self, r: &StepRecord<'_, N>) -> std::io::Result<()> {
        let finite = |v: &SVector<f64, N>| v.iter().all(|x| x.is_finite());
        if finite(&r.robot.q) && finite(&r.robot.qd) && finite(&r.human.q) && finite(&r.human.qd) {
            Ok(())
        } else {
            self.diverged_at = Some(r.t);
            Err(std::io::Error::other("plant state is not finite"))
        }
    }
}

/// Step-time samples preallocated at most (longer runs grow the buffer as they go, instead
/// of aborting on a huge up-front allocation).
const MAX_PREALLOCATED_STEPS: usize = 1 << 22;

/// [`run_experiment`], also returning the safety supervisor's counters and monitor events.
pub fn run_experiment_report<D: Dof<N>, const N: usize>(
    s: &Scenario,
    recorders: &mut [&mut dyn Recorder<N>],
) -> Result<(Summary, SafetyReport), RunError> {
    s.validate()?;
    s.check_trajectory(D::DOF)?;
    let mut controller = build_supervised::<D, N>(s, s.controller.kind)?;
    let mut plant = Plant::new(plant_params::<D, N>(s), D::trajectory(s));
    let mut sensors =
        Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults);
    let steps = s.control_steps(D::DOF);
    let mut metrics = Metrics::with_capacity(steps.min(MAX_PREALLOCATED_STEPS));
    let mut guard = DivergenceGuard { diverged_at: None };
    {
        let mut all: Vec<&mut dyn Recorder<N>> = Vec::with_capacity(recorders.len() + 2);
        all.push(&mut guard);
        all.push(&mut metrics);
        for r in recorders.iter_mut() {
            all.push(&mut **r);
        }
        let result = run_closed_loop(
            &mut plant,
            &mut sensors,
            &mut controller,
            &limits(s),
            steps,
            &mut all,
        );
        if let Some(t) = guard.diverged_at {
            return Err(RunError::Diverged { t });
        }
        result?;
    }
    let mut summary = metrics.summary(
        controller.name(),
        D::DOF,
        s.uncertainty.payload_kg,
        s.timing.dt,
    );
    summary.safety = super::SafetySummary::from_report(controller.report());
    Ok((summary, controller.report().clone()))
}
