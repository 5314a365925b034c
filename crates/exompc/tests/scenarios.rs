//! Named multi-stage scenarios (`[[multistage.scenarios]]`, docs/MODEL.md §8): resolution of the
//! overrides, the payload shorthand, validation, the indistinguishability warnings and the EKF
//! bank identifying the plant's scenario in closed loop.

use exompc::config::{ControllerKind, Experiment};
use exompc::scenario::multistage::{
    self as ms, Indistinguishable, LinkOverride, RobotOverride, ScenarioSpec, StrapsOverride,
};
use exompc::scenario::{prediction_model, run_experiment, OneDof, TwoDof};
use exompc::sim::{Recorder, StepRecord};

fn spec(name: &str) -> ScenarioSpec {
    ScenarioSpec {
        name: name.into(),
        payload_kg: None,
        robot: RobotOverride::default(),
        straps: StrapsOverride::default(),
    }
}

fn stiffness(name: &str, k: f64) -> ScenarioSpec {
    ScenarioSpec {
        straps: StrapsOverride {
            stiffness: Some(k),
            ..Default::default()
        },
        ..spec(name)
    }
}

fn shank_mass(name: &str, m: f64) -> ScenarioSpec {
    ScenarioSpec {
        robot: RobotOverride {
            shank: LinkOverride {
                mass_kg: Some(m),
                ..Default::default()
            },
            ..Default::default()
        },
        ..spec(name)
    }
}

fn with(specs: Vec<ScenarioSpec>) -> Experiment {
    let mut s = Experiment::default();
    s.multistage.scenarios = specs;
    s
}

#[test]
fn payload_shorthand_names_and_models_are_todays() {
    let s = Experiment::default();
    assert!(!ms::is_named(&s));
    assert_eq!(ms::names(&s), ["0 kg", "1 kg", "2 kg"]);
    assert_eq!(ms::count(&s), 3);
    let models = ms::prediction_models::<TwoDof, 2>(&s);
    for (m, p) in models.iter().zip([0.0, 1.0, 2.0]) {
        assert_eq!(*m, prediction_model::<TwoDof, 2>(&s, p));
    }
    let mut s = Experiment::default();
    s.multistage.payloads_kg = vec![0.5, 1.25];
    assert_eq!(ms::names(&s), ["0.5 kg", "1.25 kg"]);
    assert_eq!(ms::validate(&s), Ok(2));
    // The default payloads are told apart: no warning.
    assert!(ms::warnings(&Experiment::default(), 2).is_empty());
    assert!(ms::warnings(&Experiment::default(), 1).is_empty());
}

#[test]
fn overrides_change_only_what_they_name() {
    let mut heavy = shank_mass("heavy", 2.4);
    heavy.payload_kg = Some(0.5);
    heavy.robot.viscous_friction = Some(0.01);
    let s = with(vec![stiffness("soft", 600.0), heavy]);
    s.validate().unwrap();
    let r = ms::resolve(&s);
    assert_eq!(ms::names(&s), ["soft", "heavy"]);
    assert_eq!(r[0].payload_kg, 0.0);
    assert_eq!(r[0].robot, s.robot);
    let mut straps = s.straps.clone();
    straps.stiffness = 600.0;
    assert_eq!(r[0].straps, straps);
    let mut robot = s.robot.clone();
    robot.shank.mass = 2.4;
    robot.viscous_friction = 0.01;
    assert_eq!(
        (r[1].payload_kg, &r[1].robot, &r[1].straps),
        (0.5, &robot, &s.straps)
    );
    // The models are the base models of the resolved tables.
    let m = ms::prediction_models::<TwoDof, 2>(&s);
    let mut base = s.clone();
    base.straps.stiffness = 600.0;
    assert_eq!(m[0], prediction_model::<TwoDof, 2>(&base, 0.0));
    assert_eq!(m[0].straps.stiffness, 600.0);
    let mut base = s.clone();
    base.robot = robot;
    assert_eq!(m[1], prediction_model::<TwoDof, 2>(&base, 0.5));
    assert_ne!(m[1].robot, m[0].robot);
    assert_eq!(
        ms::differing_keys(&r[0], &r[1]),
        [
            "payload_kg",
            "robot.viscous_friction",
            "robot.shank.mass_kg",
            "straps.stiffness"
        ]
    );
}

fn err_field(s: &Experiment) -> String {
    s.validate().expect_err("invalid").field
}

#[test]
fn validation_names_the_scenario_field() {
    let ok = || with(vec![spec("a"), spec("b"), spec("c")]);
    let mut s = ok();
    s.multistage.scenarios[2].straps.stiffness = Some(-1.0);
    let e = s.validate().unwrap_err();
    assert_eq!(e.field, "multistage.scenarios[2].straps.stiffness");
    assert_eq!(e.allowed, "finite, > 0", "the base table's range");
    let mut s = ok();
    s.multistage.scenarios[1].robot.shank.mass_kg = Some(f64::NAN);
    assert_eq!(err_field(&s), "multistage.scenarios[1].robot.shank.mass_kg");
    let mut s = ok();
    s.multistage.scenarios[0].robot.coulomb_friction = Some(-0.1);
    assert_eq!(
        err_field(&s),
        "multistage.scenarios[0].robot.coulomb_friction"
    );
    // A cross-field rule the override breaks: a shank shorter than the base strap position.
    let mut s = ok();
    s.multistage.scenarios[1].robot.shank.length_m = Some(0.1);
    assert_eq!(err_field(&s), "multistage.scenarios[1].robot.shank.com_m");
    s.multistage.scenarios[1].robot.shank.com_m = Some(0.05);
    assert_eq!(
        err_field(&s),
        "multistage.scenarios[1].robot.payload_position_m"
    );
    s.multistage.scenarios[1].robot.payload_position_m = Some(0.08);
    assert_eq!(err_field(&s), "multistage.scenarios[1].straps.ls2_m");
    let mut s = ok();
    s.multistage.scenarios[2].payload_kg = Some(21.0);
    assert_eq!(err_field(&s), "multistage.scenarios[2].payload_kg");
    for bad in ["", " a", "a,b", "say \"hi\"", "tab\t", &"x".repeat(41)] {
        let mut s = ok();
        s.multistage.scenarios[1].name = bad.into();
        assert_eq!(err_field(&s), "multistage.scenarios[1].name", "{bad:?}");
    }
    let mut s = ok();
    s.multistage.scenarios[2].name = "a".into();
    let e = s.validate().unwrap_err();
    assert_eq!(e.field, "multistage.scenarios[2].name");
    assert!(e.allowed.contains("multistage.scenarios[0]"), "{e}");
    let s = with((0..33).map(|i| spec(&format!("s{i}"))).collect());
    assert_eq!(err_field(&s), "multistage.scenarios");
    let mut s = with((0..32).map(|i| spec(&format!("s{i}"))).collect());
    s.multistage.probability_floor = 1e-3;
    assert_eq!(ms::validate(&s), Ok(32));
    // The floor's range follows the scenario count.
    s.multistage.probability_floor = 0.04;
    assert_eq!(err_field(&s), "multistage.probability_floor");
    let mut s = ok();
    s.multistage.payloads_kg = vec![0.0, 1.0];
    assert_eq!(err_field(&s), "multistage.payloads_kg");
    // Names with spaces and non-ASCII letters are fine.
    let s = with(vec![spec("soft straps"), spec("μ-heavy 2 kg")]);
    s.validate().unwrap();
}

#[test]
fn warns_about_scenarios_the_estimator_cannot_tell_apart() {
    // Strap stiffness does not enter the EKF (the strap force is measured).
    let s = with(vec![stiffness("soft", 600.0), stiffness("stiff", 1500.0)]);
    for dof in [1, 2] {
        let w = ms::warnings(&s, dof);
        assert_eq!(w.len(), 1, "{w:?}");
        assert_eq!(w[0].pair, (0, 1));
        assert_eq!(w[0].reason, Indistinguishable::NotInEstimator);
        assert_eq!(w[0].differing, ["straps.stiffness"]);
        let text = w[0].to_string();
        assert!(
            text.contains("\"soft\"") && text.contains("straps.stiffness"),
            "{text}"
        );
    }
    // Identical after the override.
    let mut b = spec("b");
    b.robot.viscous_friction = Some(s.robot.viscous_friction);
    let w = ms::warnings(&with(vec![spec("a"), b, shank_mass("c", 3.0)]), 2);
    assert_eq!(w.len(), 1, "{w:?}");
    assert_eq!(
        (w[0].pair, &w[0].reason),
        ((0, 1), &Indistinguishable::Identical)
    );
    assert!(w[0].differing.is_empty());
    // The thigh does not exist in the 1-DOF layout.
    let mut t = spec("long thigh");
    t.robot.thigh.mass_kg = Some(4.0);
    let s = with(vec![spec("base"), t]);
    assert!(ms::warnings(&s, 2).is_empty());
    let w = ms::warnings(&s, 1);
    assert_eq!(w.len(), 1);
    assert_eq!(w[0].reason, Indistinguishable::Identical);
    assert_eq!(w[0].differing, ["robot.thigh.mass_kg"]);
    // A payload difference of a gram is below what the bank can resolve; 1 kg is not.
    let mut s = Experiment::default();
    s.multistage.payloads_kg = vec![0.0, 0.001, 1.0];
    let w = ms::warnings(&s, 2);
    assert_eq!(w.len(), 1, "{w:?}");
    assert_eq!(w[0].pair, (0, 1));
    assert!(
        matches!(w[0].reason, Indistinguishable::TooClose { evidence } if evidence < ms::MIN_EVIDENCE),
        "{w:?}"
    );
    assert_eq!(w[0].names, ("0 kg".to_string(), "0.001 kg".to_string()));
    // Shank masses 1.2 / 2.4 / 3.6 kg are told apart in both layouts.
    let s = with(vec![
        shank_mass("light", 1.2),
        shank_mass("heavy", 2.4),
        shank_mass("heavier", 3.6),
    ]);
    assert!(ms::warnings(&s, 2).is_empty());
    assert!(ms::warnings(&s, 1).is_empty());
    // The criterion is a property of the models, not of the run's length.
    let mut short = s.clone();
    short.timing.duration_2dof_s = 0.05;
    assert!(ms::warnings(&short, 2).is_empty());
    // An invalid scenario gives no warnings (validation reports it).
    let mut s = s;
    s.multistage.scenarios[0].robot.shank.mass_kg = Some(-1.0);
    assert!(ms::warnings(&s, 2).is_empty());
    let _ = ms::warnings_for::<OneDof, 1, 3, 2>(&Experiment::default());
}

/// The probabilities of the last step.
#[derive(Default)]
struct LastProbabilities(Vec<f64>);

impl<const N: usize> Recorder<N> for LastProbabilities {
    fn record(&mut self, r: &StepRecord<'_, N>) -> std::io::Result<()> {
        if let Some(p) = r.probabilities {
            self.0 = p.to_vec();
        }
        Ok(())
    }
}

fn closed_loop_final_probabilities(s: &Experiment, dof: usize) -> (Vec<f64>, Vec<String>) {
    let mut last = LastProbabilities::default();
    let summary = if dof == 1 {
        run_experiment::<OneDof, 1>(s, &mut [&mut last]).unwrap()
    } else {
        run_experiment::<TwoDof, 2>(s, &mut [&mut last]).unwrap()
    };
    assert_eq!(summary.limit_violations, 0);
    (
        last.0,
        summary.scenarios.expect("msnmpc names its scenarios"),
    )
}

#[test]
fn the_bank_identifies_the_plants_shank_mass() {
    // The plant's robot has the "heavy" shank; the scenarios bracket it.
    let mut s = with(vec![
        shank_mass("light", 1.2),
        shank_mass("heavy", 2.4),
        shank_mass("heavier", 3.6),
    ]);
    s.robot.shank.mass = 2.4;
    s.controller.kind = ControllerKind::MSNMPC;
    s.timing.duration_2dof_s = 10.0;
    s.timing.duration_1dof_s = 10.0;
    s.validate().unwrap();
    for dof in [2, 1] {
        let (p, names) = closed_loop_final_probabilities(&s, dof);
        assert_eq!(names, ["light", "heavy", "heavier"]);
        println!("{dof}-DOF final probabilities {p:?}");
        assert!(p[1] > p[0] && p[1] > p[2], "{dof}-DOF: {p:?}");
    }
    // The plant with the light shank: the light scenario wins.
    s.robot.shank.mass = 1.2;
    let (p, _) = closed_loop_final_probabilities(&s, 2);
    println!("light plant: final probabilities {p:?}");
    assert!(p[0] > p[1] && p[0] > p[2], "{p:?}");
}

#[test]
fn stiffness_scenarios_keep_equal_probabilities() {
    // The warning's claim, checked in closed loop: the EKF models are identical, so are the
    // probabilities (the NMPC predictions differ).
    let mut s = with(vec![stiffness("soft", 600.0), stiffness("stiff", 1500.0)]);
    s.timing.duration_2dof_s = 3.0;
    let (p, names) = closed_loop_final_probabilities(&s, 2);
    assert_eq!(names, ["soft", "stiff"]);
    assert_eq!(p[0], p[1]);
}
