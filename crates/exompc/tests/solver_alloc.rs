//! Checks that `DenseQp::solve` and `Sqp::solve` do not allocate (counting global allocator,
//! per-thread counter so parallel tests do not interfere).

use exompc::solver::qp::{DenseQp, QpStatus};
use exompc::solver::sqp::{Constraints, LeastSquares, Sqp, SqpSettings, SqpStatus};
use nalgebra::{DMatrix, DVector};

mod common;
use common::alloc::{thread_allocations as allocs, Counting};

#[global_allocator]
static GLOBAL: Counting = Counting;

/// r(z) = (z − t) ∘ (1 + 0.1 z²) … written without allocation.
struct Prob {
    t: Vec<f64>,
}
impl LeastSquares for Prob {
    fn num_vars(&self) -> usize {
        self.t.len()
    }
    fn num_residuals(&self) -> usize {
        self.t.len()
    }
    fn residuals(&mut self, z: &[f64], r: &mut [f64]) -> bool {
        for i in 0..z.len() {
            r[i] = (z[i] - self.t[i]) * (1.0 + 0.1 * z[i] * z[i]);
        }
        true
    }
    fn residuals_jacobian(&mut self, z: &[f64], r: &mut [f64], j: &mut DMatrix<f64>) -> bool {
        self.residuals(z, r);
        j.fill(0.0);
        for i in 0..z.len() {
            j[(i, i)] = (1.0 + 0.1 * z[i] * z[i]) + (z[i] - self.t[i]) * 0.2 * z[i];
        }
        true
    }
}

#[test]
fn solver_solves_do_not_allocate() {
    let n = 6;
    let h = DMatrix::from_fn(n, n, |i, j| if i == j { 2.0 } else { 0.1 });
    let g = DVector::from_fn(n, |i, _| 3.0 * (i as f64 - 2.5));
    let lb = DVector::from_element(n, -1.0);
    let ub = DVector::from_element(n, 1.0);
    let a = DMatrix::from_fn(n, n, |i, j| if j <= i { 1.0 } else { 0.0 });
    let bl = DVector::from_element(n, -1.5);
    let bu = DVector::from_element(n, 1.5);
    let mut qp = DenseQp::new(n, n);
    let mut x = DVector::zeros(n);
    let before = allocs();
    let info = qp.solve(&h, &g, &lb, &ub, &a, &bl, &bu, &mut x);
    assert_eq!(allocs(), before, "DenseQp::solve allocated");
    assert_eq!(info.status, QpStatus::Solved);
    assert!(qp.num_active() > 0);

    let cons = Constraints {
        zl: lb.clone(),
        zu: ub.clone(),
        a: a.clone(),
        bl: bl.clone(),
        bu: bu.clone(),
    };
    let mut prob = Prob {
        t: vec![2.0, -2.0, 0.5, 0.3, -0.7, 1.2],
    };
    let mut sqp = Sqp::new(n, n, n, SqpSettings::default()).unwrap();
    let mut z = DVector::from_element(n, 1.4); // infeasible: exercises the projection too
    let before = allocs();
    let info = sqp.solve(&mut prob, &cons, &mut z);
    assert_eq!(allocs(), before, "Sqp::solve allocated");
    assert_eq!(info.status, SqpStatus::Converged, "{info:?}");
}
