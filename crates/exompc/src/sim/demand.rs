//! What a gait asks of the actuator: the joint torques the robot needs to move exactly with the
//! human's desired motion, so that the straps carry nothing (paper eq. 1 solved for the torque).
//!
//! A controller can keep the strap forces small only where this demand lies within the torque
//! limit: where it does not, the person must drag the rest of the robot and its payload through
//! the straps whatever the controller does. The demand depends on the gait, the robot and its
//! payload, not on the controller, so an envelope scan can tell the cells beyond the actuator
//! from the cells a controller fails (docs/ROBUSTNESS.md).

use super::plant::PlantParams;
use super::trajectory::Trajectory;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::RobotModel;
use nalgebra::SVector;

/// Paper eq. 1 solved for the robot torque at zero interaction:
/// `τ = M(q) q̈ + C(q, q̇) q̇ + G(q) + kf1 q̇ + kf2 sign(q̇) + D`, with `d` the lumped joint
/// disturbance `D` (the same on every joint, MODEL.md §5).
pub fn required_torque<const N: usize>(
    robot: &RobotModel<N>,
    q: &SVector<f64, N>,
    qd: &SVector<f64, N>,
    qdd: &SVector<f64, N>,
    d: f64,
) -> SVector<f64, N> {
    let chain = &robot.chain;
    chain.mass_matrix(q) * qdd
        + chain.coriolis_matrix(q, qd) * qd
        + chain.gravity_torque(q)
        + robot.friction_torque(qd)
        + SVector::repeat(d)
}

/// The torque a gait needs from the actuator ([`actuator_demand`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActuatorDemand<const N: usize> {
    /// Largest `|τ_j|` over the samples, per joint (N·m).
    pub peak_nm: SVector<f64, N>,
    /// RMS of `τ_j` over the samples, per joint (N·m).
    pub rms_nm: SVector<f64, N>,
    /// Share of the samples at which some joint needs more than `torque_max`, in [0, 1].
    pub beyond_limit_fraction: f64,
    /// The torque limit it was compared with (N·m).
    pub torque_max: f64,
}

impl<const N: usize> ActuatorDemand<N> {
    /// Whether the gait needs more than the limit at some sample.
    pub fn exceeds_limit(&self) -> bool {
        self.beyond_limit_fraction > 0.0
    }
}

/// The demand of `trajectory` on the true robot of `plant` (its payload, mass perturbation,
/// Coulomb `sign` friction and lumped disturbance, MODEL.md §5) at the control instants
/// `t = k·dt`, `k = 0..steps`: [`required_torque`] along the desired motion with its exact
/// derivatives, compared with `torque_max`. No samples give zeros.
pub fn actuator_demand<const N: usize, Tr: Trajectory<N>>(
    plant: &PlantParams<N>,
    trajectory: &Tr,
    steps: usize,
    torque_max: f64,
) -> ActuatorDemand<N> {
    let mut peak = SVector::<f64, N>::zeros();
    let mut sq = SVector::<f64, N>::zeros();
    let mut beyond = 0usize;
    for k in 0..steps {
        let t = k as f64 * plant.dt;
        let (q, qd, qdd) = trajectory.eval(t);
        let tau = required_torque(
            &plant.true_robot(t),
            &q,
            &qd,
            &qdd,
            plant.uncertainty.disturbance(t),
        );
        for j in 0..N {
            peak[j] = peak[j].max(tau[j].abs());
            sq[j] += tau[j] * tau[j];
        }
        if tau.iter().any(|v| v.abs() > torque_max) {
            beyond += 1;
        }
    }
    let n = steps.max(1) as f64;
    ActuatorDemand {
        peak_nm: peak,
        rms_nm: sq.map(|v| (v / n).sqrt()),
        beyond_limit_fraction: beyond as f64 / n,
        torque_max,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Friction, Link};
    use crate::sim::robot_model;

    fn link(mass: f64, length: f64, com: f64, inertia: f64) -> Link {
        Link {
            mass,
            length,
            com,
            inertia,
        }
    }

    #[test]
    fn a_still_pendulum_needs_its_gravity_torque() {
        // One link (mass m, COM c from the joint) held at θ: τ = m g c sin θ, the closed form.
        let (m, c, theta) = (2.5, 0.18, 0.7);
        // The link with viscous / Coulomb friction and a payload of `mp` kg at `d` m.
        let pendulum = |viscous, coulomb, mp, d| {
            robot_model(
                &[link(m, 0.43, c, 0.02)],
                viscous,
                coulomb,
                Friction::Sign,
                mp,
                d,
                0.0,
            )
        };
        let q = SVector::<f64, 1>::new(theta);
        let z = SVector::<f64, 1>::zeros();
        let robot = pendulum(0.0, 0.0, 0.0, 0.2);
        let tau = required_torque(&robot, &q, &z, &z, 0.0);
        let g = robot.chain.gravity;
        assert!((tau[0] - m * g * c * theta.sin()).abs() < 1e-12, "{tau}");
        // A payload of m_p at d adds m_p g d sin θ.
        let tau = required_torque(&pendulum(0.0, 0.0, 3.0, 0.3), &q, &z, &z, 0.0);
        let want = (m * c + 3.0 * 0.3) * g * theta.sin();
        assert!((tau[0] - want).abs() < 1e-12, "{tau} vs {want}");
        // Friction and the lumped disturbance add as in paper eq. 1.
        let qd = SVector::<f64, 1>::new(2.0);
        let tau = required_torque(&pendulum(0.5, 0.2, 0.0, 0.2), &q, &qd, &z, 0.1);
        let want = m * g * c * theta.sin() + 0.5 * 2.0 + 0.2 + 0.1;
        assert!((tau[0] - want).abs() < 1e-12, "{tau} vs {want}");
    }
}
