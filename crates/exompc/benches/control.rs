//! Cost of the control hot paths on the default 2-DOF scenario: the condensed residuals and
//! Jacobian, the QP of one SQP iteration, one SQP solve at a realistic state, and whole control
//! steps of the plain and multi-stage (decoupled, coupled) controllers, fed with measurements
//! recorded from a closed loop and stepped through cyclically.

mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::control::{horizon_inputs, NmpcCore};
use exompc::model::JointState;
use exompc::scenario::{
    build_controller, initial_torque, intent, limits, nmpc_settings, prediction_model, TwoDof,
};
use exompc::solver::{Constraints, DenseQp, LeastSquares};
use nalgebra::{DMatrix, DVector, SVector};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let s = Experiment::default();
    let meas = common::record(&s, 600);
    let model = prediction_model::<TwoDof, 2>(&s, 0.0);
    let settings = nmpc_settings(&s);
    let lim = limits(&s);
    let m = meas[400];
    let inputs = horizon_inputs(&intent(&s), &model, &m, SVector::zeros());
    let x0 = JointState { q: m.q, qd: m.qd };
    let t_prev = initial_torque::<TwoDof, 2>(&s);

    // One NMPC problem at a realistic state.
    let mut core = NmpcCore::new(model, &settings).expect("core");
    core.solve(x0, t_prev, inputs, &lim);
    let mut problem = core.problem.clone();
    let (n, nr) = (problem.num_vars(), problem.num_residuals());
    let z = vec![0.0; n];
    let mut r = vec![0.0; nr];
    let mut jac = DMatrix::zeros(nr, n);
    c.bench_function("control/nmpc_residuals_jacobian", |b| {
        b.iter(|| problem.residuals_jacobian(black_box(&z), &mut r, &mut jac))
    });

    // The QP of the first SQP iteration: H = JᵀJ, g = Jᵀr, eq. 8-9 constraints.
    problem.residuals_jacobian(&z, &mut r, &mut jac);
    let h = jac.transpose() * &jac + DMatrix::identity(n, n) * 1e-12;
    let g = jac.transpose() * DVector::from_column_slice(&r);
    let mut cons = Constraints::unbounded(n, n);
    problem.write_constraints(&lim, &mut cons);
    let mut qp = DenseQp::new(n, n);
    let mut x = DVector::zeros(n);
    c.bench_function("control/qp", |b| {
        b.iter(|| {
            qp.solve(
                black_box(&h),
                black_box(&g),
                &cons.zl,
                &cons.zu,
                &cons.a,
                &cons.bl,
                &cons.bu,
                &mut x,
            )
        })
    });

    c.bench_function("control/sqp_solve", |b| {
        b.iter(|| {
            core.reset();
            core.solve(black_box(x0), t_prev, inputs, &lim)
        })
    });

    let mut step_bench = |name: &str, kind: ControllerKind, formulation: Formulation| {
        let mut sc = s.clone();
        sc.multistage.formulation = formulation;
        let mut ctrl = build_controller::<TwoDof, 2>(&sc, kind).expect("controller");
        for mm in &meas[..100] {
            ctrl.step(mm);
        }
        let mut k = 100;
        c.bench_function(name, |b| {
            b.iter(|| {
                k = if k + 1 < meas.len() { k + 1 } else { 100 };
                ctrl.step(black_box(&meas[k]))
            })
        });
    };
    step_bench(
        "control/step_nmpc",
        ControllerKind::NMPC,
        Formulation::Decoupled,
    );
    step_bench(
        "control/step_msnmpc_decoupled",
        ControllerKind::MSNMPC,
        Formulation::Decoupled,
    );
    step_bench(
        "control/step_msnmpc_coupled",
        ControllerKind::MSNMPC,
        Formulation::Coupled,
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
