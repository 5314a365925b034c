//! What a gait asks of the actuator (`exompc::sim::actuator_demand`, `sim/demand.rs`): against
//! the forward dynamics, and on plant parameters of the default scenario.

use exompc::model::Chain;
use exompc::sim::{actuator_demand, required_torque, PlantParams, Trajectory, Uncertainty};
use nalgebra::SVector;

/// A constant pose with the given angles.
struct Still<const N: usize>(SVector<f64, N>);
impl<const N: usize> Trajectory<N> for Still<N> {
    fn position<T: exompc::model::Real>(&self, _t: T) -> SVector<T, N> {
        self.0.map(|v| exompc::model::c::<T>(v))
    }
}

/// A two-joint swing `q_j = a_j sin(w_j t + p_j)`.
struct Swing;
impl Trajectory<2> for Swing {
    fn position<T: exompc::model::Real>(&self, t: T) -> SVector<T, 2> {
        let w = 2.0 * std::f64::consts::PI * 1.3;
        SVector::<T, 2>::new((t * w).sin() * 0.4 + 0.1, (t * w + 1.0).sin() * 0.9)
    }
}

fn params_2dof(payload_kg: f64, uncertainty: Uncertainty) -> PlantParams<2> {
    let s = exompc::config::Experiment::default();
    let mut p = exompc::scenario::plant_params::<exompc::scenario::TwoDof, 2>(&s);
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
fn the_forward_dynamics_of_the_required_torque_give_back_the_acceleration() {
    // Independent oracle: the robot's forward dynamics (paper eq. 1 solved for q̈) under
    // τ − D reproduce the trajectory's exact acceleration (dual numbers).
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
