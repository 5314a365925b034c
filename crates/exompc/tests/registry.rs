//! The controller registry (`exompc::scenario::controllers`): one entry per controller, names
//! that are the config's `controller.kind` spelling, builders that build what they name, and a
//! controller registered by this test alone that the config, the builders and the experiment
//! runner accept like the built-in ones.

use exompc::config::{ControllerKind, Experiment};
use exompc::control::{ControlOutput, Controller, Measurement, StepStatus, TorqueLimits};
use exompc::model::RobotModel;
use exompc::scenario::{
    build_controller, build_supervised, controller_by_name, controller_info, controllers,
    initial_torque, limits, register_controller, run_experiment, scenario_robot, validate,
    ControllerInfo, Dof, OneDof, RunError, TwoDof, BUILTIN,
};
use exompc::sim::Trajectory as _;
use nalgebra::SVector;
use serde::de::value::{Error, StrDeserializer};
use serde::Deserialize;

#[test]
fn builtin_entries_are_distinct_and_named_as_in_config_files() {
    assert_eq!(
        BUILTIN.iter().map(|c| c.name()).collect::<Vec<_>>(),
        ["msnmpc", "nmpc", "pd"]
    );
    assert_eq!(
        [
            ControllerKind::MSNMPC,
            ControllerKind::NMPC,
            ControllerKind::PD
        ],
        [BUILTIN[0].kind, BUILTIN[1].kind, BUILTIN[2].kind]
    );
    for (i, c) in BUILTIN.iter().enumerate() {
        // The registry name is the config file's spelling of the kind, and serializes back.
        let parsed = ControllerKind::deserialize(StrDeserializer::<Error>::new(c.name())).unwrap();
        assert_eq!(parsed, c.kind, "{}", c.name());
        assert_eq!(parsed.to_string(), c.name());
        assert_eq!(controller_by_name(c.name()).map(|d| d.kind), Some(c.kind));
        assert_eq!(controller_info(c.kind).unwrap().kind, c.kind);
        for d in &BUILTIN[..i] {
            assert!(d.kind != c.kind && d.label != c.label && d.colour != c.colour);
        }
        assert!(!c.description.is_empty());
    }
    assert_eq!(
        BUILTIN.iter().filter(|c| c.multistage).count(),
        1,
        "msnmpc only"
    );
    assert!(BUILTIN[0].multistage);
    assert!(controller_by_name("lqr").is_none());
}

#[test]
fn names_are_checked_for_form_then_against_the_registry() {
    for bad in ["", "MSNMPC", "ms nmpc", "1pd", "a,b", &"x".repeat(32)] {
        let e = ControllerKind::new(bad).unwrap_err();
        assert_eq!(e.field, "controller.kind", "{bad:?}");
        assert!(ControllerKind::deserialize(StrDeserializer::<Error>::new(bad)).is_err());
    }
    assert!(ControllerKind::new(&"x".repeat(31)).is_ok());
    // Well-formed but not registered: the scenario check and the builders name the field and
    // list the registered controllers.
    let mut s = Experiment::default();
    s.controller.kind = ControllerKind::new("lqr").unwrap();
    s.validate().unwrap(); // the config layer checks the form only
    let registered = controllers(); // before the check: another test may register one more
    let e = validate(&s).unwrap_err();
    assert_eq!(e.field, "controller.kind");
    for c in registered {
        assert!(e.allowed.contains(&format!("\"{}\"", c.name())), "{e}");
    }
    match build_controller::<TwoDof, 2>(&s, s.controller.kind) {
        Err(RunError::Config(e)) => assert_eq!(e.field, "controller.kind"),
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("built an unregistered controller"),
    }
    assert!(matches!(
        run_experiment::<OneDof, 1>(&s, &mut []),
        Err(RunError::Config(_))
    ));
}

#[test]
fn builders_build_the_controller_they_name() {
    let s = Experiment::default();
    for c in BUILTIN {
        let two = (c.build_2dof)(&s, initial_torque::<TwoDof, 2>(&s)).unwrap();
        let one = (c.build_1dof)(&s, initial_torque::<OneDof, 1>(&s)).unwrap();
        assert_eq!(two.name(), c.name());
        assert_eq!(one.name(), c.name());
        assert_eq!(two.probabilities().is_some(), c.multistage, "{}", c.name());
        assert_eq!(
            build_controller::<TwoDof, 2>(&s, c.kind).unwrap().name(),
            c.name()
        );
    }
}

/// A controller that exists only in this test: gravity compensation of the nominal robot,
/// within the torque limits.
struct GravityComp<const N: usize> {
    robot: RobotModel<N>,
    limits: TorqueLimits,
    prev: SVector<f64, N>,
}

impl<const N: usize> Controller<N> for GravityComp<N> {
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N> {
        let g = self.robot.chain.gravity_torque(&m.q);
        self.prev = self.limits.clamp(&self.prev, &g);
        ControlOutput {
            torque: self.prev,
            status: StepStatus::Ok,
            iterations: 0,
        }
    }
    fn name(&self) -> &'static str {
        GRAVITY.name()
    }
    fn previous_torque(&self) -> SVector<f64, N> {
        self.prev
    }
    fn set_previous_torque(&mut self, t: SVector<f64, N>) {
        self.prev = self.limits.admissible(&t);
    }
}

fn build_gravity<D: Dof<N>, const N: usize>(
    s: &Experiment,
    t0: SVector<f64, N>,
) -> Result<Box<dyn Controller<N>>, RunError> {
    Ok(Box::new(GravityComp {
        robot: scenario_robot::<D, N>(s, 0.0),
        limits: limits(s),
        prev: t0,
    }))
}

/// The one registry entry that adds the test's controller.
static GRAVITY: ControllerInfo = ControllerInfo {
    kind: ControllerKind::from_static("gravity-comp"),
    label: "gravity compensation",
    description: "gravity compensation of the nominal robot (test only)",
    colour: 3,
    multistage: false,
    build_2dof: build_gravity::<TwoDof, 2>,
    build_1dof: build_gravity::<OneDof, 1>,
};

#[test]
fn a_controller_registered_here_runs_like_the_built_in_ones() {
    // Registered once per test process (the other tests of this file do not depend on it).
    let _ = register_controller(&GRAVITY);
    assert!(
        register_controller(&GRAVITY).is_err(),
        "a name is registered once"
    );
    assert!(register_controller(&BUILTIN[1]).is_err());
    assert_eq!(controllers().last().map(|c| c.name()), Some("gravity-comp"));
    assert_eq!(controllers().len(), BUILTIN.len() + 1);

    // The config's spelling, checked by the scenario layer.
    let kind = ControllerKind::deserialize(StrDeserializer::<Error>::new("gravity-comp")).unwrap();
    let mut s = Experiment::default();
    s.controller.kind = kind;
    s.timing.duration_2dof_s = 2.0;
    s.timing.duration_1dof_s = 2.0;
    validate(&s).unwrap();
    assert_eq!(controller_info(kind).unwrap().label, "gravity compensation");

    // Built by the generic builders, supervised or not, and run as an experiment.
    let mut c = build_controller::<TwoDof, 2>(&s, kind).unwrap();
    assert_eq!(c.name(), "gravity-comp");
    let q0 = TwoDof::trajectory(&s).eval(0.0).0;
    let out = c.step(&Measurement {
        t: 0.0,
        q: q0,
        qd: SVector::zeros(),
        force: SVector::zeros(),
    });
    // The first torque is the gravity torque at the start, which is T_R(−1) itself.
    assert!((out.torque - initial_torque::<TwoDof, 2>(&s)).norm() < 1e-12);
    assert_eq!(
        build_supervised::<OneDof, 1>(&s, kind).unwrap().name(),
        "gravity-comp"
    );
    let two = run_experiment::<TwoDof, 2>(&s, &mut []).unwrap();
    let one = run_experiment::<OneDof, 1>(&s, &mut []).unwrap();
    for summary in [&two, &one] {
        assert_eq!(summary.controller, "gravity-comp");
        assert_eq!(summary.limit_violations, 0);
        assert!(summary.scenarios.is_none() && summary.mean_probability.is_none());
        assert!(summary.rms_force_n.shank.is_some_and(f64::is_finite));
    }
}
