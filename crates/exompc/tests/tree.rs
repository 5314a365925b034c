//! The coupled scenario tree (paper eq. 12, shared first inputs) in structured form against the
//! dense condensed path:
//! * `TreeQp` (per-scenario Riccati + shared block) on random tree QPs vs `DenseQp` on the
//!   condensed QP built here, and the condensed-Hessian diagonal vs the explicit one;
//! * the coupled multi-stage NMPC, structured vs dense (Gauss–Newton), on random instances,
//!   1-DOF and 2-DOF, robust horizon 1 and > 1, with active rate and cumulative torque bounds;
//! * closed loops of the coupled controller, structured vs dense.

#![allow(clippy::needless_range_loop)]

mod common;

use common::{Condensed, Rng};
use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::control::{horizon_inputs, CoupledProblem, Measurement, TorqueLimits, TreeSqp};
use exompc::model::JointState;
use exompc::scenario::{intent, limits, nmpc_settings, prediction_model, Dof, OneDof, TwoDof};
use exompc::solver::{
    Constraints, HessianModel, LeastSquares, QpSettings, QpStatus, Sqp, SqpStatus, TreeQp,
};
use nalgebra::{DMatrix, DVector, SVector};

/// A random tree QP and its condensed dense form.
struct Instance {
    qp: TreeQp,
    dense: Condensed,
}

#[allow(clippy::too_many_arguments)]
fn random_tree(
    rng: &mut Rng,
    nx: usize,
    nu: usize,
    np: usize,
    nc: usize,
    nr: usize,
    ns: usize,
) -> Instance {
    let mut qp = TreeQp::new(nx, nu, np, nc, nr, ns, QpSettings::default()).unwrap();
    for v in qp.a.iter_mut() {
        *v = rng.uniform(-0.6, 0.6);
    }
    for k in 0..ns * np {
        for i in 0..nx {
            qp.a[k * nx * nx + i * nx + i] += 0.5;
        }
    }
    for v in qp.b.iter_mut() {
        *v = rng.uniform(-1.0, 1.0);
    }
    let psd = |rng: &mut Rng, n: usize, shift: f64, rank: usize| {
        let l = DMatrix::from_fn(n, rank, |_, _| rng.uniform(-1.0, 1.0));
        &l * l.transpose() + DMatrix::identity(n, n) * shift
    };
    for k in 0..ns * np {
        let qm = psd(rng, nx, 0.0, nx.saturating_sub(1).max(1));
        qp.q[k * nx * nx..(k + 1) * nx * nx].copy_from_slice(qm.as_slice());
    }
    for k in 0..nr {
        let rm = psd(rng, nu, 0.1, nu);
        qp.r_shared[k * nu * nu..(k + 1) * nu * nu].copy_from_slice(rm.as_slice());
    }
    for k in 0..ns * (nc - nr) {
        let rm = psd(rng, nu, 0.1, nu);
        qp.r[k * nu * nu..(k + 1) * nu * nu].copy_from_slice(rm.as_slice());
    }
    for v in qp.g.iter_mut() {
        *v = rng.uniform(-3.0, 3.0);
    }
    let len = qp.len();
    let nv = qp.num_inputs();
    for k in 0..nv {
        qp.lo[k] = rng.uniform(-1.0, -0.1);
        qp.hi[k] = rng.uniform(0.1, 1.0);
    }
    let mut rows = vec![];
    for i in 0..ns {
        for j in 1..=np {
            let x = qp.x_index(i, j, (i + j) % nx);
            qp.lo[x] = rng.uniform(-1.5, -0.2);
            qp.hi[x] = rng.uniform(0.2, 1.5);
            rows.push(x);
        }
    }
    // Condense: T maps the inputs to the trajectory.
    let mut t = DMatrix::zeros(len, nv);
    for k in 0..nv {
        t[(k, k)] = 1.0;
        for i in 0..ns {
            let mut x = DVector::zeros(nx);
            for j in 0..np {
                let ao = (i * np + j) * nx * nx;
                let aj = DMatrix::from_column_slice(nx, nx, &qp.a[ao..ao + nx * nx]);
                let mut xn = &aj * &x;
                if j < nc {
                    let bo = (i * nc + j) * nx * nu;
                    let bj = DMatrix::from_column_slice(nx, nu, &qp.b[bo..bo + nx * nu]);
                    let u = DVector::from_fn(nu, |c, _| t[(qp.u_index(i, j, c), k)]);
                    xn += bj * u;
                }
                for c in 0..nx {
                    t[(qp.x_index(i, j + 1, c), k)] = xn[c];
                }
                x = xn;
            }
        }
    }
    let mut w = DMatrix::zeros(len, len);
    let put = |w: &mut DMatrix<f64>, at: usize, m: &[f64], n: usize| {
        for c in 0..n {
            for r in 0..n {
                w[(at + r, at + c)] = m[c * n + r];
            }
        }
    };
    for j in 0..nr {
        put(
            &mut w,
            qp.u_index(0, j, 0),
            &qp.r_shared[j * nu * nu..(j + 1) * nu * nu],
            nu,
        );
    }
    for i in 0..ns {
        for j in nr..nc {
            let k = i * (nc - nr) + j - nr;
            put(
                &mut w,
                qp.u_index(i, j, 0),
                &qp.r[k * nu * nu..(k + 1) * nu * nu],
                nu,
            );
        }
        for j in 1..=np {
            let k = i * np + j - 1;
            put(
                &mut w,
                qp.x_index(i, j, 0),
                &qp.q[k * nx * nx..(k + 1) * nx * nx],
                nx,
            );
        }
    }
    let dense = Condensed::new(&t, &w, &qp.g, &qp.lo, &qp.hi, rows);
    Instance { qp, dense }
}

#[test]
fn tree_qp_matches_dense_qp_on_random_tree_qps() {
    let mut rng = Rng::new(31);
    let mut total_active = 0;
    for (case, &(nx, nu, np, nc, nr, ns)) in [
        (2, 1, 3, 3, 1, 2),
        (3, 1, 8, 5, 2, 3),
        (3, 1, 6, 4, 4, 3),
        (4, 2, 10, 10, 3, 4),
        (6, 2, 20, 12, 1, 9),
        (6, 2, 12, 12, 4, 5),
        (3, 1, 5, 5, 1, 1),
    ]
    .iter()
    .cycle()
    .take(35)
    .enumerate()
    {
        let mut inst = random_tree(&mut rng, nx, nu, np, nc, nr, ns);
        let maxdiag = inst.qp.max_condensed_diagonal();
        let want = (0..inst.dense.h.nrows())
            .map(|k| inst.dense.h[(k, k)])
            .fold(f64::NEG_INFINITY, f64::max);
        assert!(
            (maxdiag - want).abs() <= 1e-10 * want.abs(),
            "case {case}: max diag {maxdiag} vs {want}"
        );
        let info = inst.qp.solve();
        assert_eq!(info.status, QpStatus::Solved, "case {case}");
        common::assert_matches_dense(
            case,
            &inst.dense,
            inst.qp.solution(),
            inst.qp.multipliers(),
            info.objective,
        );
        total_active += inst.qp.num_active();
    }
    eprintln!("active bounds over all cases: {total_active}");
    assert!(total_active > 35, "too few active bounds: {total_active}");
}

/// Random coupled instances (`ns` payload scenarios, horizon `n`, robust horizon `nr`) for a
/// `D`-DOF scenario, half built to hit the limits: the tree SQP against the dense coupled SQP
/// (Gauss–Newton), both from a zero warm start. Returns (active rate bounds, active cumulative
/// bounds) at the solutions.
fn compare_coupled<D: Dof<N>, const N: usize>(
    n: usize,
    nr: usize,
    ns: usize,
    seed: u64,
) -> (usize, usize) {
    let mut s = Experiment::default();
    s.controller.np = n;
    s.controller.nc = n;
    let mut st = nmpc_settings(&s);
    st.sqp.hessian = HessianModel::GaussNewton;
    st.sqp.max_iterations = 200;
    let models: Vec<_> = (0..ns)
        .map(|i| prediction_model::<D, N>(&s, 3.0 * i as f64 / ns as f64))
        .collect();
    let lim: TorqueLimits = limits(&s);
    let int = intent(&s);
    let mut prob = CoupledProblem::new(&models, &st, nr);
    let nv = prob.num_vars();
    let p = ns * N * n;
    let mut dense = Sqp::new(nv, prob.num_residuals(), p, st.sqp).unwrap();
    let mut cons = Constraints::unbounded(nv, p);
    let mut scratch = Constraints::unbounded(N * n, N * n);
    let mut tree = TreeSqp::<N>::new(&st, nr, ns).unwrap();
    assert_eq!(tree.num_vars(), nv);
    let mut rng = Rng::new(seed);
    let (mut rate_active, mut cum_active, mut stalled) = (0, 0, 0);
    for k in 0..16 {
        let hard = k % 2 == 1;
        let q = SVector::<f64, N>::from_fn(|_, _| rng.uniform(-1.0, 1.0));
        let qd = SVector::<f64, N>::from_fn(|_, _| rng.uniform(-3.0, 3.0));
        let span = if hard { 200.0 } else { 20.0 };
        let force = SVector::<f64, N>::from_fn(|_, _| rng.uniform(-span, span));
        let t_prev = SVector::<f64, N>::from_fn(|_, _| {
            if hard && k % 4 == 1 {
                if rng.uniform(0.0, 1.0) < 0.5 {
                    rng.uniform(25.0, 30.0)
                } else {
                    rng.uniform(-30.0, -25.0)
                }
            } else {
                rng.uniform(-30.0, 30.0)
            }
        });
        let m = Measurement {
            t: 0.0,
            q,
            qd,
            force,
        };
        let inputs: Vec<_> = models
            .iter()
            .map(|model| {
                let d = SVector::<f64, N>::from_fn(|_, _| rng.uniform(-2.0, 2.0));
                horizon_inputs(&int, model, &m, d)
            })
            .collect();
        // Probabilities, one of them at the floor on some instances.
        let mut w: Vec<f64> = (0..ns).map(|_| rng.uniform(0.05, 1.0)).collect();
        if k % 3 == 0 {
            w[k % ns] = 1e-4;
        }
        let sum: f64 = w.iter().sum();
        w.iter_mut().for_each(|v| *v /= sum);
        let x0 = JointState { q, qd };
        prob.set_step(x0, t_prev, &inputs, &w);
        prob.write_constraints(&lim, &mut cons, &mut scratch);
        let mut za = DVector::zeros(nv);
        let mut zb = DVector::zeros(nv);
        let a = dense.solve(&mut prob, &cons, &mut za);
        let b = tree.solve(prob.scenarios(), prob.weights(), &lim, &mut zb);
        let diff = (&za - &zb).amax();
        if a.status != SqpStatus::Converged || b.status != SqpStatus::Converged {
            eprintln!(
                "{N}-DOF n={n} nr={nr} S={ns} case {k}: {:?}/{:?} after {}/{} iterations, \
                 |Δz| = {diff:e}",
                a.status, b.status, a.iterations, b.iterations
            );
            stalled += 1;
            continue;
        }
        assert_eq!(
            a.iterations, b.iterations,
            "{N}-DOF n={n} nr={nr} S={ns} case {k}"
        );
        assert!(
            diff <= 1e-8,
            "{N}-DOF n={n} nr={nr} S={ns} case {k}: |z_dense − z_tree| = {diff:e}"
        );
        for v in za.iter() {
            if (v.abs() - lim.rate).abs() < 1e-9 {
                rate_active += 1;
            }
        }
        let sh = N * nr;
        let pr = N * (n - nr);
        for i in 0..ns {
            let mut acc = t_prev;
            for j in 0..n {
                for c in 0..N {
                    let idx = if j < nr {
                        j * N + c
                    } else {
                        sh + i * pr + (j - nr) * N + c
                    };
                    acc[c] += za[idx];
                    if (acc[c].abs() - lim.max).abs() < 1e-9 {
                        cum_active += 1;
                    }
                }
            }
        }
    }
    assert!(
        stalled <= 2,
        "{N}-DOF n={n} nr={nr} S={ns}: {stalled} of 16 solves did not converge"
    );
    (rate_active, cum_active)
}

#[test]
fn tree_sqp_equals_dense_coupled_gauss_newton_on_random_instances() {
    let (mut rate, mut cum) = (0, 0);
    for (c, &(n, nr, ns)) in [(3, 1, 3), (6, 3, 3), (10, 1, 4), (12, 4, 3), (20, 2, 2)]
        .iter()
        .enumerate()
    {
        let (r, k) = compare_coupled::<TwoDof, 2>(n, nr, ns, 300 + c as u64);
        rate += r;
        cum += k;
        let (r, k) = compare_coupled::<OneDof, 1>(n, nr, ns, 400 + c as u64);
        rate += r;
        cum += k;
    }
    eprintln!("active rate bounds {rate}, active cumulative bounds {cum}");
    assert!(rate > 10, "rate bounds never active: {rate}");
    assert!(cum > 10, "cumulative bounds never active: {cum}");
}

/// Closed loop of the default `D`-DOF scenario, coupled multi-stage NMPC with horizon `n` and
/// robust horizon `nr`, structured and dense (Gauss–Newton) each in its own loop: the largest
/// torque difference over `steps` steps.
fn coupled_closed_loop_diff<D: Dof<N>, const N: usize>(n: usize, nr: usize, steps: usize) -> f64 {
    let mut s = Experiment::default();
    s.controller.np = n;
    s.controller.nc = n;
    s.controller.sqp.hessian = HessianModel::GaussNewton.into();
    s.controller.sqp.max_iterations = 1000;
    s.controller.sqp.kkt_tolerance = 1e-10;
    s.multistage.formulation = Formulation::Coupled;
    s.multistage.robust_horizon = nr;
    common::dense_vs_structured_torque_diff::<D, N>(&s, ControllerKind::MSNMPC, steps)
}

#[test]
fn coupled_structured_closed_loops_equal_dense() {
    for (n, nr) in [(3, 1), (10, 1), (10, 3)] {
        let d = coupled_closed_loop_diff::<TwoDof, 2>(n, nr, 300);
        eprintln!("2-DOF coupled n={n} nr={nr}: max |ΔT| = {d:e}");
        assert!(d <= 1e-8, "2-DOF coupled n={n} nr={nr}: max |ΔT| = {d:e}");
    }
    for (n, nr) in [(10, 1), (10, 4)] {
        let d = coupled_closed_loop_diff::<OneDof, 1>(n, nr, 300);
        eprintln!("1-DOF coupled n={n} nr={nr}: max |ΔT| = {d:e}");
        assert!(d <= 1e-8, "1-DOF coupled n={n} nr={nr}: max |ΔT| = {d:e}");
    }
}
