//! Simulation building blocks against direct oracles: trajectories (MODEL.md §6) against the
//! written-out formulas and finite differences, the moving-average filter (MODEL.md §5) against a
//! direct mean, the plant's energy balance, and the torque-limit projection (paper eqs. 8-9).

mod common;

use common::Rng;
use exompc::config::Experiment;
use exompc::control::TorqueLimits;
use exompc::estimate::MovingAverage;
use exompc::scenario::{plant_params, TwoDof};
use exompc::sim::{KneeTrajectory, Plant, PlantState, SwingTrajectory, Trajectory};
use nalgebra::{SVector, Vector2};
use proptest::prelude::*;
use std::f64::consts::PI;

/// MODEL.md §6 written out.
fn swing_spec(t: f64) -> [f64; 2] {
    let phi =
        2.0 * PI * (0.8 * t + (0.2 * 15.0 / (2.0 * PI)) * (1.0 - (2.0 * PI * t / 15.0).cos()));
    let ah = 0.30 + 0.05 * (2.0 * PI * t / 10.0).sin();
    let ak = 1.00 + 0.15 * (2.0 * PI * t / 7.0).sin();
    [
        0.10 + ah * phi.sin(),
        -ak * (1.0 - (phi - PI / 3.0).cos()) / 2.0,
    ]
}

fn knee_spec(t: f64) -> [f64; 1] {
    [-0.6 * (1.0 - (2.0 * PI * 0.5 * t).cos())]
}

fn check_derivatives<const N: usize, T: Trajectory<N>>(
    name: &str,
    traj: &T,
    spec: impl Fn(f64) -> [f64; N],
    t_end: f64,
) {
    let mut rng = Rng::new(7);
    let mut ts: Vec<f64> = (0..200).map(|_| rng.uniform(0.0, t_end)).collect();
    ts.push(0.0);
    for t in ts {
        let (q, qd, qdd) = traj.eval(t);
        let (h1, h2) = (1e-5, 1e-3);
        let p = spec(t);
        let (p1m, p1p) = (spec(t - h1), spec(t + h1));
        let (p2m, p2p) = (spec(t - h2), spec(t + h2));
        let (p2mm, p2pp) = (spec(t - 2.0 * h2), spec(t + 2.0 * h2));
        for i in 0..N {
            assert!(
                (q[i] - p[i]).abs() < 1e-12,
                "{name} q[{i}]({t}) = {} vs spec {}",
                q[i],
                p[i]
            );
            let fd1 = (p1p[i] - p1m[i]) / (2.0 * h1);
            assert!(
                (qd[i] - fd1).abs() < 1e-7 * (1.0 + fd1.abs()),
                "{name} qd[{i}]({t}) = {} vs FD {fd1}",
                qd[i]
            );
            // Fourth-order central second difference.
            let fd2 = (-p2pp[i] + 16.0 * p2p[i] - 30.0 * p[i] + 16.0 * p2m[i] - p2mm[i])
                / (12.0 * h2 * h2);
            assert!(
                (qdd[i] - fd2).abs() < 1e-5 * (1.0 + fd2.abs()),
                "{name} qdd[{i}]({t}) = {} vs FD {fd2}",
                qdd[i]
            );
        }
    }
}

#[test]
fn trajectories_match_spec_and_finite_differences() {
    check_derivatives("swing", &SwingTrajectory::default(), swing_spec, 20.0);
    check_derivatives("knee", &KneeTrajectory::default(), knee_spec, 30.0);
    // The scenario's trajectory is the one of docs/MODEL.md.
    let s = Experiment::default();
    use exompc::scenario::Dof;
    check_derivatives("scenario swing", &TwoDof::trajectory(&s), swing_spec, 20.0);
}

#[test]
fn moving_average_is_the_mean_of_the_last_samples() {
    let mut rng = Rng::new(3);
    for window in 1..=7 {
        let mut f = MovingAverage::<2>::new(window);
        assert_eq!(f.mean(), Vector2::zeros());
        let mut all: Vec<Vector2<f64>> = Vec::new();
        for _ in 0..40 {
            let x = Vector2::new(rng.uniform(-10.0, 10.0), rng.uniform(-1.0, 1.0));
            all.push(x);
            let got = f.push(x);
            let k = all.len().min(window);
            let direct = all[all.len() - k..].iter().sum::<Vector2<f64>>() / k as f64;
            assert!((got - direct).amax() < 1e-12, "window {window}");
            assert!((f.mean() - direct).amax() < 1e-12);
        }
        f.reset();
        let x = Vector2::new(1.0, 2.0);
        assert_eq!(f.push(x), x, "after reset the mean restarts");
    }
    // Spec default: 5 samples, fewer at start-up.
    let mut f = MovingAverage::<1>::new(Experiment::default().uncertainty.filter_window);
    let out: Vec<f64> = (1..=7)
        .map(|i| f.push(SVector::from([i as f64]))[0])
        .collect();
    assert_eq!(out, vec![1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0]);
}

/// With no uncertainty, no friction, zero robot torque and a brain with zero gains on a static
/// pose (so it exactly cancels the human's own gravity and Coriolis terms: the human stays put),
/// the robot hangs on the straps as a passive system: robot energy plus strap spring energy can
/// only decrease, at the rate `cs |J qd_R|²` of the strap dampers.
#[test]
fn passive_plant_never_gains_energy() {
    #[derive(Clone)]
    struct Still;
    impl Trajectory<2> for Still {
        fn position<T: exompc::model::Real>(&self, _t: T) -> SVector<T, 2> {
            SVector::<T, 2>::new(T::from(0.3), T::from(-0.4))
        }
    }
    let mut s = Experiment::default();
    s.uncertainty.mass_perturbation = false;
    s.uncertainty.disturbance = false;
    s.uncertainty.human_mass_ramp = false;
    s.uncertainty.payload_kg = 0.5;
    s.robot.viscous_friction = 0.0;
    s.robot.coulomb_friction = 0.0;
    let mut p = plant_params::<TwoDof, 2>(&s);
    p.brain_gains = (0.0, 0.0);
    let mut plant = Plant::new(p, Still);
    let energy = |st: &PlantState<2>, plant: &Plant<2, Still>| {
        let robot = plant.true_robot(0.0).chain;
        robot.kinetic_energy(&st.robot.q, &st.robot.qd)
            + robot.potential_energy(&st.robot.q)
            + plant
                .params()
                .straps
                .spring_energy(&(st.human.q - st.robot.q))
    };
    let start = *plant.state();
    let e0 = energy(&start, &plant);
    let mut last = e0;
    let mut moved = 0.0f64;
    for _ in 0..500 {
        plant.step(&Vector2::zeros());
        let st = *plant.state();
        assert!(
            (st.human.q - start.human.q).amax() < 1e-12,
            "the human should stay put"
        );
        moved = moved.max((st.robot.q - start.robot.q).amax());
        let e = energy(&st, &plant);
        assert!(e <= last + 1e-9, "energy grew from {last} to {e}");
        last = e;
    }
    assert!(moved > 1e-3, "the robot should sag on the straps");
    assert!(
        last < e0 - 1e-6,
        "the dampers should dissipate energy: {e0} -> {last}"
    );
}

proptest! {
    /// `TorqueLimits::clamp` returns the admissible torque nearest to the request (per joint),
    /// holds the previous torque for non-finite requests, and always satisfies both limits.
    #[test]
    fn clamp_is_the_nearest_admissible_torque(
        prev in prop::array::uniform2(-30.0..=30.0f64),
        desired in prop::array::uniform2(prop_oneof![
            6 => -60.0..60.0f64,
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(f64::NEG_INFINITY),
            1 => any::<f64>(),
        ]),
    ) {
        let lim = TorqueLimits { max: 30.0, rate: 10.0 };
        let (p, d) = (Vector2::from(prev), Vector2::from(desired));
        let t = lim.clamp(&p, &d);
        prop_assert!(lim.admits(&p, &t));
        for i in 0..2 {
            let lo = (p[i] - 10.0).max(-30.0);
            let hi = (p[i] + 10.0).min(30.0);
            let want = if !d[i].is_finite() {
                p[i]
            } else if d[i] < lo {
                lo
            } else if d[i] > hi {
                hi
            } else {
                d[i]
            };
            prop_assert_eq!(t[i], want);
        }
    }
}

/// A plant step far too long for RK4 makes the run fail with `Diverged`, instead of a summary
/// that looks healthy (NaN forces were once dropped by `f64::max`).
#[test]
fn diverging_plant_is_reported_as_an_error() {
    let mut s = exompc::config::Experiment::default();
    s.timing.dt = 1.0;
    s.timing.plant_substeps = 1;
    match exompc::scenario::run_experiment::<exompc::scenario::TwoDof, 2>(&s, &mut []) {
        Err(exompc::scenario::RunError::Diverged { t }) => assert!(t.is_finite() && t > 0.0),
        other => panic!("expected Diverged, got {other:?}"),
    }
}

/// A run whose step count would be absurd is rejected by validation, naming the duration.
#[test]
fn too_many_control_steps_are_rejected() {
    let mut s = exompc::config::Experiment::default();
    s.timing.dt = 1e-12;
    let e = s.validate().unwrap_err();
    assert!(e.to_string().contains("timing.duration_2dof_s"), "{e}");
}

/// Invalid limits are an error from the constructors, and the clamp never panics on them.
#[test]
fn invalid_torque_limits_are_errors_not_panics() {
    use exompc::control::{Nmpc, TorqueLimits};
    use nalgebra::Vector2;
    let s = exompc::config::Experiment::default();
    let model = exompc::scenario::prediction_model::<exompc::scenario::TwoDof, 2>(&s, 0.0);
    for bad in [
        TorqueLimits {
            max: -1.0,
            rate: 10.0,
        },
        TorqueLimits {
            max: 30.0,
            rate: -1.0,
        },
        TorqueLimits {
            max: f64::NAN,
            rate: 10.0,
        },
    ] {
        let r = Nmpc::new(
            model,
            &exompc::scenario::nmpc_settings(&s),
            exompc::scenario::intent(&s),
            bad,
            Vector2::zeros(),
        );
        // A limits error naming the limit, not a solver-setting error.
        match r {
            Err(exompc::control::NmpcError::Limits(e)) => {
                assert!(["torque_max", "torque_rate"].contains(&e.field), "{e}");
                assert!(e.to_string().contains("invalid torque limit"), "{e}");
            }
            Err(e) => panic!("{bad:?}: expected a limits error, got {e}"),
            Ok(_) => panic!("{bad:?} accepted"),
        }
        let _ = bad.clamp(&Vector2::new(1.0, f64::NAN), &Vector2::new(5.0, 2.0));
        let _ = bad.admissible(&Vector2::new(1.0, f64::NAN));
    }
}

#[test]
fn controller_build_errors_are_typed() {
    use exompc::control::MultiStageError;
    use exompc::estimate::EstimateError;
    use exompc::scenario::{build_controller, RunError, TwoDof};
    let mut s = exompc::config::Experiment::default();
    s.ekf.q_angle = -1.0; // not validated here: build_controller trusts its caller
    match build_controller::<TwoDof, 2>(&s, exompc::config::ControllerKind::MSNMPC) {
        Err(RunError::MultiStage(MultiStageError::Estimator(EstimateError::Settings(e)))) => {
            assert_eq!(e.field, "q_angle")
        }
        Err(e) => panic!("expected an estimator error, got {e}"),
        Ok(_) => panic!("a negative EKF variance was accepted"),
    }
    let mut s = exompc::config::Experiment::default();
    s.controller.torque_max = f64::NAN;
    for kind in [
        exompc::config::ControllerKind::NMPC,
        exompc::config::ControllerKind::MSNMPC,
    ] {
        let e = build_controller::<TwoDof, 2>(&s, kind)
            .err()
            .expect("NaN limit accepted");
        assert!(
            matches!(
                e,
                RunError::Nmpc(exompc::control::NmpcError::Limits(_))
                    | RunError::MultiStage(MultiStageError::Limits(_))
            ),
            "{kind:?}: {e}"
        );
    }
}
