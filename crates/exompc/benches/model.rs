//! Cost of the prediction model: the stage dynamics (with a dual-number Jacobian) and one RK4
//! step of the default 2-DOF scenario, alone and with its Jacobian (tailored and num-dual).

use criterion::{criterion_group, criterion_main, Criterion};
use exompc::config::Experiment;
use exompc::control::{HorizonInputs, PredictionModel};
use exompc::model::{JointState, StepJacobian};
use exompc::scenario::{prediction_model, TwoDof};
use nalgebra::Vector2;
use num_dual::{DualSVec64, DualStruct};
use std::hint::black_box;

fn fixture() -> (
    PredictionModel<2>,
    JointState<f64, 2>,
    Vector2<f64>,
    HorizonInputs<2>,
) {
    let s = Experiment::default();
    let m = prediction_model::<TwoDof, 2>(&s, 1.0);
    let x = JointState {
        q: Vector2::new(0.3, -0.6),
        qd: Vector2::new(1.2, -2.0),
    };
    let u = Vector2::new(4.0, 1.5);
    let inp = HorizonInputs {
        q_h: x.q + Vector2::new(0.01, -0.02),
        qd_h: x.qd + Vector2::new(0.1, 0.05),
        t_int_measured: Vector2::new(0.5, -0.3),
        disturbance: Vector2::new(0.2, 0.1),
    };
    (m, x, u, inp)
}

fn bench(c: &mut Criterion) {
    let (m, x, u, inp) = fixture();
    c.bench_function("model/dynamics", |b| {
        b.iter(|| m.derivative(0.0, black_box(&x), black_box(&u), &inp))
    });
    c.bench_function("model/dynamics_jacobian_dual", |b| {
        type D = DualSVec64<4>;
        b.iter(|| {
            let x = black_box(&x);
            let xd = JointState {
                q: Vector2::new(D::from(x.q[0]).derivative(0), D::from(x.q[1]).derivative(1)),
                qd: Vector2::new(
                    D::from(x.qd[0]).derivative(2),
                    D::from(x.qd[1]).derivative(3),
                ),
            };
            let ud = black_box(&u).map(D::from);
            let f = m.derivative(0.0, &xd, &ud, &inp);
            f.qd[0].re() + f.qd[1].re()
        })
    });
    c.bench_function("model/rk4_step", |b| {
        b.iter(|| m.step(black_box(&x), black_box(&u), 0.0, &inp))
    });
    c.bench_function("model/rk4_step_jacobian", |b| {
        b.iter(|| m.step_with_jacobian(black_box(&x), black_box(&u), 0.0, &inp))
    });
    c.bench_function("model/rk4_step_jacobian_dual", |b| {
        b.iter(|| {
            StepJacobian::by_dual_numbers(black_box(&x), black_box(&u), |x, u| {
                m.step(x, u, 0.0, &inp)
            })
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
