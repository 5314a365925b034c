//! Cost of one scenario EKF step and one 3-scenario bank step (2-DOF robot, MODEL.md §8 settings).

use criterion::{criterion_group, criterion_main, Criterion};
use exompc::estimate::{EkfBank, EkfSettings, EstimatorOptions, ScenarioEkf};
use exompc::model::{Chain, Friction, Link, RobotModel};
use nalgebra::{Vector2, Vector4};
use std::hint::black_box;

fn robot(payload: f64) -> RobotModel<2> {
    let thigh = Link {
        length: 0.43,
        mass: 2.0,
        com: 0.20,
        inertia: 0.035,
    };
    let shank = Link {
        length: 0.43,
        mass: 1.2,
        com: 0.18,
        inertia: 0.018,
    }
    .with_point_mass(payload, 0.215);
    RobotModel {
        chain: Chain::new([thigh, shank]),
        viscous: 0.000899,
        coulomb: 0.05048,
        friction: Friction::Tanh { width: 0.01 },
    }
}

/// A short deterministic measurement sequence (a swing), cycled through by the benches.
fn measurements() -> Vec<(Vector4<f64>, Vector2<f64>)> {
    let w = 2.0 * std::f64::consts::PI * 0.8;
    (0..100)
        .map(|k| {
            let t = k as f64 * 0.01;
            let y = Vector4::new(
                0.1 + 0.3 * (w * t).sin(),
                -0.5 * (1.0 - (w * t).cos()),
                0.3 * w * (w * t).cos(),
                -0.5 * w * (w * t).sin(),
            );
            let u = Vector2::new(5.0 * (w * t).sin(), 1.0 * (w * t).cos());
            (y, u)
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let settings = EkfSettings::default();
    let opts = EstimatorOptions::default();
    let q0 = Vector2::new(0.1, 0.0);
    let qd0 = Vector2::zeros();
    let data = measurements();
    let tint = Vector2::new(0.5, -0.2);

    let mut f: ScenarioEkf<2, 6, 4> =
        ScenarioEkf::new(robot(1.0), &settings, &opts, &q0, &qd0).expect("valid settings");
    let mut k = 0;
    c.bench_function("scenario_ekf_step", |b| {
        b.iter(|| {
            let (y, u) = &data[k % data.len()];
            k += 1;
            if k % data.len() == 0 {
                f.reset();
            }
            black_box(f.step(black_box(y), black_box(u), black_box(&tint))).ok()
        })
    });

    let models = [robot(0.0), robot(1.0), robot(2.0)];
    let mut bank: EkfBank<2, 6, 4> =
        EkfBank::new(&models, &settings, &opts, &q0, &qd0).expect("valid settings");
    let mut k = 0;
    c.bench_function("ekf_bank3_step", |b| {
        b.iter(|| {
            let (y, u) = &data[k % data.len()];
            k += 1;
            if k % data.len() == 0 {
                bank.reset();
            }
            black_box(bank.step(black_box(y), black_box(u), black_box(&tint))).ok();
            black_box(bank.probabilities()[0])
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
