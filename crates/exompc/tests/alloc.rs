//! The control step allocates nothing: after construction and a few warm-up steps, 200 closed-loop
//! control steps of `nmpc`, `msnmpc` (decoupled) and `msnmpc` (coupled) on the default 2-DOF
//! scenario make no heap allocation. (The rayon-parallel decoupled path, off by default, is not
//! covered: rayon's work stealing may allocate.)

use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::scenario::{build_controller, plant_params, uncertainty, Dof, TwoDof};
use exompc::sim::{Plant, Sensors};

mod common;
use common::alloc::{allocations_in, Counting};

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Closed loop of `s`: 20 warm-up steps, then 200 counted controller steps.
fn count_steps(s: &Experiment, kind: ControllerKind) -> usize {
    let mut controller = build_controller::<TwoDof, 2>(s, kind).expect("controller");
    let mut plant = Plant::new(plant_params::<TwoDof, 2>(s), TwoDof::trajectory(s));
    let mut sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window);
    let mut total = 0;
    for k in 0..220 {
        let t = plant.time();
        let st = *plant.state();
        let force = plant.strap_force();
        let (_raw, meas) = sensors.read(t, &st.robot.q, &st.robot.qd, &force);
        let mut out = None;
        let n = allocations_in(|| out = Some(controller.step(&meas)));
        if k >= 20 {
            total += n;
        }
        plant.step(&out.expect("stepped").torque);
    }
    total
}

#[test]
fn control_steps_do_not_allocate() {
    let mut s = Experiment::default();
    s.multistage.parallel = false;

    s.controller.kind = ControllerKind::NMPC;
    assert_eq!(count_steps(&s, ControllerKind::NMPC), 0, "nmpc allocates");

    s.controller.kind = ControllerKind::MSNMPC;
    s.multistage.formulation = Formulation::Decoupled;
    assert_eq!(
        count_steps(&s, ControllerKind::MSNMPC),
        0,
        "msnmpc (decoupled) allocates"
    );

    s.multistage.formulation = Formulation::Coupled;
    assert_eq!(
        count_steps(&s, ControllerKind::MSNMPC),
        0,
        "msnmpc (coupled) allocates"
    );

    // The structured (Riccati) QP path, plain and decoupled multi-stage, at a longer horizon.
    s.controller.sqp.qp = exompc::control::QpBackend::Structured;
    s.controller.np = 12;
    s.controller.nc = 12;
    s.controller.kind = ControllerKind::NMPC;
    assert_eq!(
        count_steps(&s, ControllerKind::NMPC),
        0,
        "nmpc (structured QP) allocates"
    );
    s.controller.kind = ControllerKind::MSNMPC;
    s.multistage.formulation = Formulation::Decoupled;
    assert_eq!(
        count_steps(&s, ControllerKind::MSNMPC),
        0,
        "msnmpc (decoupled, structured QP) allocates"
    );
    // The coupled scenario tree with the block-arrowhead QP, robust horizon 1 and 3.
    s.multistage.formulation = Formulation::Coupled;
    for nr in [1, 3] {
        s.multistage.robust_horizon = nr;
        assert_eq!(
            count_steps(&s, ControllerKind::MSNMPC),
            0,
            "msnmpc (coupled, structured QP, robust horizon {nr}) allocates"
        );
    }
    s.multistage.robust_horizon = 1;
    // The exact Hessian (inertia correction and curvature blocks), both back-ends.
    s.multistage.formulation = Formulation::Decoupled;
    s.controller.sqp.hessian = exompc::solver::HessianModel::Exact.into();
    for qp in [
        exompc::control::QpBackend::Dense,
        exompc::control::QpBackend::Structured,
    ] {
        s.controller.sqp.qp = qp;
        for kind in [ControllerKind::NMPC, ControllerKind::MSNMPC] {
            s.controller.kind = kind;
            assert_eq!(
                count_steps(&s, kind),
                0,
                "{kind:?} (exact Hessian, {qp:?} QP) allocates"
            );
        }
    }
    s.controller.sqp.hessian = Experiment::default().controller.sqp.hessian;
    s.controller.sqp.qp = exompc::control::QpBackend::Auto;
    s.controller.np = 3;
    s.controller.nc = 3;
    // The robust method's filter-aware mode engaged from the first step.
    s.multistage.formulation = Formulation::Decoupled;
    s.controller.robust.filter_aware = exompc::config::FilterAware::Always;
    assert_eq!(
        count_steps(&s, ControllerKind::MSNMPC),
        0,
        "msnmpc (filter-aware) allocates"
    );

    // The counter works.
    assert!(allocations_in(|| drop(std::hint::black_box(vec![1u8; 16]))) > 0);
}

/// Reports the controllers' inline sizes (`cargo test --test alloc -- --nocapture`); the heap
/// buffers are listed in `docs/PERFORMANCE.md`.
#[test]
fn controller_sizes() {
    use exompc::control::{MultiStage, Nmpc};
    let nmpc = std::mem::size_of::<Nmpc<2>>();
    let ms = std::mem::size_of::<MultiStage<2, 6, 4>>();
    eprintln!("size_of Nmpc<2> = {nmpc} B, MultiStage<2, 6, 4> = {ms} B");
    assert!(nmpc > 0 && ms > 0);
}

/// The safety supervisor (plausibility, monitors incl. the oscillation detectors' ring
/// buffers, event log) adds no allocation: on the default scenario and on a limit-cycling one
/// whose monitors trip and clear.
#[test]
fn supervised_steps_do_not_allocate() {
    let mut provoked = Experiment::default();
    provoked.uncertainty.filter_window = 9;
    provoked.uncertainty.payload_kg = 2.0;
    provoked.robot.payload_position_m = 0.43;
    for s in [Experiment::default(), provoked] {
        let mut controller =
            exompc::scenario::build_supervised::<TwoDof, 2>(&s, ControllerKind::MSNMPC).unwrap();
        let mut plant = Plant::new(plant_params::<TwoDof, 2>(&s), TwoDof::trajectory(&s));
        let mut sensors = Sensors::new(uncertainty(&s), s.uncertainty.filter_window);
        let mut total = 0;
        for k in 0..400 {
            let t = plant.time();
            let st = *plant.state();
            let force = plant.strap_force();
            let (_raw, meas) = sensors.read(t, &st.robot.q, &st.robot.qd, &force);
            let mut out = None;
            let n = allocations_in(|| {
                out = Some(exompc::control::Controller::step(&mut controller, &meas))
            });
            if k >= 20 {
                total += n;
            }
            plant.step(&out.expect("stepped").torque);
        }
        assert_eq!(total, 0, "supervised msnmpc allocates");
    }
}
