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
    use crate::model::{Chain, Friction, Link};
    use crate::sim::{robot_model, Uncertainty};

    fn link(mass: f64, length: f64, com: f64, inertia: f64) -> Link {
        Link {
            mass,
            length,
            com,
            inertia,
        }
    }

    /// A constant pose with the given angles.
    struct Still<const N: usize>(SVector<f64, N>);
    impl<const N: usize> Trajectory<N> for Still<N> {
        fn position<T: crate::model::Real>(&self, _t: T) -> SVector<T, N> {
            self.0.map(|v| crate::model::c::<T>(v))
        }
    }

    /// A two-joint swing `q_j = a_j sin(w_j t + p_j)`.
    struct Swing;
    impl Trajectory<2> for Swing {
        fn position<T: crate::model::Real>(&self, t: T) -> SVector<T, 2> {
            let w = 2.0 * std::f64::consts::PI * 1.3;
            SVector::<T, 2>::new((t * w).sin() * 0.4 + 0.1, (t * w + 1.0).sin() * 0.9)
        }
    }

    fn params_2dof(payload_kg: f64, uncertainty: Uncertainty) -> PlantParams<2> {
        let s = crate::config::Scenario::default();
        let mut p = crate::scenario::plant_params::<crate::scenario::TwoDof, 2>(&s);
        p.payload_kg = payload_kg;
        p.uncertainty = uncertainty;
        p
    }

    fn still_uncertainty() -> Uncertainty {
        Uncertainty {
            mass_perturbation: false,
            disturbance: false,
            ..Uncertainty::default()
        }
    }

    #[test]
    fn a_still_pendulum_needs_its_gravity_torque() {
        // One link (mass m, COM c from the joint) held at θ: τ = m g c sin θ, the closed form.
        let (m, c, theta) = (2.5, 0.18, 0.7);
        let robot = robot_model(
            &[link(m, 0.43, c, 0.02)],
            0.0,
            0.0,
            Friction::Sign,
            0.0,
            0.2,
            0.0,
        );
        let q = SVector::<f64, 1>::new(theta);
        let z = SVector::<f64, 1>::zeros();
        let tau = required_torque(&robot, &q, &z, &z, 0.0);
        let g = robot.chain.gravity;
        assert!((tau[0] - m * g * c * theta.sin()).abs() < 1e-12, "{tau}");
        // A payload of m_p at d adds m_p g d sin θ.
        let robot = robot_model(
            &[link(m, 0.43, c, 0.02)],
            0.0,
            0.0,
            Friction::Sign,
            3.0,
            0.3,
            0.0,
        );
        let tau = required_torque(&robot, &q, &z, &z, 0.0);
        let want = (m * c + 3.0 * 0.3) * g * theta.sin();
        assert!((tau[0] - want).abs() < 1e-12, "{tau} vs {want}");
    }

    #[test]
    fn the_forward_dynamics_of_the_required_torque_give_back_the_acceleration() {
        // Independent oracle: the robot's forward dynamics (paper eq. 1 solved for q̈ by a
        // Cholesky solve of M) under τ − D reproduce the trajectory's exact acceleration.
        let p = params_2dof(3.0, Uncertainty::default());
        for k in 0..200 {
            let t = 0.013 * k as f64;
            let (q, qd, qdd) = Swing.eval(t);
            let robot = p.true_robot(t);
            let d = p.uncertainty.disturbance(t);
            let tau = required_torque(&robot, &q, &qd, &qdd, d);
            let back = robot.acceleration(&q, &qd, &(tau - SVector::repeat(d)));
            assert!(
                (back - qdd).norm() < 1e-9 * (1.0 + qdd.norm()),
                "t {t}: {back} vs {qdd}"
            );
        }
    }

    #[test]
    fn the_demand_reports_peaks_rms_and_the_share_beyond_the_limit() {
        // Still at q = (θ, 0): the demand is the constant gravity torque, so peak = RMS, and
        // the share beyond a limit is all or nothing on either side of it.
        let p = params_2dof(0.0, still_uncertainty());
        let pose = Still(SVector::<f64, 2>::new(0.5, 0.0));
        let g = required_torque(
            &p.true_robot(0.0),
            &pose.0,
            &SVector::zeros(),
            &SVector::zeros(),
            0.0,
        );
        let d = actuator_demand(&p, &pose, 50, g[0].abs() + 1e-9);
        assert!((d.peak_nm - g.abs()).norm() < 1e-12);
        assert!((d.rms_nm - g.abs()).norm() < 1e-12);
        assert_eq!(d.beyond_limit_fraction, 0.0);
        assert!(!d.exceeds_limit());
        let d = actuator_demand(&p, &pose, 50, g[0].abs() - 1e-9);
        assert_eq!(d.beyond_limit_fraction, 1.0);
        assert!(d.exceeds_limit());
        // Chain check: the 2-link gravity torque at (θ, 0) is Σ m_k c̄_k g sin θ about the hip.
        let ch: &Chain<2> = &p.true_robot(0.0).chain;
        assert!(g[0] > g[1] && g[1] > 0.0, "{g} ({ch:?})");
        assert_eq!(
            actuator_demand(&p, &pose, 0, 1.0).beyond_limit_fraction,
            0.0
        );
    }

    #[test]
    fn a_payload_raises_the_demand_of_a_swing() {
        let light = actuator_demand(&params_2dof(0.0, Uncertainty::default()), &Swing, 300, 30.0);
        let heavy = actuator_demand(&params_2dof(3.0, Uncertainty::default()), &Swing, 300, 30.0);
        for j in 0..2 {
            assert!(heavy.peak_nm[j] > light.peak_nm[j], "{j}");
            assert!(heavy.rms_nm[j] > light.rms_nm[j], "{j}");
        }
        assert!(heavy.beyond_limit_fraction >= light.beyond_limit_fraction);
    }
}
