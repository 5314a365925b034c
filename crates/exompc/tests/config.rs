//! Tests of `exompc::config`: the defaults of docs/MODEL.md, validation rules and helpers.

use exompc::config::*;

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn default_validates() {
    Experiment::default()
        .validate()
        .expect("default scenario must validate");
}

#[test]
fn default_matches_spec_values() {
    let s = Experiment::default();
    // MODEL.md §2
    assert_eq!(s.human.height_m, 1.75);
    assert_eq!(s.human.body_mass_kg, 60.0);
    assert_eq!(s.human.final_body_mass_kg, 85.0);
    assert_eq!((s.human.kp, s.human.kd), (400.0, 40.0));
    assert_eq!(s.human.thigh.mass_fraction, 0.100);
    assert_eq!(s.human.shank.com_fraction, 0.606);
    assert_eq!(s.human.shank.gyration_fraction, 0.416);
    // MODEL.md §3
    assert_eq!(s.robot.viscous_friction, 0.000899);
    assert_eq!(s.robot.coulomb_friction, 0.05048);
    assert_eq!(s.robot.coulomb_smoothing, 0.01);
    assert_eq!(s.robot.payload_position_m, 0.215);
    assert_eq!(
        s.robot.thigh,
        Link {
            length: 0.43,
            mass: 2.0,
            com: 0.20,
            inertia: 0.035
        }
    );
    assert_eq!(
        s.robot.shank,
        Link {
            length: 0.43,
            mass: 1.2,
            com: 0.18,
            inertia: 0.018
        }
    );
    // MODEL.md §4
    assert_eq!((s.straps.ls1_m, s.straps.ls2_m), (0.28, 0.16));
    assert_eq!((s.straps.stiffness, s.straps.damping), (937.5, 93.7));
    // MODEL.md §5
    assert_eq!(s.uncertainty.payload_kg, 0.0);
    assert!(
        s.uncertainty.mass_perturbation
            && s.uncertainty.disturbance
            && s.uncertainty.human_mass_ramp
    );
    assert_eq!(
        (s.uncertainty.velocity_noise, s.uncertainty.force_noise),
        (1e-4, 1e-3)
    );
    assert_eq!(s.uncertainty.noise_frequency, 100.0);
    assert_eq!(s.uncertainty.filter_window, 5);
    // MODEL.md §6
    let t = &s.trajectory.swing;
    assert_eq!(
        (
            t.base_frequency_hz,
            t.frequency_swing_hz,
            t.frequency_period_s
        ),
        (0.8, 0.2, 15.0)
    );
    assert_eq!(
        (
            t.hip_offset,
            t.hip_amplitude,
            t.hip_amplitude_swing,
            t.hip_amplitude_period_s
        ),
        (0.10, 0.30, 0.05, 10.0)
    );
    assert_eq!(
        (
            t.knee_amplitude,
            t.knee_amplitude_swing,
            t.knee_amplitude_period_s
        ),
        (1.00, 0.15, 7.0)
    );
    assert_eq!(t.knee_phase, 1.0471975511965976);
    let k = &s.trajectory.knee;
    assert_eq!((k.amplitude, k.frequency_hz), (0.6, 0.5));
    // MODEL.md §7
    assert_eq!(s.timing.dt, 0.01);
    assert_eq!(
        (s.timing.plant_substeps, s.timing.prediction_substeps),
        (10, 1)
    );
    assert_eq!(
        (s.timing.duration_2dof_s, s.timing.duration_1dof_s),
        (20.0, 30.0)
    );
    // MODEL.md §8
    let c = &s.controller;
    assert_eq!(c.kind, ControllerKind::MSNMPC);
    assert_eq!(
        (c.k1, c.k2),
        (GainSetting::Value(0.005), GainSetting::Value(0.05))
    );
    // "auto" (K = κ / ks) is the paper's 0.005 / 0.05 at the default 937.5 N/m straps.
    let mut s = s.clone();
    s.controller.k1 = GainSetting::Auto;
    s.controller.k2 = GainSetting::Auto;
    let i = exompc::scenario::intent(&s);
    let straps = exompc::model::Straps::two_dof(0.28, 0.16, s.straps.stiffness, s.straps.damping);
    assert_eq!((i.k1.value(&straps), i.k2.value(&straps)), (0.005, 0.05));
    assert_eq!((c.np, c.nc), (3, 3));
    assert_eq!((c.r_d, c.r_t), (0.1, 1e-5));
    assert_eq!((c.torque_max, c.torque_rate_max), (30.0, 1000.0));
    assert_eq!(c.interaction, Interaction::Predict);
    assert_eq!(
        (c.sqp.max_iterations, c.sqp.kkt_tolerance, c.sqp.max_time_us),
        (20, 1e-8, None)
    );
    assert_eq!((c.pd.kp, c.pd.kd), (30.0, 3.0));
    let m = &s.multistage;
    assert_eq!(m.payloads_kg, vec![0.0, 1.0, 2.0]);
    assert_eq!((m.c1, m.probability_floor), (100.0, 1e-4));
    assert_eq!(m.formulation, Formulation::Decoupled);
    assert_eq!(
        (m.robust_horizon, m.parallel, m.innovation),
        (1, false, Innovation::Standard)
    );
    // MODEL.md §8 EKF starting point: Q = diag(1e-8, 1e-8, 1e-4, 1e-4, 1e-2, 1e-2), R, P0
    let diag = |m: nalgebra::SMatrix<f64, 6, 6>| m.diagonal().iter().copied().collect::<Vec<_>>();
    assert_eq!(
        diag(s.ekf.process_noise::<6>()),
        vec![1e-8, 1e-8, 1e-4, 1e-4, 1e-2, 1e-2]
    );
    let r = s.ekf.measurement_noise::<4>();
    assert_eq!(
        r.diagonal().iter().copied().collect::<Vec<_>>(),
        vec![1e-6, 1e-6, 1.0, 1.0]
    );
    assert_eq!(
        diag(s.ekf.initial_covariance::<6>()),
        vec![1e-6, 1e-6, 1e-2, 1e-2, 1.0, 1.0]
    );
    let q1 = s.ekf.process_noise::<3>();
    assert_eq!(
        q1.diagonal().iter().copied().collect::<Vec<_>>(),
        vec![1e-8, 1e-4, 1e-2]
    );
    // faults and monitors
    assert!(s.faults.events.is_empty());
    assert_eq!(s.faults.saturation_n, 70.0);
    assert_eq!(
        (s.monitors.tracking_error_max_rad, s.monitors.force_max_n),
        (0.35, 70.0)
    );
    assert_eq!(s.monitors.sensor_timeout_s, 0.5);
    assert_eq!(s.monitors.response, MonitorResponse::Fallback);
}

#[test]
fn helpers() {
    let mut s = Experiment::default();
    assert_eq!(s.duration_s(2), 20.0);
    assert_eq!(s.duration_s(1), 30.0);
    assert_eq!(s.control_steps(2), 2000);
    assert_eq!(s.control_steps(1), 3000);
    assert!(close(s.rate_limit_per_step(), 10.0, 1e-12));
    assert!(close(s.plant_step_s(), 1e-3, 1e-15));
    assert!(close(s.prediction_step_s(), 1e-2, 1e-15));
    assert_eq!(s.plant_body_mass_kg(2, 0.0), 60.0);
    assert!(close(s.plant_body_mass_kg(2, 10.0), 72.5, 1e-12));
    assert_eq!(s.plant_body_mass_kg(2, 20.0), 85.0);
    assert_eq!(s.plant_body_mass_kg(2, 99.0), 85.0);
    assert_eq!(s.plant_body_mass_kg(1, 15.0), 60.0);
    s.uncertainty.human_mass_ramp = false;
    assert_eq!(s.plant_body_mass_kg(2, 20.0), 60.0);
    let ev = FaultEvent {
        kind: FaultKind::Spike,
        channel: Channel::F2,
        start_s: 1.0,
        duration_s: 0.5,
        magnitude: 3.0,
    };
    assert!(ev.active_at(1.0) && ev.active_at(1.49) && !ev.active_at(1.5) && !ev.active_at(0.99));
    assert_eq!(Channel::Qd2.joint(), 1);
    assert_eq!(Channel::F1.joint(), 0);
}

#[test]
fn error_display_format() {
    let mut s = Experiment::default();
    s.robot.thigh.mass = -1.0;
    let e = s.validate().unwrap_err();
    assert_eq!(e.field, "robot.thigh.mass_kg");
    assert_eq!(e.value, "-1");
    assert_eq!(e.allowed, "finite, > 0");
    assert_eq!(
        e.to_string(),
        "invalid value for robot.thigh.mass_kg: -1 (allowed: finite, > 0)"
    );
}

type Mutation = fn(&mut Experiment);

fn spike() -> FaultEvent {
    FaultEvent {
        kind: FaultKind::Spike,
        channel: Channel::F1,
        start_s: 1.0,
        duration_s: 0.1,
        magnitude: 5.0,
    }
}

/// Each rule: the mutation breaks exactly the named field.
const RULES: &[(&str, Mutation)] = &[
    ("human.height_m", |s| s.human.height_m = 0.0),
    ("human.body_mass_kg", |s| s.human.body_mass_kg = -60.0),
    ("human.final_body_mass_kg", |s| {
        s.human.final_body_mass_kg = f64::INFINITY
    }),
    ("human.kp", |s| s.human.kp = 0.0),
    ("human.kd", |s| s.human.kd = f64::NAN),
    ("human.thigh.mass_fraction", |s| {
        s.human.thigh.mass_fraction = 1.5
    }),
    ("human.shank.length_fraction", |s| {
        s.human.shank.length_fraction = 0.0
    }),
    ("human.shank.gyration_fraction", |s| {
        s.human.shank.gyration_fraction = -0.1
    }),
    ("robot.thigh.mass_kg", |s| s.robot.thigh.mass = -1.0),
    ("robot.shank.mass_kg", |s| s.robot.shank.mass = 0.0),
    ("robot.thigh.length_m", |s| s.robot.thigh.length = 0.0),
    ("robot.shank.com_m", |s| s.robot.shank.com = 0.5),
    ("robot.thigh.com_m", |s| s.robot.thigh.com = -0.01),
    ("robot.thigh.inertia_kgm2", |s| s.robot.thigh.inertia = 0.0),
    ("robot.viscous_friction", |s| {
        s.robot.viscous_friction = -1e-3
    }),
    ("robot.coulomb_friction", |s| {
        s.robot.coulomb_friction = f64::NAN
    }),
    ("robot.coulomb_smoothing", |s| {
        s.robot.coulomb_smoothing = 0.0
    }),
    ("robot.payload_position_m", |s| {
        s.robot.payload_position_m = 0.5
    }),
    ("straps.ls1_m", |s| s.straps.ls1_m = 0.0),
    ("straps.ls2_m", |s| s.straps.ls2_m = 1.0),
    ("straps.stiffness", |s| s.straps.stiffness = -937.5),
    ("straps.damping", |s| s.straps.damping = f64::NEG_INFINITY),
    ("uncertainty.payload_kg", |s| {
        s.uncertainty.payload_kg = -0.5
    }),
    ("uncertainty.payload_kg", |s| {
        s.uncertainty.payload_kg = 21.0
    }),
    ("uncertainty.velocity_noise", |s| {
        s.uncertainty.velocity_noise = -1e-4
    }),
    ("uncertainty.force_noise", |s| {
        s.uncertainty.force_noise = f64::NAN
    }),
    ("uncertainty.noise_frequency", |s| {
        s.uncertainty.noise_frequency = -100.0
    }),
    ("uncertainty.filter_window", |s| {
        s.uncertainty.filter_window = 0
    }),
    ("uncertainty.filter_window", |s| {
        s.uncertainty.filter_window = 101
    }),
    ("trajectory.base_frequency_hz", |s| {
        s.trajectory.swing.base_frequency_hz = 0.0
    }),
    ("trajectory.frequency_swing_hz", |s| {
        s.trajectory.swing.frequency_swing_hz = 0.8
    }),
    ("trajectory.frequency_period_s", |s| {
        s.trajectory.swing.frequency_period_s = 0.0
    }),
    ("trajectory.hip_offset", |s| {
        s.trajectory.swing.hip_offset = f64::NAN
    }),
    ("trajectory.hip_amplitude", |s| {
        s.trajectory.swing.hip_amplitude = -0.3
    }),
    ("trajectory.knee_amplitude_swing", |s| {
        s.trajectory.swing.knee_amplitude_swing = -0.1
    }),
    ("trajectory.knee_amplitude_period_s", |s| {
        s.trajectory.swing.knee_amplitude_period_s = 0.0
    }),
    ("trajectory.knee_phase", |s| {
        s.trajectory.swing.knee_phase = f64::INFINITY
    }),
    ("trajectory.one_dof_amplitude", |s| {
        s.trajectory.knee.amplitude = f64::NAN
    }),
    ("trajectory.one_dof_frequency_hz", |s| {
        s.trajectory.knee.frequency_hz = -0.5
    }),
    ("timing.dt", |s| s.timing.dt = 0.0),
    ("timing.dt", |s| s.timing.dt = 2.0),
    ("timing.dt", |s| s.timing.dt = f64::NAN),
    ("timing.plant_substeps", |s| s.timing.plant_substeps = 0),
    ("timing.prediction_substeps", |s| {
        s.timing.prediction_substeps = 1001
    }),
    ("timing.duration_2dof_s", |s| s.timing.duration_2dof_s = 0.0),
    ("timing.duration_1dof_s", |s| {
        s.timing.duration_1dof_s = f64::NAN
    }),
    ("controller.k1", |s| s.controller.k1 = f64::NAN.into()),
    ("controller.k2", |s| s.controller.k2 = (-0.05).into()),
    ("controller.np", |s| s.controller.np = 0),
    ("controller.np", |s| s.controller.np = 201),
    ("controller.nc", |s| s.controller.nc = 4),
    ("controller.nc", |s| s.controller.nc = 0),
    ("controller.r_d", |s| s.controller.r_d = -0.1),
    ("controller.r_t", |s| s.controller.r_t = 0.0),
    ("controller.torque_max", |s| s.controller.torque_max = 0.0),
    ("controller.torque_rate_max", |s| {
        s.controller.torque_rate_max = f64::INFINITY
    }),
    ("controller.sqp.max_iterations", |s| {
        s.controller.sqp.max_iterations = 0
    }),
    ("controller.sqp.kkt_tolerance", |s| {
        s.controller.sqp.kkt_tolerance = -1e-9
    }),
    ("controller.sqp.max_time_us", |s| {
        s.controller.sqp.max_time_us = Some(10_000_001)
    }),
    ("controller.pd.kp", |s| s.controller.pd.kp = f64::NAN),
    ("controller.pd.kd", |s| s.controller.pd.kd = 0.0),
    ("multistage.payloads_kg", |s| {
        s.multistage.payloads_kg.clear()
    }),
    ("multistage.payloads_kg", |s| {
        s.multistage.payloads_kg = vec![0.0; 33]
    }),
    ("multistage.payloads_kg[1]", |s| {
        s.multistage.payloads_kg[1] = -1.0
    }),
    ("multistage.payloads_kg[2]", |s| {
        s.multistage.payloads_kg[2] = f64::NAN
    }),
    ("multistage.payloads_kg[0]", |s| {
        s.multistage.payloads_kg[0] = 25.0
    }),
    ("multistage.c1", |s| s.multistage.c1 = 0.0),
    ("multistage.probability_floor", |s| {
        s.multistage.probability_floor = 0.5
    }),
    ("multistage.probability_floor", |s| {
        s.multistage.probability_floor = 0.0
    }),
    ("multistage.robust_horizon", |s| {
        s.multistage.robust_horizon = 0
    }),
    ("multistage.robust_horizon", |s| {
        s.multistage.robust_horizon = 4
    }),
    ("ekf.q_angle", |s| s.ekf.q_angle = 0.0),
    ("ekf.q_velocity", |s| s.ekf.q_velocity = -1.0),
    ("ekf.q_disturbance", |s| s.ekf.q_disturbance = f64::NAN),
    ("ekf.r_angle", |s| s.ekf.r_angle = 0.0),
    ("ekf.r_velocity", |s| s.ekf.r_velocity = f64::INFINITY),
    ("ekf.p0_angle", |s| s.ekf.p0_angle = 0.0),
    ("ekf.p0_velocity", |s| s.ekf.p0_velocity = -1e-2),
    ("ekf.p0_disturbance", |s| s.ekf.p0_disturbance = 0.0),
    ("faults.saturation_n", |s| s.faults.saturation_n = 0.0),
    ("faults.events[0].start_s", |s| {
        s.faults.events = vec![FaultEvent {
            start_s: -1.0,
            ..spike()
        }]
    }),
    ("faults.events[1].duration_s", |s| {
        s.faults.events = vec![
            spike(),
            FaultEvent {
                duration_s: -0.1,
                ..spike()
            },
        ]
    }),
    ("faults.events[0].magnitude", |s| {
        s.faults.events = vec![FaultEvent {
            magnitude: f64::NAN,
            ..spike()
        }]
    }),
    ("monitors.tracking_error_max_rad", |s| {
        s.monitors.tracking_error_max_rad = 0.0
    }),
    ("monitors.force_max_n", |s| s.monitors.force_max_n = -70.0),
    ("monitors.sensor_timeout_s", |s| {
        s.monitors.sensor_timeout_s = f64::NAN
    }),
];

#[test]
fn each_rule_rejects_bad_value_naming_the_field() {
    for (i, (field, mutate)) in RULES.iter().enumerate() {
        let mut s = Experiment::default();
        mutate(&mut s);
        let err = s
            .validate()
            .expect_err(&format!("rule {i} ({field}) should be rejected"));
        assert_eq!(err.field, *field, "rule {i}: {err}");
        let msg = err.to_string();
        assert!(
            msg.starts_with(&format!("invalid value for {field}: ")),
            "rule {i}: {msg}"
        );
        assert!(msg.contains("(allowed: "), "rule {i}: {msg}");
    }
}

#[test]
fn boundary_values_are_accepted() {
    let mut s = Experiment::default();
    s.uncertainty.payload_kg = 20.0;
    s.multistage.payloads_kg = vec![0.0, 20.0];
    s.multistage.probability_floor = 0.49;
    s.timing.dt = 1.0;
    s.controller.np = 200;
    s.controller.nc = 200;
    s.multistage.robust_horizon = 200;
    s.controller.k1 = 0.0.into();
    s.controller.r_d = 0.0;
    s.straps.damping = 0.0;
    s.robot.shank.com = s.robot.shank.length;
    s.robot.payload_position_m = 0.0;
    s.controller.sqp.max_time_us = Some(5000);
    s.faults.events = vec![spike()];
    s.validate().expect("boundary values are valid");
}

/// Each cross-field rule: the mutation breaks `field` through the bound set by `other`, and the
/// error names both (issue 15); a breach of the field's own range names no other key.
#[test]
fn cross_field_rules_name_both_keys() {
    let cases: &[(&str, &str, Mutation)] = &[
        ("robot.thigh.com_m", "robot.thigh.length_m", |s| {
            s.robot.thigh.length = 0.1
        }),
        ("robot.shank.com_m", "robot.shank.length_m", |s| {
            s.robot.shank.com = 0.5
        }),
        ("robot.payload_position_m", "robot.shank.length_m", |s| {
            s.robot.payload_position_m = 0.5
        }),
        ("straps.ls1_m", "robot.thigh.length_m", |s| {
            s.robot.thigh.length = 0.25
        }),
        ("straps.ls2_m", "robot.shank.length_m", |s| {
            s.straps.ls2_m = 0.5
        }),
        (
            "trajectory.frequency_swing_hz",
            "trajectory.base_frequency_hz",
            |s| s.trajectory.swing.base_frequency_hz = 0.2,
        ),
        ("timing.duration_2dof_s", "timing.dt", |s| {
            s.timing.duration_2dof_s = 0.005
        }),
        ("timing.duration_1dof_s", "timing.dt", |s| {
            s.timing.duration_1dof_s = 2e5;
            s.timing.dt = 1e-4
        }),
        ("controller.nc", "controller.np", |s| s.controller.np = 2),
        ("multistage.robust_horizon", "controller.nc", |s| {
            s.multistage.robust_horizon = 4
        }),
        (
            "multistage.probability_floor",
            "multistage.payloads_kg",
            |s| s.multistage.probability_floor = 0.4,
        ),
    ];
    for (field, other, mutate) in cases {
        let mut s = Experiment::default();
        mutate(&mut s);
        let e = s.validate().expect_err(field);
        assert_eq!(e.field, *field, "{e}");
        let d = e
            .depends_on
            .as_ref()
            .unwrap_or_else(|| panic!("{field}: {e}"));
        assert_eq!(d.key, *other, "{e}");
        let msg = e.to_string();
        assert!(msg.contains(field) && msg.contains(other), "{msg}");
        assert!(d.fix.contains(field) && d.fix.contains(other), "{}", d.fix);
    }
    // Own-range breaches of the same fields name no other key.
    for mutate in [
        (|s: &mut Experiment| s.straps.ls1_m = 0.0) as Mutation,
        |s| s.robot.thigh.com = -0.1,
        |s| s.controller.nc = 0,
        |s| s.multistage.probability_floor = 0.0,
        |s| s.trajectory.swing.frequency_swing_hz = -0.1,
        |s| s.timing.duration_2dof_s = f64::NAN,
    ] {
        let mut s = Experiment::default();
        mutate(&mut s);
        let e = s.validate().unwrap_err();
        assert_eq!(e.depends_on, None, "{e}");
    }
}
