//! The coupled human-robot plant (paper eqs. 1-4) under the uncertainties of MODEL.md §5,
//! integrated by RK4 substeps under a zero-order hold of the robot torque (MODEL.md §7).

use super::human::{HumanBrain, HumanLeg};
use super::trajectory::Trajectory;
use super::uncertainty::Uncertainty;
use crate::model::{rk4_step, Friction, JointState, Link, RkState, RobotModel, Straps};
use nalgebra::SVector;

/// Everything that defines the plant of one experiment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlantParams<const N: usize> {
    /// Bare robot links from the hip outwards (1-DOF: the shank only).
    pub robot_links: [Link; N],
    /// Viscous friction `kf1` (N·m·s).
    pub viscous: f64,
    /// Coulomb friction `kf2` (N·m), applied as `kf2 sign(qd)`.
    pub coulomb: f64,
    /// True payload `m_p` (kg) on the last link, unknown to the controller.
    pub payload_kg: f64,
    /// Payload distance from the last joint (m), default 0.215.
    pub payload_position: f64,
    /// The human leg.
    pub human: HumanLeg<N>,
    /// Plant body mass at `t = 0` (kg).
    pub body_mass_start: f64,
    /// Plant body mass at `t = ramp_duration` (kg); linear in between.
    pub body_mass_end: f64,
    /// Duration of the body-mass ramp (s), the run length.
    pub ramp_duration: f64,
    /// The brain's nominal body mass (kg).
    pub nominal_body_mass: f64,
    /// Brain PD gains `(Kp, Kd)`.
    pub brain_gains: (f64, f64),
    /// Straps.
    pub straps: Straps<N>,
    /// Uncertainties and noise.
    pub uncertainty: Uncertainty,
    /// Control period (s).
    pub dt: f64,
    /// RK4 substeps per control period.
    pub substeps: usize,
}

impl<const N: usize> PlantParams<N> {
    /// The true robot at time `t`: `m_dis(t)` on each bare link, then the payload merged into
    /// the last link (MODEL.md §8a), Coulomb `sign` friction.
    pub fn true_robot(&self, t: f64) -> RobotModel<N> {
        robot_model(
            &self.robot_links,
            self.viscous,
            self.coulomb,
            Friction::Sign,
            self.payload_kg,
            self.payload_position,
            self.uncertainty.mass_perturbation(t),
        )
    }
}

/// Robot and human joint states together.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlantState<const N: usize> {
    /// Robot `(q_R, qd_R)`.
    pub robot: JointState<f64, N>,
    /// Human `(q_H, qd_H)`.
    pub human: JointState<f64, N>,
}

impl<const N: usize> RkState for PlantState<N> {
    #[inline(always)]
    fn add_scaled(&self, h: f64, d: &Self) -> Self {
        PlantState {
            robot: self.robot.add_scaled(h, &d.robot),
            human: self.human.add_scaled(h, &d.human),
        }
    }
}

/// The simulated human-robot system.
#[derive(Clone, Debug)]
pub struct Plant<const N: usize, Tr: Trajectory<N>> {
    params: PlantParams<N>,
    trajectory: Tr,
    brain: HumanBrain<N>,
    state: PlantState<N>,
    t: f64,
    k: u64,
}

impl<const N: usize, Tr: Trajectory<N>> Plant<N, Tr> {
    /// A plant with human and robot at rest on the desired trajectory's start (MODEL.md §7).
    pub fn new(params: PlantParams<N>, trajectory: Tr) -> Self {
        let (q0, qd0, _) = trajectory.eval(0.0);
        let js = JointState { q: q0, qd: qd0 };
        let brain = HumanBrain {
            nominal: params.human.chain(params.nominal_body_mass),
            kp: params.brain_gains.0,
            kd: params.brain_gains.1,
        };
        Plant {
            params,
            trajectory,
            brain,
            state: PlantState {
                robot: js,
                human: js,
            },
            t: 0.0,
            k: 0,
        }
    }

    /// Parameters.
    pub fn params(&self) -> &PlantParams<N> {
        &self.params
    }

    /// Current time (s).
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Current state.
    pub fn state(&self) -> &PlantState<N> {
        &self.state
    }

    /// The desired trajectory.
    pub fn trajectory(&self) -> &Tr {
        &self.trajectory
    }

    /// The nominal robot (no payload, no perturbation) with smooth friction: what a controller
    /// may know (MODEL.md §8).
    pub fn nominal_robot(&self, coulomb_width: f64) -> RobotModel<N> {
        robot_model(
            &self.params.robot_links,
            self.params.viscous,
            self.params.coulomb,
            Friction::Tanh {
                width: coulomb_width,
            },
            0.0,
            self.params.payload_position,
            0.0,
        )
    }

    /// The true robot at time `t`: `m_dis(t)` on each bare link, then the payload merged into
    /// the last link (MODEL.md §8a), Coulomb `sign` friction.
    pub fn true_robot(&self, t: f64) -> RobotModel<N> {
        self.params.true_robot(t)
    }

    /// Plant body mass at `t` (kg).
    pub fn body_mass(&self, t: f64) -> f64 {
        let p = &self.params;
        let s = if p.ramp_duration > 0.0 {
            (t / p.ramp_duration).clamp(0.0, 1.0)
        } else {
            0.0
        };
        p.body_mass_start + (p.body_mass_end - p.body_mass_start) * s
    }

    /// True strap forces `F` (N) in the current state (paper eqs. 3-4).
    pub fn strap_force(&self) -> SVector<f64, N> {
        let s = &self.state;
        self.params
            .straps
            .force(&(s.human.q - s.robot.q), &(s.human.qd - s.robot.qd))
    }

    /// Human joint torque `T_H` at the current state and time.
    pub fn human_torque(&self) -> SVector<f64, N> {
        let t_int = self.params.straps.torque(&self.strap_force());
        self.brain.torque(
            &self.trajectory.eval(self.t),
            &self.state.human.q,
            &self.state.human.qd,
            &t_int,
        )
    }

    /// Time derivative of the coupled state under robot torque `tau_r` (paper eqs. 1-4).
    fn derivative(&self, t: f64, x: &PlantState<N>, tau_r: &SVector<f64, N>) -> PlantState<N> {
        let p = &self.params;
        let f = p
            .straps
            .force(&(x.human.q - x.robot.q), &(x.human.qd - x.robot.qd));
        let t_int = p.straps.torque(&f);
        let d = SVector::<f64, N>::repeat(p.uncertainty.disturbance(t));
        let robot = self.true_robot(t);
        let qdd_r = robot.acceleration(&x.robot.q, &x.robot.qd, &(tau_r + t_int - d));
        let desired = self.trajectory.eval(t);
        let t_h = self.brain.torque(&desired, &x.human.q, &x.human.qd, &t_int);
        let human = p.human.chain(self.body_mass(t));
        let qdd_h = human.forward_dynamics(&x.human.q, &x.human.qd, &(t_h - t_int));
        PlantState {
            robot: JointState {
                q: x.robot.qd,
                qd: qdd_r,
            },
            human: JointState {
                q: x.human.qd,
                qd: qdd_h,
            },
        }
    }

    /// Advance one control period with `tau_r` held (zero-order hold), in RK4 substeps.
    pub fn step(&mut self, tau_r: &SVector<f64, N>) {
        let n = self.params.substeps.max(1);
        let h = self.params.dt / n as f64;
        let t0 = self.k as f64 * self.params.dt;
        let mut x = self.state;
        for i in 0..n {
            let ti = t0 + i as f64 * h;
            x = rk4_step(
                |t, s: &PlantState<N>| self.derivative(t, s, tau_r),
                ti,
                &x,
                h,
            );
        }
        self.state = x;
        self.k += 1;
        self.t = self.k as f64 * self.params.dt;
    }
}

/// A robot model from bare links, friction, payload and mass perturbation (MODEL.md §3, §5, §8a).
pub fn robot_model<const N: usize>(
    links: &[Link; N],
    viscous: f64,
    coulomb: f64,
    friction: Friction,
    payload_kg: f64,
    payload_position: f64,
    mass_perturbation: f64,
) -> RobotModel<N> {
    let mut l: [Link; N] = core::array::from_fn(|i| links[i].with_mass_added(mass_perturbation));
    l[N - 1] = l[N - 1].with_point_mass(payload_kg, payload_position);
    RobotModel {
        chain: crate::model::Chain::new(l),
        viscous,
        coulomb,
        friction,
    }
}
