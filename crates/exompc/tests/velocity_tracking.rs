//! The robust method's strap-space velocity residual (`[controller.robust] velocity_tracking`,
//! `control::VelocityTracking`): its metric against the strap model, its residuals and
//! Jacobian against an independent evaluation, and where the scenario layer uses it.

use exompc::config::{Experiment, Method};
use exompc::control::{velocity_metric, NmpcProblem, VelocityTracking};
use exompc::model::{JointState, Straps};
use exompc::scenario::{multistage_nmpc_settings, nmpc_settings, prediction_model, TwoDof};
use exompc::solver::LeastSquares;
use nalgebra::{DMatrix, SMatrix, Vector2};

#[test]
fn the_strap_metric_is_each_straps_stretch_rate_in_its_links_angle_units() {
    // Symbolic identity with the strap model of paper eqs. 3-4: with no stretch, the strap
    // forces are the damping term `cs J ė`, so `L ė = diag(J)⁻¹ F / cs`.
    for (ls1, ls2) in [(0.28, 0.16), (0.2, 0.3), (0.35, 0.05)] {
        let straps = Straps::two_dof(ls1, ls2, 937.5, 93.7);
        let l = velocity_metric(VelocityTracking::Strap, &straps.j);
        for e in [
            Vector2::new(1.0, 0.0),
            Vector2::new(0.0, 1.0),
            Vector2::new(-0.7, 2.3),
        ] {
            let f = straps.force(&Vector2::zeros(), &e);
            let want = Vector2::new(f[0] / (straps.damping * ls1), f[1] / (straps.damping * ls2));
            assert!(
                (l * e - want).norm() < 1e-12,
                "{ls1} {ls2} {e}: {} vs {want}",
                l * e
            );
        }
        // Thigh row: the hip alone; shank row: (Ls1/Ls2) e_hip + e_knee.
        assert_eq!(l[(0, 0)], 1.0);
        assert_eq!(l[(0, 1)], 0.0);
        assert!((l[(1, 0)] - ls1 / ls2).abs() < 1e-15);
        assert_eq!(l[(1, 1)], 1.0);
        assert_eq!(
            velocity_metric(VelocityTracking::Joint, &straps.j),
            SMatrix::<f64, 2, 2>::identity()
        );
    }
    // One joint: L = 1 (the 1-DOF knee is unchanged).
    let one = Straps::one_dof(0.16, 937.5, 93.7);
    assert_eq!(
        velocity_metric(VelocityTracking::Strap, &one.j),
        SMatrix::<f64, 1, 1>::identity()
    );
    // A lever that is not positive cannot be divided by: the identity.
    let bad = SMatrix::<f64, 2, 2>::new(0.0, 0.0, 0.28, 0.16);
    assert_eq!(
        velocity_metric(VelocityTracking::Strap, &bad),
        SMatrix::<f64, 2, 2>::identity()
    );
}

fn problem(tracking: VelocityTracking) -> NmpcProblem<2> {
    let mut s = Experiment::default();
    s.controller.np = 6;
    s.controller.nc = 4;
    let model = prediction_model::<TwoDof, 2>(&s, 1.0);
    let settings = exompc::control::NmpcSettings {
        velocity_tracking: tracking,
        ..nmpc_settings(&s)
    };
    let mut p = NmpcProblem::new(model, &settings);
    p.x0 = JointState {
        q: Vector2::new(0.3, -0.6),
        qd: Vector2::new(1.2, -2.0),
    };
    p.t_prev = Vector2::new(8.0, -3.0);
    p.inputs.q_h = Vector2::new(0.35, -0.5);
    p.inputs.qd_h = Vector2::new(0.9, -1.4);
    p
}

#[test]
fn strap_residuals_follow_the_metric_and_their_jacobian_is_exact() {
    let mut joint = problem(VelocityTracking::Joint);
    let mut strap = problem(VelocityTracking::Strap);
    let l = *strap.velocity_metric();
    assert_ne!(l, SMatrix::<f64, 2, 2>::identity());
    let (n, m) = (strap.num_vars(), strap.num_residuals());
    let z: Vec<f64> = (0..n).map(|k| 0.7 * ((k as f64) * 1.3).sin()).collect();
    let (mut rj, mut rs) = (vec![0.0; m], vec![0.0; m]);
    assert!(joint.residuals(&z, &mut rj));
    assert!(strap.residuals(&z, &mut rs));
    // Independent evaluation from the predicted trajectory: position rows equal, velocity rows
    // `√r_d L (qd − qd_ref)`, increment rows equal.
    let (xs, _) = strap.predict(&z);
    let sqrt_rd = nmpc_settings(&Experiment::default()).r_d.sqrt();
    for (j, x) in xs.iter().enumerate() {
        let base = j * 4;
        let ev = l * (x.qd - strap.inputs.qd_h);
        for a in 0..2 {
            assert_eq!(rs[base + a], rj[base + a]);
            assert!((rs[base + 2 + a] - sqrt_rd * ev[a]).abs() < 1e-12);
            assert!((rj[base + 2 + a] - sqrt_rd * (x.qd[a] - strap.inputs.qd_h[a])).abs() < 1e-12);
        }
    }
    assert_eq!(rs[xs.len() * 4..], rj[xs.len() * 4..]);
    // The Jacobian against central differences of the residuals (the oracle).
    let mut r = vec![0.0; m];
    let mut jac = DMatrix::zeros(m, n);
    assert!(strap.residuals_jacobian(&z, &mut r, &mut jac));
    assert_eq!(r, rs);
    let h = 1e-6;
    for k in 0..n {
        let (mut zp, mut zm) = (z.clone(), z.clone());
        zp[k] += h;
        zm[k] -= h;
        let (mut rp, mut rm) = (vec![0.0; m], vec![0.0; m]);
        assert!(strap.residuals(&zp, &mut rp));
        assert!(strap.residuals(&zm, &mut rm));
        for i in 0..m {
            let fd = (rp[i] - rm[i]) / (2.0 * h);
            assert!(
                (fd - jac[(i, k)]).abs() < 1e-6,
                "({i},{k}): {fd} vs {}",
                jac[(i, k)]
            );
        }
    }
}

#[test]
fn the_scenario_layer_gives_the_strap_metric_to_the_robust_multi_stage_nmpc_only() {
    let s = Experiment::default();
    assert_eq!(s.controller.method, Method::Robust);
    assert_eq!(
        multistage_nmpc_settings(&s).velocity_tracking,
        VelocityTracking::Strap
    );
    // The plain NMPC and the paper's method keep the paper's eq. 7.
    assert_eq!(nmpc_settings(&s).velocity_tracking, VelocityTracking::Joint);
    let mut paper = s.clone();
    paper.controller.method = Method::Paper;
    assert_eq!(
        multistage_nmpc_settings(&paper).velocity_tracking,
        VelocityTracking::Joint
    );
    let mut joint = s.clone();
    joint.controller.robust.velocity_tracking = VelocityTracking::Joint;
    assert_eq!(
        multistage_nmpc_settings(&joint).velocity_tracking,
        VelocityTracking::Joint
    );
}
