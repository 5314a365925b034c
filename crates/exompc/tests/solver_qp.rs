//! Tests of the dense Goldfarb–Idnani QP solver against Clarabel and independent KKT checks.

use clarabel::solver::{DefaultSolver, IPSolver, SolverStatus, SupportedConeT};
use exompc::solver::qp::{DenseQp, QpSettings, QpStatus};
use nalgebra::{DMatrix, DVector};
use proptest::prelude::*;

mod common;
use common::Rng;

struct Qp {
    h: DMatrix<f64>,
    g: DVector<f64>,
    lb: DVector<f64>,
    ub: DVector<f64>,
    a: DMatrix<f64>,
    bl: DVector<f64>,
    bu: DVector<f64>,
}

fn random_qp(rng: &mut Rng) -> Qp {
    let n = 1 + rng.below(12);
    let m = rng.below(2 * n + 1);
    let k = n + rng.below(n + 1);
    let mm = DMatrix::from_fn(k, n, |_, _| rng.range(-1.0, 1.0));
    let mut h = mm.transpose() * &mm;
    for i in 0..n {
        h[(i, i)] += 0.05 + rng.unif();
    }
    let g = DVector::from_fn(n, |_, _| rng.range(-10.0, 10.0));
    // Feasible point x0, bounds around it (some infinite, some tight).
    let x0 = DVector::from_fn(n, |_, _| rng.range(-1.0, 1.0));
    let mut lb = DVector::zeros(n);
    let mut ub = DVector::zeros(n);
    for i in 0..n {
        lb[i] = if rng.unif() < 0.2 {
            f64::NEG_INFINITY
        } else {
            x0[i] - rng.range(0.0, 1.0)
        };
        ub[i] = if rng.unif() < 0.2 {
            f64::INFINITY
        } else {
            x0[i] + rng.range(0.0, 1.0)
        };
    }
    let a = DMatrix::from_fn(m, n, |_, _| rng.range(-1.0, 1.0));
    let ax = &a * &x0;
    let mut bl = DVector::zeros(m);
    let mut bu = DVector::zeros(m);
    let mut n_eq = 0;
    for j in 0..m {
        let c = rng.unif();
        if c < 0.1 && n_eq + 1 < n {
            n_eq += 1;
            bl[j] = ax[j];
            bu[j] = ax[j];
        } else {
            bl[j] = if c < 0.4 {
                f64::NEG_INFINITY
            } else {
                ax[j] - rng.range(0.0, 0.5)
            };
            bu[j] = if c > 0.8 {
                f64::INFINITY
            } else {
                ax[j] + rng.range(0.0, 0.5)
            };
        }
    }
    Qp {
        h,
        g,
        lb,
        ub,
        a,
        bl,
        bu,
    }
}

/// Reference solution from Clarabel (interior point, tight tolerances).
fn clarabel_solve(p: &Qp) -> (Vec<f64>, f64) {
    let n = p.g.len();
    let m = p.a.nrows();
    let pm = common::clarabel_upper(&p.h);
    // Rows: equalities first (zero cone), then inequalities Gx ≤ h (nonnegative cone).
    let mut eq_rows: Vec<(Vec<f64>, f64)> = vec![];
    let mut in_rows = common::box_rows(p.lb.as_slice(), p.ub.as_slice());
    for j in 0..m {
        let row: Vec<f64> = (0..n).map(|c| p.a[(j, c)]).collect();
        if p.bl[j] == p.bu[j] {
            eq_rows.push((row, p.bu[j]));
            continue;
        }
        if p.bu[j].is_finite() {
            in_rows.push((row.clone(), p.bu[j]));
        }
        if p.bl[j].is_finite() {
            in_rows.push((row.iter().map(|v| -v).collect(), -p.bl[j]));
        }
    }
    let (neq, nin) = (eq_rows.len(), in_rows.len());
    let all_rows = || eq_rows.iter().chain(in_rows.iter());
    let b: Vec<f64> = all_rows().map(|(_, rhs)| *rhs).collect();
    let am = common::clarabel_rows(all_rows().map(|(row, _)| row.as_slice()), n);
    let mut cones = vec![];
    if neq > 0 {
        cones.push(SupportedConeT::ZeroConeT(neq));
    }
    if nin > 0 {
        cones.push(SupportedConeT::NonnegativeConeT(nin));
    }
    let settings = common::clarabel_settings();
    let mut solver = DefaultSolver::new(&pm, p.g.as_slice(), &am, &b, &cones, settings).unwrap();
    solver.solve();
    let st = solver.solution.status;
    assert!(
        matches!(st, SolverStatus::Solved | SolverStatus::AlmostSolved),
        "clarabel status {st:?}"
    );
    (solver.solution.x.clone(), solver.solution.obj_val)
}

/// Independent KKT check of (x, λ) with tolerance `tol`.
fn check_kkt(p: &Qp, x: &DVector<f64>, lb_: &DVector<f64>, lg: &DVector<f64>, tol: f64) {
    let n = x.len();
    let stat = &p.h * x + &p.g + lb_ + p.a.transpose() * lg;
    assert!(stat.amax() < tol, "stationarity {}", stat.amax());
    let ax = &p.a * x;
    let scale = 1.0 + x.amax();
    for i in 0..n {
        assert!(x[i] >= p.lb[i] - tol && x[i] <= p.ub[i] + tol, "box {i}");
        let l = lb_[i];
        if l < 0.0 {
            assert!(
                ((x[i] - p.lb[i]) * l).abs() < tol * scale,
                "box compl lo {i}"
            );
        } else if l > 0.0 {
            assert!(
                ((p.ub[i] - x[i]) * l).abs() < tol * scale,
                "box compl hi {i}"
            );
        }
    }
    for j in 0..ax.len() {
        assert!(ax[j] >= p.bl[j] - tol && ax[j] <= p.bu[j] + tol, "row {j}");
        let l = lg[j];
        if l < 0.0 {
            assert!(
                ((ax[j] - p.bl[j]) * l).abs() < tol * scale,
                "row compl lo {j}"
            );
        } else if l > 0.0 {
            assert!(
                ((p.bu[j] - ax[j]) * l).abs() < tol * scale,
                "row compl hi {j}"
            );
        }
    }
}

fn solve(p: &Qp) -> (DenseQp, exompc::solver::QpInfo, DVector<f64>) {
    let n = p.g.len();
    let mut qp = DenseQp::new(n, p.a.nrows());
    let mut x = DVector::zeros(n);
    let info = qp.solve(&p.h, &p.g, &p.lb, &p.ub, &p.a, &p.bl, &p.bu, &mut x);
    (qp, info, x)
}

#[test]
fn solver_qp_matches_clarabel_random() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut total_active = 0;
    for case in 0..250 {
        let p = random_qp(&mut rng);
        let (qp, info, x) = solve(&p);
        assert_eq!(info.status, QpStatus::Solved, "case {case}");
        total_active += qp.num_active();
        let (xc, objc) = clarabel_solve(&p);
        let xc = DVector::from_vec(xc);
        let err = (&x - &xc).amax();
        assert!(err < 1e-6, "case {case}: |x - x_clarabel| = {err}");
        assert!(
            (info.objective - objc).abs() < 1e-6 * (1.0 + objc.abs()),
            "case {case}: objective {} vs {objc}",
            info.objective
        );
        check_kkt(&p, &x, qp.multipliers_box(), qp.multipliers_general(), 1e-8);
    }
    // Make sure the instances exercise the active-set logic.
    assert!(total_active > 500, "only {total_active} active constraints");
}

#[test]
fn solver_qp_reuse_workspace_same_answer() {
    let mut rng = Rng(42);
    let p = random_qp(&mut rng);
    let (mut qp, info, x) = solve(&p);
    let mut x2 = DVector::from_element(x.len(), 123.0);
    let info2 = qp.solve(&p.h, &p.g, &p.lb, &p.ub, &p.a, &p.bl, &p.bu, &mut x2);
    assert_eq!(info, info2);
    assert_eq!(x, x2);
}

fn simple_infeasible() -> Qp {
    // x1 + x2 ≥ 3 with 0 ≤ x ≤ 1.
    Qp {
        h: DMatrix::identity(2, 2),
        g: DVector::from_vec(vec![1.0, -1.0]),
        lb: DVector::zeros(2),
        ub: DVector::from_element(2, 1.0),
        a: DMatrix::from_row_slice(1, 2, &[1.0, 1.0]),
        bl: DVector::from_element(1, 3.0),
        bu: DVector::from_element(1, f64::INFINITY),
    }
}

#[test]
fn solver_qp_infeasible() {
    let p = simple_infeasible();
    assert_eq!(solve(&p).1.status, QpStatus::Infeasible);
    // Crossed box bounds.
    let mut p = simple_infeasible();
    p.bl[0] = f64::NEG_INFINITY;
    p.lb[1] = 2.0;
    assert_eq!(solve(&p).1.status, QpStatus::Infeasible);
    // Two contradictory general rows.
    let p = Qp {
        h: DMatrix::identity(3, 3),
        g: DVector::zeros(3),
        lb: DVector::from_element(3, f64::NEG_INFINITY),
        ub: DVector::from_element(3, f64::INFINITY),
        a: DMatrix::from_row_slice(2, 3, &[1.0, 1.0, 0.0, 1.0, 1.0, 0.0]),
        bl: DVector::from_vec(vec![2.0, f64::NEG_INFINITY]),
        bu: DVector::from_vec(vec![f64::INFINITY, 1.0]),
    };
    assert_eq!(solve(&p).1.status, QpStatus::Infeasible);
}

#[test]
fn solver_qp_non_finite_input() {
    let mut p = simple_infeasible();
    p.bl[0] = 0.5;
    assert_eq!(solve(&p).1.status, QpStatus::Solved);
    let mut q = Qp { ..p };
    q.h[(0, 1)] = f64::NAN;
    assert_eq!(solve(&q).1.status, QpStatus::NonFiniteInput);
    q.h[(0, 1)] = 0.0;
    q.g[1] = f64::INFINITY;
    assert_eq!(solve(&q).1.status, QpStatus::NonFiniteInput);
    q.g[1] = 0.0;
    q.lb[0] = f64::NAN;
    assert_eq!(solve(&q).1.status, QpStatus::NonFiniteInput);
    q.lb[0] = 0.0;
    q.a[(0, 0)] = f64::NEG_INFINITY;
    assert_eq!(solve(&q).1.status, QpStatus::NonFiniteInput);
    // Indefinite H.
    q.a[(0, 0)] = 1.0;
    q.h[(1, 1)] = -1.0;
    assert_eq!(solve(&q).1.status, QpStatus::NumericalError);
}

#[test]
fn solver_qp_equality_and_unconstrained() {
    // min ½|x|² − 1ᵀx s.t. x1 + x2 + x3 = 0 → x = 1 − 1 = 0 projected: x = (0, 0, 0)... check KKT.
    let p = Qp {
        h: DMatrix::identity(3, 3),
        g: DVector::from_vec(vec![-1.0, -2.0, -3.0]),
        lb: DVector::from_element(3, f64::NEG_INFINITY),
        ub: DVector::from_element(3, f64::INFINITY),
        a: DMatrix::from_row_slice(1, 3, &[1.0, 1.0, 1.0]),
        bl: DVector::zeros(1),
        bu: DVector::zeros(1),
    };
    let (qp, info, x) = solve(&p);
    assert_eq!(info.status, QpStatus::Solved);
    assert!((x - DVector::from_vec(vec![-1.0, 0.0, 1.0])).amax() < 1e-12);
    check_kkt(
        &p,
        &DVector::from_vec(vec![-1.0, 0.0, 1.0]),
        qp.multipliers_box(),
        qp.multipliers_general(),
        1e-12,
    );
    // Zero-dimensional problem.
    let mut qp0 = DenseQp::new(0, 0);
    let e = DVector::zeros(0);
    let info = qp0.solve(
        &DMatrix::zeros(0, 0),
        &e,
        &e,
        &e,
        &DMatrix::zeros(0, 0),
        &e,
        &e,
        &mut DVector::zeros(0),
    );
    assert_eq!(info.status, QpStatus::Solved);
}

#[test]
fn solver_qp_settings_validation() {
    assert!(QpSettings::default().validate().is_ok());
    let s = QpSettings {
        dependency_tolerance: -1.0,
        ..Default::default()
    };
    let err = s.validate().unwrap_err().to_string();
    assert!(err.contains("dependency_tolerance"), "{err}");
    let s = QpSettings {
        max_iterations: 0,
        ..Default::default()
    };
    assert!(DenseQp::with_settings(2, 1, s).is_err());
}

#[test]
fn solver_qp_max_iterations_status() {
    let mut rng = Rng(7);
    let mut p;
    loop {
        p = random_qp(&mut rng);
        let (qp, _, _) = solve(&p);
        if qp.num_active() >= 2 {
            break;
        }
    }
    let n = p.g.len();
    let s = QpSettings {
        max_iterations: 1,
        ..Default::default()
    };
    let mut qp = DenseQp::with_settings(n, p.a.nrows(), s).unwrap();
    let mut x = DVector::zeros(n);
    let info = qp.solve(&p.h, &p.g, &p.lb, &p.ub, &p.a, &p.bl, &p.bu, &mut x);
    assert_eq!(info.status, QpStatus::MaxIterations);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    /// Arbitrary finite (possibly indefinite, inconsistent) data never panics, and a `Solved`
    /// answer is feasible.
    #[test]
    fn solver_qp_never_panics(
        n in 1usize..6,
        m in 0usize..6,
        data in proptest::collection::vec(-1e3f64..1e3, 200),
        infs in proptest::collection::vec(0u8..6, 40),
    ) {
        let mut it = data.iter().cycle().copied();
        let h = DMatrix::from_fn(n, n, |_, _| it.next().unwrap());
        let h = if infs[0] < 3 { &h * h.transpose() } else { h };
        let g = DVector::from_fn(n, |_, _| it.next().unwrap());
        let mut inf_it = infs.iter().cycle().copied();
        let mut bound = |v: f64, s: f64| if inf_it.next().unwrap() == 0 { s * f64::INFINITY } else { v };
        let lb = DVector::from_fn(n, |_, _| bound(it.next().unwrap(), -1.0));
        let ub = DVector::from_fn(n, |_, _| bound(it.next().unwrap(), 1.0));
        let a = DMatrix::from_fn(m, n, |_, _| it.next().unwrap());
        let bl = DVector::from_fn(m, |_, _| bound(it.next().unwrap(), -1.0));
        let bu = DVector::from_fn(m, |_, _| bound(it.next().unwrap(), 1.0));
        let mut qp = DenseQp::new(n, m);
        let mut x = DVector::zeros(n);
        let info = qp.solve(&h, &g, &lb, &ub, &a, &bl, &bu, &mut x);
        if info.status == QpStatus::Solved {
            let ax = &a * &x;
            for i in 0..n {
                prop_assert!(x[i] >= lb[i] - 1e-6 * (1.0 + lb[i].abs()) && x[i] <= ub[i] + 1e-6 * (1.0 + ub[i].abs()));
            }
            for j in 0..m {
                prop_assert!(ax[j] >= bl[j] - 1e-6 * (1.0 + bl[j].abs()) && ax[j] <= bu[j] + 1e-6 * (1.0 + bu[j].abs()));
            }
        }
    }
}
