//! The structured (Riccati) QP and SQP path against the dense path and Clarabel:
//! * `RiccatiQp` on random stage QPs vs `DenseQp` on the condensed QP built here, and vs Clarabel;
//! * `NmpcCore` structured vs dense (Gauss–Newton Hessian) on random NMPC instances, 1-DOF and
//!   2-DOF, with active rate bounds and active cumulative torque bounds, several horizons;
//! * closed loops (plain NMPC and decoupled multi-stage NMPC) structured vs dense.

#![allow(clippy::needless_range_loop)]

mod common;

use clarabel::solver::{DefaultSolver, IPSolver, SolverStatus, SupportedConeT};
use common::{Condensed, Rng};
use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::control::{NmpcCore, NmpcSettings, QpBackend, TorqueLimits, VelocityTracking};
use exompc::scenario::{intent, limits, nmpc_settings, prediction_model, Dof, OneDof, TwoDof};
use exompc::solver::{HessianModel, QpSettings, QpStatus, RiccatiQp, SqpStatus};
use nalgebra::{DMatrix, SVector};

/// A random stage QP and its condensed dense form `(H, g, lb, ub, A, bl, bu)`.
struct Instance {
    qp: RiccatiQp,
    dense: Condensed,
}

fn random_instance(rng: &mut Rng, nx: usize, nu: usize, np: usize, nc: usize) -> Instance {
    let mut qp = RiccatiQp::new(nx, nu, np, nc, QpSettings::default()).unwrap();
    for v in qp.a.iter_mut() {
        *v = rng.uniform(-0.6, 0.6);
    }
    for j in 0..np {
        for i in 0..nx {
            qp.a[j * nx * nx + i * nx + i] += 0.5;
        }
    }
    for v in qp.b.iter_mut() {
        *v = rng.uniform(-1.0, 1.0);
    }
    // Q = LLᵀ (positive semidefinite, some rank deficiency), R = LLᵀ + 0.1 I.
    let psd = |rng: &mut Rng, n: usize, shift: f64, rank: usize| {
        let l = DMatrix::from_fn(n, rank, |_, _| rng.uniform(-1.0, 1.0));
        &l * l.transpose() + DMatrix::identity(n, n) * shift
    };
    for j in 0..np {
        let qm = psd(rng, nx, 0.0, nx.saturating_sub(1).max(1));
        qp.q[j * nx * nx..(j + 1) * nx * nx].copy_from_slice(qm.as_slice());
    }
    for j in 0..nc {
        let rm = psd(rng, nu, 0.1, nu);
        qp.r[j * nu * nu..(j + 1) * nu * nu].copy_from_slice(rm.as_slice());
    }
    for v in qp.g.iter_mut() {
        *v = rng.uniform(-3.0, 3.0);
    }
    // Bounds: inputs boxed (tight enough to bind), one state component boxed per stage.
    let rows = common::random_stage_bounds(&mut qp, rng, nx, nu, np, nc);
    // Condense: T maps u to the trajectory.
    let t = common::condensing_map(&qp, nx, nu, np, nc);
    let w = common::trajectory_hessian(&qp, nx, nu, np, nc);
    let dense = Condensed::new(&t, &w, &qp.g, &qp.lo, &qp.hi, rows);
    Instance { qp, dense }
}

fn clarabel(inst: &Instance) -> Vec<f64> {
    let n = inst.dense.g.len();
    let mut rows = common::box_rows(inst.dense.lb.as_slice(), inst.dense.ub.as_slice());
    for r in 0..inst.dense.a.nrows() {
        let row: Vec<f64> = (0..n).map(|c| inst.dense.a[(r, c)]).collect();
        rows.push((row.clone(), inst.dense.bu[r]));
        rows.push((row.iter().map(|v| -v).collect(), -inst.dense.bl[r]));
    }
    let am = common::clarabel_rows(rows.iter().map(|(row, _)| row.as_slice()), n);
    let b: Vec<f64> = rows.iter().map(|(_, rhs)| *rhs).collect();
    let cones = vec![SupportedConeT::NonnegativeConeT(rows.len())];
    let pm = common::clarabel_upper(&inst.dense.h);
    let settings = common::clarabel_settings();
    let mut solver =
        DefaultSolver::new(&pm, inst.dense.g.as_slice(), &am, &b, &cones, settings).unwrap();
    solver.solve();
    assert!(matches!(
        solver.solution.status,
        SolverStatus::Solved | SolverStatus::AlmostSolved
    ));
    solver.solution.x.clone()
}

#[test]
fn riccati_qp_matches_dense_qp_and_clarabel_on_random_stage_qps() {
    let mut rng = Rng::new(12);
    let mut total_active = 0;
    for (case, &(nx, nu, np, nc)) in [
        (2, 1, 3, 3),
        (3, 1, 8, 5),
        (4, 2, 10, 10),
        (6, 2, 20, 12),
        (6, 2, 30, 30),
    ]
    .iter()
    .cycle()
    .take(40)
    .enumerate()
    {
        let mut inst = random_instance(&mut rng, nx, nu, np, nc);
        let info = inst.qp.solve();
        assert_eq!(info.status, QpStatus::Solved, "case {case}");
        let nuv = nc * nu;
        let xs = &inst.qp.solution()[..nuv];
        let xd = common::assert_matches_dense(
            case,
            &inst.dense,
            inst.qp.solution(),
            inst.qp.multipliers(),
            info.objective,
        );
        let scale = 1.0 + xd.amax();
        let xc = clarabel(&inst);
        for k in 0..nuv {
            assert!(
                (xs[k] - xc[k]).abs() <= 1e-5 * scale,
                "case {case}: clarabel u[{k}] {} vs {}",
                xc[k],
                xs[k]
            );
        }
        total_active += inst.qp.num_active();
    }
    assert!(total_active > 40, "too few active bounds: {total_active}");
}

#[test]
fn riccati_qp_reports_infeasible_and_bad_data() {
    let mut rng = Rng::new(3);
    let mut inst = random_instance(&mut rng, 3, 1, 4, 4);
    // x bound that the inputs cannot reach: infeasible.
    let i = inst.qp.x_index(1, 1);
    inst.qp.lo[i] = 1e6;
    inst.qp.hi[i] = 2e6;
    assert_eq!(inst.qp.solve().status, QpStatus::Infeasible);
    inst.qp.lo[i] = 3.0;
    inst.qp.hi[i] = 1.0;
    assert_eq!(inst.qp.solve().status, QpStatus::Infeasible);
    inst.qp.lo[i] = f64::NAN;
    assert_eq!(inst.qp.solve().status, QpStatus::NonFiniteInput);
    inst.qp.lo[i] = -1.0;
    inst.qp.g[0] = f64::INFINITY;
    assert_eq!(inst.qp.solve().status, QpStatus::NonFiniteInput);
    inst.qp.g[0] = 0.0;
    for v in inst.qp.r.iter_mut() {
        *v = -1.0;
    }
    assert_eq!(inst.qp.solve().status, QpStatus::NumericalError);
}

fn settings_with(s: &Experiment, qp: QpBackend) -> NmpcSettings {
    let mut st = nmpc_settings(s);
    st.sqp.hessian = HessianModel::GaussNewton;
    // Gauss–Newton converges linearly on the hard instances: allow it to finish.
    st.sqp.max_iterations = 200;
    st.qp = qp;
    st
}

/// Random instances for a `D`-DOF scenario with horizon `n`; half built to hit the limits.
fn compare_random<D: Dof<N>, const N: usize>(
    n: usize,
    seed: u64,
    tracking: VelocityTracking,
) -> (usize, usize) {
    let mut s = Experiment::default();
    s.controller.np = n;
    s.controller.nc = n;
    let model = prediction_model::<D, N>(&s, 0.0);
    let lim: TorqueLimits = limits(&s);
    let int = intent(&s);
    let settings = |qp| NmpcSettings {
        velocity_tracking: tracking,
        ..settings_with(&s, qp)
    };
    let mut dense = NmpcCore::new(model, &settings(QpBackend::Dense)).unwrap();
    let mut st = NmpcCore::new(model, &settings(QpBackend::Structured)).unwrap();
    assert!(st.is_structured() && !dense.is_structured());
    let mut rng = Rng::new(seed);
    let (mut rate_active, mut cum_active) = (0, 0);
    let mut stalled = 0;
    for k in 0..24 {
        let hard = k % 2 == 1;
        let q = SVector::<f64, N>::from_fn(|_, _| rng.uniform(-1.0, 1.0));
        let qd = SVector::<f64, N>::from_fn(|_, _| rng.uniform(-3.0, 3.0));
        let force = SVector::<f64, N>::from_fn(|_, _| {
            if hard {
                rng.uniform(-200.0, 200.0)
            } else {
                rng.uniform(-20.0, 20.0)
            }
        });
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
        let (a, b) = common::solve_both_cold(
            &mut dense,
            &mut st,
            &model,
            &int,
            &lim,
            (q, qd),
            force,
            t_prev,
        );
        let (za, zb) = (dense.solution(), st.solution());
        let diff = (za - zb).amax();
        if a.status != SqpStatus::Converged || b.status != SqpStatus::Converged {
            // Gauss–Newton stalling near the tolerance (linear convergence on a flat valley):
            // the iterates are then determined only to the accuracy reached.
            eprintln!(
                "{N}-DOF n={n} case {k}: {:?}/{:?} after {}/{} iterations, |Δz| = {diff:e}",
                a.status, b.status, a.iterations, b.iterations
            );
            stalled += 1;
            continue;
        }
        assert_eq!(a.iterations, b.iterations, "{N}-DOF n={n} case {k}");
        assert!(
            diff <= 1e-8,
            "{N}-DOF n={n} case {k}: |z_dense − z_structured| = {diff:e}"
        );
        // Count active bounds at the solution.
        let mut acc = t_prev;
        for j in 0..n {
            for a in 0..N {
                if (za[j * N + a].abs() - lim.rate).abs() < 1e-9 {
                    rate_active += 1;
                }
                acc[a] += za[j * N + a];
                if (acc[a].abs() - lim.max).abs() < 1e-9 {
                    cum_active += 1;
                }
            }
        }
    }
    assert!(
        stalled <= 2,
        "{N}-DOF n={n}: {stalled} of 24 solves did not converge"
    );
    (rate_active, cum_active)
}

#[test]
fn structured_nmpc_equals_dense_gauss_newton_on_random_instances() {
    let mut rate = 0;
    let mut cum = 0;
    for (i, n) in [3usize, 10, 25].into_iter().enumerate() {
        let (r, c) = compare_random::<TwoDof, 2>(n, 100 + i as u64, VelocityTracking::Joint);
        rate += r;
        cum += c;
        let (r, c) = compare_random::<OneDof, 1>(n, 200 + i as u64, VelocityTracking::Joint);
        rate += r;
        cum += c;
        // The robust method's strap-space velocity residual (`Q_j`'s velocity block
        // `r_d LᵀL` is not diagonal in 2-DOF).
        let (r, c) = compare_random::<TwoDof, 2>(n, 300 + i as u64, VelocityTracking::Strap);
        rate += r;
        cum += c;
    }
    eprintln!("active rate bounds {rate}, active cumulative bounds {cum}");
    assert!(rate > 10, "rate bounds never active: {rate}");
    assert!(cum > 10, "cumulative bounds never active: {cum}");
}

/// Closed loop of the default 2-DOF scenario with horizon `n` and controller `kind`: the
/// structured and dense (Gauss–Newton) controllers, each in its own loop; returns the largest
/// torque difference over `steps` steps.
fn closed_loop_diff(kind: ControllerKind, formulation: Formulation, n: usize, steps: usize) -> f64 {
    let mut s = Experiment::default();
    s.controller.np = n;
    s.controller.nc = n;
    s.controller.sqp.hessian = HessianModel::GaussNewton.into();
    // Both solved to a KKT residual of 2e-9, which every step of the Np ≤ 10 loops attains
    // (at most 82 iterations a step for the NMPC and 291 for the three-scenario MS-NMPC at
    // Np = 10). At 1e-10 (the tolerance until issue 12's ninth pass) the Gauss–Newton SQP
    // stalled below its rounding floor on 4 of the 400 NMPC steps and 1 MS-NMPC step at
    // Np = 10 (1000 iterations, the iterates wandering within the Armijo slack), on main as
    // well, and the loops agreed only as long as both back-ends wandered alike; with 2e-9 they
    // agree to ~1e-11 N·m (docs/PERFORMANCE.md, ninth pass).
    s.controller.sqp.max_iterations = 1000;
    s.controller.sqp.kkt_tolerance = 2e-9;
    s.multistage.formulation = formulation;
    common::dense_vs_structured_torque_diff::<TwoDof, 2>(&s, kind, steps)
}

#[test]
fn structured_closed_loops_equal_dense() {
    // (controller, formulation, horizon, tolerance on the torque difference). Both back-ends
    // build the same QP (same Hessian regularisation) and take the same steps to ~1e-12. At
    // Np = Nc = 20 the Gauss–Newton SQP of the NMPC stalls on some steps of this loop (both
    // backends hit 1000 iterations without reaching the KKT tolerance, 1e-10 as well as 2e-9 or
    // 1e-8): the iterates then wander within the rounding floor of the KKT test, and the loops
    // drift apart by ~1e-7 N·m; the tolerance says so (docs/PERFORMANCE.md, closed-loop
    // agreement). With the exact Hessian
    // (`hessian = "exact"`) every step of the Np = 10 and 20 loops converges and they agree to
    // 1e-8 (tests/exact_hessian.rs).
    for (kind, formulation, n, tol) in [
        (ControllerKind::NMPC, Formulation::Decoupled, 3, 1e-8),
        (ControllerKind::NMPC, Formulation::Decoupled, 10, 1e-8),
        (ControllerKind::MSNMPC, Formulation::Decoupled, 3, 1e-8),
        (ControllerKind::MSNMPC, Formulation::Decoupled, 10, 1e-8),
        (ControllerKind::NMPC, Formulation::Decoupled, 20, 1e-6),
    ] {
        let d = closed_loop_diff(kind, formulation, n, 400);
        eprintln!("{kind:?} {formulation:?} n={n}: max |ΔT| = {d:e}");
        assert!(d <= tol, "{kind:?} {formulation:?} n={n}: max |ΔT| = {d:e}");
    }
}

/// `qp = "auto"` chooses the QP back-end only, and the run summary says what was chosen: the
/// default (2 joints × Nc = 3, dense, structured secant); Nc = 9 with `hessian = "auto"`
/// (structured, Gauss–Newton: the same torques as `qp = "structured"`); Nc = 9 with
/// `hessian = "structured_secant"`, which only the dense back-end runs (dense, secant: the
/// same torques as `qp = "dense"`); no `solver` for the PD.
#[test]
fn auto_qp_keeps_the_hessian_and_the_summary_reports_the_choice() {
    use exompc::control::SolverChoice;
    use exompc::solver::HessianModel as H;
    let run = |s: &Experiment| {
        let mut t = s.clone();
        t.timing.duration_2dof_s = 0.3;
        let mut trace = exompc::sim::TraceLog::<2>::default();
        let summary = exompc::scenario::run_experiment::<TwoDof, 2>(&t, &mut [&mut trace]).unwrap();
        let torques: Vec<_> = trace.rows.iter().map(|r| r.torque_robot).collect();
        (summary.solver, torques)
    };
    let choice = |qp, hessian| Some(SolverChoice { qp, hessian });
    let mut s = Experiment::default();
    assert_eq!(
        run(&s).0,
        choice(QpBackend::Dense, H::StructuredSecant),
        "the default"
    );
    s.controller.kind = ControllerKind::NMPC;
    s.controller.np = 9;
    s.controller.nc = 9;
    let (auto, auto_trace) = run(&s);
    assert_eq!(auto, choice(QpBackend::Structured, H::GaussNewton));
    s.controller.sqp.qp = QpBackend::Structured;
    assert_eq!(run(&s).1, auto_trace);
    s.controller.sqp.qp = QpBackend::Auto;
    s.controller.sqp.hessian = H::StructuredSecant.into();
    let (secant, secant_trace) = run(&s);
    assert_eq!(secant, choice(QpBackend::Dense, H::StructuredSecant));
    s.controller.sqp.qp = QpBackend::Dense;
    assert_eq!(run(&s).1, secant_trace);
    s.controller.kind = ControllerKind::PD;
    assert_eq!(run(&s).0, None);
}
