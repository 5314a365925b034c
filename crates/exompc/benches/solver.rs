//! Benchmarks of the dense QP (n = 6 and n = 100) and of a small SQP solve.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use exompc::solver::qp::DenseQp;
use exompc::solver::sqp::{Constraints, LeastSquares, Sqp, SqpSettings};
use nalgebra::{DMatrix, DVector};

/// The tests' shared support module (its deterministic [`Rng`]).
#[path = "../tests/common/mod.rs"]
mod test_support;
use test_support::Rng;

/// QP with a box, cumulative-sum rows and a gradient pushing several constraints active.
#[allow(clippy::type_complexity)]
fn qp_instance(
    n: usize,
    seed: u64,
) -> (
    DMatrix<f64>,
    DVector<f64>,
    DVector<f64>,
    DVector<f64>,
    DMatrix<f64>,
    DVector<f64>,
    DVector<f64>,
) {
    let mut rng = Rng(seed);
    let m = DMatrix::from_fn(3 * n, n, |_, _| rng.range(-1.0, 1.0));
    let h = m.transpose() * &m + DMatrix::identity(n, n) * 1e-3;
    let g = DVector::from_fn(n, |_, _| rng.range(-4.0, 4.0) * n as f64);
    let lb = DVector::from_element(n, -1.0);
    let ub = DVector::from_element(n, 1.0);
    let a = DMatrix::from_fn(n, n, |i, j| if j <= i { 1.0 } else { 0.0 });
    let bl = DVector::from_element(n, -2.0);
    let bu = DVector::from_element(n, 2.0);
    (h, g, lb, ub, a, bl, bu)
}

fn bench_qp(c: &mut Criterion) {
    for n in [6usize, 100] {
        let (h, g, lb, ub, a, bl, bu) = qp_instance(n, 3);
        let mut qp = DenseQp::new(n, n);
        let mut x = DVector::zeros(n);
        let info = qp.solve(&h, &g, &lb, &ub, &a, &bl, &bu, &mut x);
        eprintln!(
            "qp n={n}: {:?}, {} iterations, {} active",
            info.status,
            info.iterations,
            qp.num_active()
        );
        c.bench_function(&format!("qp_dense_n{n}_p{n}"), |b| {
            b.iter(|| {
                black_box(qp.solve(black_box(&h), black_box(&g), &lb, &ub, &a, &bl, &bu, &mut x))
            })
        });
    }
}

/// r(z) = C z − y + β ∘ sin(W z): allocation-free residuals and Jacobian.
struct SmallNl {
    c: DMatrix<f64>,
    y: DVector<f64>,
    beta: DVector<f64>,
    w: DMatrix<f64>,
}

impl LeastSquares for SmallNl {
    fn num_vars(&self) -> usize {
        self.c.ncols()
    }
    fn num_residuals(&self) -> usize {
        self.c.nrows()
    }
    fn residuals(&mut self, z: &[f64], r: &mut [f64]) -> bool {
        for (i, ri) in r.iter_mut().enumerate() {
            let (mut cz, mut wz) = (0.0, 0.0);
            for (j, zj) in z.iter().enumerate() {
                cz += self.c[(i, j)] * zj;
                wz += self.w[(i, j)] * zj;
            }
            *ri = cz - self.y[i] + self.beta[i] * wz.sin();
        }
        r.iter().all(|v| v.is_finite())
    }
    fn residuals_jacobian(&mut self, z: &[f64], r: &mut [f64], jac: &mut DMatrix<f64>) -> bool {
        for (i, ri) in r.iter_mut().enumerate() {
            let (mut cz, mut wz) = (0.0, 0.0);
            for (j, zj) in z.iter().enumerate() {
                cz += self.c[(i, j)] * zj;
                wz += self.w[(i, j)] * zj;
            }
            let (s, co) = wz.sin_cos();
            *ri = cz - self.y[i] + self.beta[i] * s;
            let bc = self.beta[i] * co;
            for j in 0..z.len() {
                jac[(i, j)] = self.c[(i, j)] + bc * self.w[(i, j)];
            }
        }
        r.iter().all(|v| v.is_finite())
    }
}

fn bench_sqp(c: &mut Criterion) {
    let (n, m) = (6usize, 18usize);
    let mut rng = Rng(17);
    let mut prob = SmallNl {
        c: DMatrix::from_fn(m, n, |_, _| rng.range(-1.0, 1.0)),
        y: DVector::zeros(m),
        beta: DVector::from_fn(m, |_, _| rng.range(-0.3, 0.3)),
        w: DMatrix::from_fn(m, n, |_, _| rng.range(-1.0, 1.0)),
    };
    // Targets from a reference point partly outside the constraints, plus small noise
    // (moderate residual at the optimum, as in tracking NMPC).
    let z_ref = DVector::from_fn(n, |i, _| if i % 2 == 0 { 0.8 } else { -0.2 });
    let mut r0 = vec![0.0; m];
    prob.residuals(z_ref.as_slice(), &mut r0);
    for (yi, ri) in prob.y.iter_mut().zip(&r0) {
        *yi = ri + rng.range(-0.05, 0.05);
    }
    let cons = Constraints {
        zl: DVector::from_element(n, -0.5),
        zu: DVector::from_element(n, 0.5),
        a: DMatrix::from_fn(n, n, |i, j| if j <= i { 1.0 } else { 0.0 }),
        bl: DVector::from_element(n, -1.0),
        bu: DVector::from_element(n, 1.0),
    };
    let mut sqp = Sqp::new(n, m, n, SqpSettings::default()).unwrap();
    let z0 = DVector::zeros(n);
    let mut z = z0.clone();
    let info = sqp.solve(&mut prob, &cons, &mut z);
    eprintln!("sqp n={n} m={m} p={n} cold: {info:?}");
    let z_opt = z.clone();
    c.bench_function("sqp_nl_n6_m18_p6_cold", |b| {
        b.iter(|| {
            z.copy_from(&z0);
            black_box(sqp.solve(&mut prob, &cons, &mut z))
        })
    });
    // Warm start near the optimum (typical receding-horizon situation).
    let z_warm = z_opt.map(|v| 0.97 * v);
    let mut zw = z_warm.clone();
    let info = sqp.solve(&mut prob, &cons, &mut zw);
    eprintln!("sqp warm: {info:?}");
    c.bench_function("sqp_nl_n6_m18_p6_warm", |b| {
        b.iter(|| {
            zw.copy_from(&z_warm);
            black_box(sqp.solve(&mut prob, &cons, &mut zw))
        })
    });
}

criterion_group!(benches, bench_qp, bench_sqp);
criterion_main!(benches);
