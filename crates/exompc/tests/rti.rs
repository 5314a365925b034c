//! Real-time iteration (`[controller.sqp] rti = true`, `SqpSettings::real_time_iteration`): one
//! linearisation and one QP per solve, full step. Oracles: repeated on a fixed problem, the
//! real-time iterations are undamped Gauss–Newton iterations and reach the converged SQP
//! solution; the dense and the structured back-ends take the same step, so their closed loops
//! agree to rounding.

use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::control::QpBackend;
use exompc::control::{horizon_inputs, Measurement, NmpcProblem, StructuredSqp, TorqueLimits};
use exompc::model::JointState;
use exompc::scenario::{
    build_controller, intent, limits, nmpc_settings, plant_params, prediction_model, uncertainty,
    Dof, OneDof, TwoDof,
};
use exompc::sim::{Plant, Sensors};
use exompc::solver::{Constraints, HessianModel, LeastSquares, Sqp, SqpStatus};
use nalgebra::{DVector, SVector};

/// Repeats real-time iterations on one problem (each from the previous result, unshifted) with
/// both back-ends, and compares with the converged Gauss–Newton SQP solution.
fn repeated_rti_reaches_sqp<D: Dof<N>, const N: usize>(n: usize, t_prev: [f64; 2], force: f64) {
    let mut s = Experiment::default();
    s.controller.np = n;
    s.controller.nc = n;
    s.controller.sqp.hessian = HessianModel::GaussNewton.into();
    let model = prediction_model::<D, N>(&s, 0.0);
    let lim: TorqueLimits = limits(&s);
    let mut full = nmpc_settings(&s);
    full.sqp.max_iterations = 500;
    full.sqp.kkt_tolerance = 1e-11;
    let mut rti = full;
    rti.sqp.real_time_iteration = true;

    let q = SVector::<f64, N>::from_fn(|a, _| 0.3 - 0.4 * a as f64);
    let qd = SVector::<f64, N>::from_fn(|a, _| 1.5 - 2.0 * a as f64);
    let m = Measurement {
        t: 0.0,
        q,
        qd,
        force: SVector::<f64, N>::from_element(force),
    };
    let mut problem = NmpcProblem::new(model, &full);
    problem.x0 = JointState { q, qd };
    problem.t_prev = SVector::<f64, N>::from_fn(|a, _| t_prev[a]);
    problem.inputs = horizon_inputs(&intent(&s), &model, &m, SVector::zeros());
    let nv = problem.num_vars();
    let mut cons = Constraints::unbounded(nv, nv);
    problem.write_constraints(&lim, &mut cons);

    let mut z_full = DVector::zeros(nv);
    let mut sqp = Sqp::new(nv, problem.num_residuals(), nv, full.sqp).unwrap();
    let info = sqp.solve(&mut problem, &cons, &mut z_full);
    assert_eq!(info.status, SqpStatus::Converged, "{N}-DOF n={n}: {info:?}");

    let mut dense = Sqp::new(nv, problem.num_residuals(), nv, rti.sqp).unwrap();
    let mut structured = StructuredSqp::<N>::new(&rti).unwrap();
    let (mut za, mut zb) = (DVector::zeros(nv), DVector::zeros(nv));
    let mut converged_after = None;
    for it in 0..200 {
        let a = dense.solve(&mut problem, &cons, &mut za);
        let b = structured.solve(&problem, &lim, &mut zb);
        assert_eq!(a.status, b.status, "{N}-DOF n={n} iteration {it}");
        assert!(a.iterations <= 1 && b.iterations <= 1);
        assert!(
            (&za - &zb).amax() <= 1e-8,
            "{N}-DOF n={n} iteration {it}: dense and structured RTI steps differ by {:e}",
            (&za - &zb).amax()
        );
        match a.status {
            SqpStatus::RealTimeIteration => {}
            SqpStatus::Converged => {
                converged_after = Some(it);
                break;
            }
            other => panic!("{N}-DOF n={n} iteration {it}: {other:?}"),
        }
    }
    let it = converged_after.expect("the real-time iterations did not reach the KKT tolerance");
    let diff = (&za - &z_full).amax();
    eprintln!("{N}-DOF n={n}: RTI converged after {it} periods, |z − z_sqp| = {diff:e}");
    assert!(diff <= 1e-8, "{N}-DOF n={n}: |z_rti − z_sqp| = {diff:e}");
    // The instance exercises the limits: some rate or cumulative bound is active.
    let mut acc = problem.t_prev;
    let mut active = 0;
    for j in 0..n {
        for a in 0..N {
            acc[a] += z_full[j * N + a];
            if (z_full[j * N + a].abs() - lim.rate).abs() < 1e-9
                || (acc[a].abs() - lim.max).abs() < 1e-9
            {
                active += 1;
            }
        }
    }
    eprintln!("{N}-DOF n={n}: {active} active bounds");
}

#[test]
fn repeated_real_time_iterations_reach_the_sqp_solution() {
    // Free and at the cumulative torque limit (T(k−1) near ±30 N·m with a large strap force).
    repeated_rti_reaches_sqp::<OneDof, 1>(10, [0.0, 0.0], 5.0);
    repeated_rti_reaches_sqp::<TwoDof, 2>(10, [2.0, -1.0], 5.0);
    repeated_rti_reaches_sqp::<OneDof, 1>(10, [29.9, 0.0], 150.0);
    repeated_rti_reaches_sqp::<TwoDof, 2>(20, [29.9, -29.9], 150.0);
}

/// Closed loop with real-time iterations, dense vs structured back-end: the largest torque
/// difference over `steps` steps; every step is one iteration with status Ok.
fn rti_closed_loop_diff<D: Dof<N>, const N: usize>(kind: ControllerKind, n: usize) -> f64 {
    let mut s = Experiment::default();
    s.controller.np = n;
    s.controller.nc = n;
    s.controller.sqp.hessian = HessianModel::GaussNewton.into();
    s.controller.sqp.rti = true;
    s.multistage.formulation = Formulation::Decoupled;
    let run = |qp: QpBackend| {
        let mut sc = s.clone();
        sc.controller.sqp.qp = qp;
        let mut c = build_controller::<D, N>(&sc, kind).unwrap();
        let mut plant = Plant::new(plant_params::<D, N>(&sc), D::trajectory(&sc));
        let mut sensors = Sensors::new(uncertainty(&sc), sc.uncertainty.filter_window);
        let mut out = vec![];
        for k in 0..300 {
            let st = *plant.state();
            let f = plant.strap_force();
            let (_, meas) = sensors.read(plant.time(), &st.robot.q, &st.robot.qd, &f);
            let o = c.step(&meas);
            assert_eq!(o.status, exompc::control::StepStatus::Ok, "{qp:?} step {k}");
            out.push(o.torque);
            plant.step(&o.torque);
        }
        out
    };
    let a = run(QpBackend::Dense);
    let b = run(QpBackend::Structured);
    a.iter()
        .zip(&b)
        .map(|(x, y)| (x - y).amax())
        .fold(0.0, f64::max)
}

#[test]
fn rti_closed_loops_dense_equal_structured() {
    for (kind, d) in [
        (
            ControllerKind::NMPC,
            rti_closed_loop_diff::<OneDof, 1>(ControllerKind::NMPC, 10),
        ),
        (
            ControllerKind::NMPC,
            rti_closed_loop_diff::<TwoDof, 2>(ControllerKind::NMPC, 10),
        ),
        (
            ControllerKind::MSNMPC,
            rti_closed_loop_diff::<TwoDof, 2>(ControllerKind::MSNMPC, 10),
        ),
        (
            ControllerKind::NMPC,
            rti_closed_loop_diff::<TwoDof, 2>(ControllerKind::NMPC, 20),
        ),
    ] {
        eprintln!("{kind:?}: max |ΔT| = {d:e}");
        assert!(d <= 1e-8, "{kind:?}: max |ΔT| = {d:e}");
    }
}
