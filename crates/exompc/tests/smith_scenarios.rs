//! `method = "robust"` with scenario sets that differ in their strap model: each scenario's
//! Smith predictor and EKF use that scenario's straps (docs/MODEL.md §8), so the closed loop
//! does not depend on the order in which the scenarios are listed.

use exompc::config::{Experiment, FilterAware, Method};
use exompc::scenario::multistage::{ScenarioSpec, StrapsOverride};
use exompc::scenario::{run_experiment, OneDof, TwoDof};
use exompc::sim::{Recorder, StepRecord};

fn straps(name: &str, o: StrapsOverride) -> ScenarioSpec {
    ScenarioSpec {
        name: name.into(),
        payload_kg: None,
        robot: Default::default(),
        straps: o,
    }
}

/// Robot torques and scenario probabilities of every step.
#[derive(Default)]
struct Log {
    torque: Vec<Vec<f64>>,
    probabilities: Vec<Vec<f64>>,
}

impl<const N: usize> Recorder<N> for Log {
    fn record(&mut self, r: &StepRecord<'_, N>) -> std::io::Result<()> {
        self.torque.push(r.torque_robot.iter().copied().collect());
        self.probabilities
            .push(r.probabilities.expect("msnmpc has scenarios").to_vec());
        Ok(())
    }
}

fn run(s: &Experiment, dof: usize) -> Log {
    s.validate().unwrap();
    let mut log = Log::default();
    if dof == 1 {
        run_experiment::<OneDof, 1>(s, &mut [&mut log]).unwrap();
    } else {
        run_experiment::<TwoDof, 2>(s, &mut [&mut log]).unwrap();
    }
    log
}

/// Largest torque difference (N·m) between the run of `specs` and the run of `specs` reversed,
/// and the largest difference of the correspondingly reversed probabilities.
fn order_difference(specs: Vec<ScenarioSpec>, dof: usize) -> (f64, f64) {
    let mut s = Experiment::default();
    s.controller.method = Method::Robust;
    s.controller.robust.filter_aware = FilterAware::Always;
    s.uncertainty.payload_kg = 1.0;
    s.timing.duration_2dof_s = 3.0;
    s.timing.duration_1dof_s = 3.0;
    s.multistage.scenarios = specs;
    let a = run(&s, dof);
    s.multistage.scenarios.reverse();
    let b = run(&s, dof);
    assert_eq!(a.torque.len(), b.torque.len());
    let mut dt: f64 = 0.0;
    let mut dp: f64 = 0.0;
    for k in 0..a.torque.len() {
        for (x, y) in a.torque[k].iter().zip(&b.torque[k]) {
            dt = dt.max((x - y).abs());
        }
        let pb: Vec<f64> = b.probabilities[k].iter().rev().copied().collect();
        for (x, y) in a.probabilities[k].iter().zip(&pb) {
            dp = dp.max((x - y).abs());
        }
    }
    (dt, dp)
}

#[test]
fn strap_stiffness_scenarios_each_predict_with_their_own_straps() {
    // Listed in either order, the scenarios blend the same predictions: each Smith predictor
    // removes the robot's own force change through its own stiffness and damping. (When every
    // scenario used the first one's straps, the reversed list moved the torques by N·m.)
    let specs = || {
        vec![
            straps(
                "loose",
                StrapsOverride {
                    stiffness: Some(600.0),
                    damping: Some(60.0),
                    ..Default::default()
                },
            ),
            straps("nominal", StrapsOverride::default()),
            straps(
                "tight",
                StrapsOverride {
                    stiffness: Some(1500.0),
                    damping: Some(150.0),
                    ..Default::default()
                },
            ),
        ]
    };
    for dof in [2, 1] {
        let (dt, dp) = order_difference(specs(), dof);
        println!("{dof}-DOF stiffness set: max |ΔT| {dt:e} N·m, max |Δp| {dp:e}");
        assert!(
            dt < 1e-6,
            "{dof}-DOF: torques depend on the order ({dt} N·m)"
        );
        assert!(
            dp < 1e-9,
            "{dof}-DOF: probabilities depend on the order ({dp})"
        );
    }
}

#[test]
fn strap_position_scenarios_each_map_the_force_through_their_own_geometry() {
    // Scenarios whose shank strap sits elsewhere map the same measured force to different knee
    // torques in their EKFs (and predict with their own lever arms).
    let ls2 = |name: &str, l: f64| {
        straps(
            name,
            StrapsOverride {
                ls2_m: Some(l),
                ..Default::default()
            },
        )
    };
    for dof in [2, 1] {
        let (dt, dp) = order_difference(vec![ls2("high", 0.15), ls2("low", 0.3)], dof);
        println!("{dof}-DOF strap position set: max |ΔT| {dt:e} N·m, max |Δp| {dp:e}");
        assert!(
            dt < 1e-6,
            "{dof}-DOF: torques depend on the order ({dt} N·m)"
        );
        assert!(
            dp < 1e-6,
            "{dof}-DOF: probabilities depend on the order ({dp})"
        );
    }
}
