//! Estimator tests against independent oracles: a textbook linear Kalman filter written with
//! dynamic matrices, finite differences of the filter's own prediction, a direct Bayes
//! computation, invariants of the probability update (proptest), and scenario identification on
//! a simulated plant.

mod common;
use common::{robot_links, Rng};
use exompc::estimate::*;
use exompc::model::*;
use nalgebra::{DMatrix, DVector, SMatrix, SVector, Vector2, Vector4};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

fn robot(payload: f64, friction: Friction) -> RobotModel<2> {
    let mut links = robot_links();
    links[1] = links[1].with_point_mass(payload, 0.215);
    RobotModel {
        chain: Chain::new(links),
        viscous: 0.000899,
        coulomb: 0.05048,
        friction,
    }
}

const TANH: Friction = Friction::Tanh { width: 0.01 };

fn to_d<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> DMatrix<f64> {
    DMatrix::from_fn(R, C, |i, j| m[(i, j)])
}

fn max_rel_err(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    let scale = b.amax().max(1.0);
    (a - b).amax() / scale
}

// ---------------------------------------------------------------------------------------------
// Generic EKF vs an independent linear Kalman filter
// ---------------------------------------------------------------------------------------------

/// Textbook linear KF (standard covariance form), dynamic matrices.
struct LinearKf {
    x: DVector<f64>,
    p: DMatrix<f64>,
}

impl LinearKf {
    fn predict(&mut self, f: &DMatrix<f64>, q: &DMatrix<f64>) {
        self.x = f * &self.x;
        self.p = f * &self.p * f.transpose() + q;
    }
    /// Returns (v, S).
    fn update(
        &mut self,
        y: &DVector<f64>,
        h: &DMatrix<f64>,
        r: &DMatrix<f64>,
    ) -> (DVector<f64>, DMatrix<f64>) {
        let v = y - h * &self.x;
        let s = h * &self.p * h.transpose() + r;
        let k = &self.p * h.transpose() * s.clone().try_inverse().unwrap();
        self.x = &self.x + &k * &v;
        let n = self.x.len();
        self.p = (DMatrix::identity(n, n) - &k * h) * &self.p;
        (v, s)
    }
}

/// The linear test model: constant acceleration, two mixed measurements; `(F, H, Q, R, x0)`.
#[allow(clippy::type_complexity)]
fn linear_model() -> (
    SMatrix<f64, 3, 3>,
    SMatrix<f64, 2, 3>,
    SMatrix<f64, 3, 3>,
    SMatrix<f64, 2, 2>,
    SVector<f64, 3>,
) {
    let dt = 0.1;
    let f = SMatrix::<f64, 3, 3>::new(1.0, dt, 0.5 * dt * dt, 0.0, 1.0, dt, 0.0, 0.0, 1.0);
    let h = SMatrix::<f64, 2, 3>::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.5);
    let g = SMatrix::<f64, 3, 3>::new(0.3, 0.1, 0.0, 0.0, 0.2, 0.05, 0.1, 0.0, 0.4);
    let q = g * g.transpose() * 0.1;
    let r = SMatrix::<f64, 2, 2>::new(0.5, 0.1, 0.1, 0.3);
    (f, h, q, r, SVector::<f64, 3>::new(0.2, -0.1, 0.05))
}

#[test]
fn ekf_equals_linear_kalman_filter_on_linear_model() {
    let (f, h, q, r, x0) = linear_model();
    let p0 = SMatrix::<f64, 3, 3>::from_diagonal(&SVector::from([1.0, 0.5, 0.2]));

    let mut ekf = Ekf::<3, 2>::new(x0, p0, q, r);
    let mut kf = LinearKf {
        x: DVector::from_column_slice(x0.as_slice()),
        p: to_d(&p0),
    };
    let (fd, hd, qd, rd) = (to_d(&f), to_d(&h), to_d(&q), to_d(&r));
    let mut rng = Rng::new(7);
    let mut truth = SVector::<f64, 3>::new(0.0, 0.3, -0.2);
    for _ in 0..100 {
        truth = f * truth + SVector::from_fn(|_, _| rng.uniform(-0.05, 0.05));
        let y = h * truth + SVector::<f64, 2>::from_fn(|_, _| rng.uniform(-0.3, 0.3));

        let xn = f * ekf.state();
        ekf.predict(&xn, &f).unwrap();
        let y_pred = h * ekf.state();
        let stats = ekf.update(&y, &y_pred, &h).unwrap();

        kf.predict(&fd, &qd);
        let (v, s) = kf.update(&DVector::from_column_slice(y.as_slice()), &hd, &rd);

        assert!(
            max_rel_err(
                &to_d(ekf.state()),
                &DMatrix::from_column_slice(3, 1, kf.x.as_slice())
            ) < 1e-12
        );
        assert!(max_rel_err(&to_d(ekf.covariance()), &kf.p) < 1e-12);
        assert!(
            max_rel_err(
                &to_d(&stats.v),
                &DMatrix::from_column_slice(2, 1, v.as_slice())
            ) < 1e-12
        );
        assert!(max_rel_err(&to_d(&stats.s), &s) < 1e-12);
        let sinv = s.clone().try_inverse().unwrap();
        assert!(max_rel_err(&to_d(&stats.s_inv), &sinv) < 1e-12);
        assert!((stats.log_det_s - s.determinant().ln()).abs() < 1e-12);
        let m = (v.transpose() * &sinv * &v)[(0, 0)];
        assert!((stats.mahalanobis - m).abs() < 1e-12 * m.max(1.0));
        // P stays exactly symmetric.
        let p = ekf.covariance();
        assert_eq!(*p, p.transpose());
    }
}

/// `predict_holding` / `update_holding` (a state held out of the filter, as the MS-NMPC holds
/// `d̂` while it replays the gait) against the Schmidt–Kalman "consider" filter written with
/// dynamic matrices: `Q` without the held state's rows and columns, the gain's held row zeroed,
/// the Joseph-form covariance. The held state and its variance never move; with nothing held
/// the two calls are `predict` and `update`.
#[test]
fn ekf_holding_a_state_equals_the_consider_filter() {
    let (f, h, q, r, x0) = linear_model();
    let p0 = SMatrix::<f64, 3, 3>::new(1.0, 0.1, 0.2, 0.1, 0.5, 0.05, 0.2, 0.05, 0.4);
    let held = [false, false, true];

    let mut ekf = Ekf::<3, 2>::new(x0, p0, q, r);
    let (fd, hd, rd) = (to_d(&f), to_d(&h), to_d(&r));
    let mut qd = to_d(&q);
    for i in 0..3 {
        qd[(2, i)] = 0.0;
        qd[(i, 2)] = 0.0;
    }
    let mut x = to_d(&x0);
    let mut p = to_d(&p0);
    let mut rng = Rng::new(11);
    let mut truth = SVector::<f64, 3>::new(0.0, 0.3, -0.2);
    for _ in 0..100 {
        truth = f * truth + SVector::from_fn(|_, _| rng.uniform(-0.05, 0.05));
        let y = h * truth + SVector::<f64, 2>::from_fn(|_, _| rng.uniform(-0.3, 0.3));

        let xn = f * ekf.state();
        ekf.predict_holding(&xn, &f, &held).unwrap();
        let y_pred = h * ekf.state();
        ekf.update_holding(&y, &y_pred, &h, &held).unwrap();

        // The consider filter.
        x = &fd * &x;
        p = &fd * &p * fd.transpose() + &qd;
        let v = to_d(&y) - &hd * &x;
        let sm = &hd * &p * hd.transpose() + &rd;
        let mut k = &p * hd.transpose() * sm.clone().try_inverse().unwrap();
        k.row_mut(2).fill(0.0);
        x = &x + &k * &v;
        // Its covariance in closed form: P_xx − K_x S K_xᵀ, P_xd − K_x (H P)_d, P_dd.
        let kx = k.rows(0, 2).into_owned();
        let hp = &hd * &p;
        let mut closed = p.clone();
        closed
            .view_mut((0, 0), (2, 2))
            .copy_from(&(p.view((0, 0), (2, 2)) - &kx * &sm * kx.transpose()));
        let xd = p.view((0, 2), (2, 1)) - &kx * hp.column(2);
        closed.view_mut((0, 2), (2, 1)).copy_from(&xd);
        closed.view_mut((2, 0), (1, 2)).copy_from(&xd.transpose());
        let ikh = DMatrix::identity(3, 3) - &k * &hd;
        p = &ikh * &p * ikh.transpose() + &k * &rd * k.transpose();
        assert!(
            max_rel_err(&p, &closed) < 1e-10,
            "Joseph form vs closed form"
        );

        assert!(max_rel_err(&to_d(ekf.state()), &x) < 1e-12);
        assert!(max_rel_err(&to_d(ekf.covariance()), &p) < 1e-12);
        assert_eq!(ekf.state()[2], x0[2], "the held state moved");
        assert!((ekf.covariance()[(2, 2)] - p0[(2, 2)]).abs() < 1e-15);
    }

    // Nothing held: the plain calls.
    let (mut a, mut b) = (
        Ekf::<3, 2>::new(x0, p0, q, r),
        Ekf::<3, 2>::new(x0, p0, q, r),
    );
    let y = SVector::<f64, 2>::new(0.4, -0.2);
    a.predict(&(f * x0), &f).unwrap();
    b.predict_holding(&(f * x0), &f, &[false; 3]).unwrap();
    let yp = h * a.state();
    a.update(&y, &yp, &h).unwrap();
    b.update_holding(&y, &yp, &h, &[false; 3]).unwrap();
    assert_eq!(a.state(), b.state());
    assert_eq!(a.covariance(), b.covariance());
}

#[test]
fn ekf_rejects_bad_steps_and_stays_unchanged() {
    let mut ekf = Ekf::<2, 1>::new(
        SVector::from([1.0, 2.0]),
        SMatrix::identity(),
        SMatrix::identity() * 0.1,
        SMatrix::identity() * 0.5,
    );
    let before = ekf;
    let h = SMatrix::<f64, 1, 2>::new(1.0, 0.0);
    let y = SVector::from([f64::NAN]);
    assert_eq!(
        ekf.update(&y, &SVector::from([0.0]), &h),
        Err(EkfError::NonFiniteInput)
    );
    assert_eq!(
        ekf.update(&SVector::from([f64::INFINITY]), &SVector::from([0.0]), &h),
        Err(EkfError::NonFiniteInput)
    );
    assert_eq!(
        ekf.predict(&SVector::from([f64::NAN, 0.0]), &SMatrix::identity()),
        Err(EkfError::NonFiniteInput)
    );
    assert_eq!(ekf, before);
    // Singular S: zero measurement noise and zero H.
    let mut ekf0 = Ekf::<2, 1>::new(
        SVector::from([1.0, 2.0]),
        SMatrix::identity(),
        SMatrix::zeros(),
        SMatrix::zeros(),
    );
    let before0 = ekf0;
    assert_eq!(
        ekf0.update(
            &SVector::from([1.0]),
            &SVector::from([0.0]),
            &SMatrix::zeros()
        ),
        Err(EkfError::SingularInnovation)
    );
    assert_eq!(ekf0, before0);
    // Overflowing covariance.
    let big = SMatrix::<f64, 2, 2>::identity() * 1e200;
    assert_eq!(
        ekf.predict(&SVector::from([0.0, 0.0]), &big),
        Err(EkfError::NonFiniteResult)
    );
    assert_eq!(ekf, before);
}

// ---------------------------------------------------------------------------------------------
// Scenario EKF: Jacobian vs finite differences
// ---------------------------------------------------------------------------------------------

fn scenario(payload: f64, opts: &EstimatorOptions) -> ScenarioEkf<2, 6, 4> {
    ScenarioEkf::new(
        robot(payload, TANH),
        &EkfSettings::default(),
        opts,
        &Vector2::new(0.1, -0.4),
        &Vector2::zeros(),
    )
    .unwrap()
}

#[test]
fn scenario_jacobian_matches_central_differences() {
    let mut rng = Rng::new(11);
    for substeps in [1usize, 3] {
        let opts = EstimatorOptions {
            substeps,
            ..Default::default()
        };
        let f = scenario(1.0, &opts);
        for _ in 0..20 {
            let x = SVector::<f64, 6>::from_fn(|i, _| match i {
                0 | 1 => rng.uniform(-1.0, 1.0),
                2 | 3 => {
                    // keep away from the tanh knee, where differences need tiny steps
                    // up to 20 rad/s: far beyond where num-dual's sinh/cosh tanh overflows
                    let v = rng.uniform(0.2, 20.0);
                    if rng.uniform(0.0, 1.0) < 0.5 {
                        -v
                    } else {
                        v
                    }
                }
                _ => rng.uniform(-3.0, 3.0),
            });
            let u = Vector2::new(rng.uniform(-20.0, 20.0), rng.uniform(-10.0, 10.0));
            let ti = Vector2::new(rng.uniform(-5.0, 5.0), rng.uniform(-5.0, 5.0));
            let (xn, jac) = f.predict_with_jacobian(&x, &u, &ti);
            let xf = f.predict(&x, &u, &ti);
            assert!((xn - xf).amax() < 1e-13, "dual and f64 predictions differ");
            let hstep = 1e-6;
            let mut fd = SMatrix::<f64, 6, 6>::zeros();
            for c in 0..6 {
                let mut xp = x;
                let mut xm = x;
                xp[c] += hstep;
                xm[c] -= hstep;
                let col = (f.predict(&xp, &u, &ti) - f.predict(&xm, &u, &ti)) / (2.0 * hstep);
                fd.set_column(c, &col);
            }
            let err = (jac - fd).amax();
            assert!(jac.iter().all(|v| v.is_finite()));
            assert!(
                err < 1e-6 * jac.amax().max(1.0),
                "substeps {substeps}: err {err}"
            );
            // Disturbance is a random walk: bottom block [0 0 I].
            for r in 4..6 {
                for c in 0..6 {
                    assert_eq!(jac[(r, c)], if r == c { 1.0 } else { 0.0 });
                }
            }
        }
    }
}

/// The hand-derived `F` of `predict_with_jacobian` equals the dual-number `F`
/// (`predict_with_jacobian_dual`) to rounding on random states, `d` columns and `[0 0 I]` rows
/// included, for one and two links, smooth and sign friction and several substep counts.
#[test]
fn scenario_jacobian_equals_dual_numbers() {
    fn run<const N: usize, const NA: usize, const NY: usize>(
        model: impl Fn(usize) -> RobotModel<N>,
        rng: &mut Rng,
    ) {
        for case in 0..300 {
            let opts = EstimatorOptions {
                substeps: 1 + case % 4,
                ..Default::default()
            };
            let q0 = SVector::<f64, N>::zeros();
            let f = ScenarioEkf::<N, NA, NY>::new(
                model(case),
                &EkfSettings::default(),
                &opts,
                &q0,
                &q0,
            )
            .unwrap();
            let x = SVector::<f64, NA>::from_fn(|i, _| match i / N {
                0 => rng.uniform(-2.0, 2.0),
                1 => rng.uniform(-8.0, 8.0),
                _ => rng.uniform(-3.0, 3.0),
            });
            let u = SVector::<f64, N>::from_fn(|_, _| rng.uniform(-20.0, 20.0));
            let ti = SVector::<f64, N>::from_fn(|_, _| rng.uniform(-5.0, 5.0));
            let (xa, ja) = f.predict_with_jacobian(&x, &u, &ti);
            let (xb, jb) = f.predict_with_jacobian_dual(&x, &u, &ti);
            let err = (ja - jb).amax();
            assert!(
                err <= 1e-12 * (1.0 + jb.amax()),
                "N = {N} case {case}: err {err:e}\n{ja}{jb}"
            );
            assert!(
                (xa - xb).amax() <= 1e-13 * (1.0 + xb.amax()),
                "N = {N} case {case}"
            );
            for r in 2 * N..NA {
                assert_eq!(xa[r], x[r]);
                for c in 0..NA {
                    assert_eq!(ja[(r, c)], if r == c { 1.0 } else { 0.0 });
                }
            }
        }
    }
    let friction = |case: usize| {
        if case % 5 == 4 {
            Friction::Sign
        } else {
            Friction::Tanh {
                width: [0.01, 0.1, 1.0][case % 3],
            }
        }
    };
    let mut rng = Rng::new(12);
    run::<2, 6, 4>(
        |case| robot([0.0, 1.0, 2.0, 3.0][case % 4], friction(case)),
        &mut rng,
    );
    run::<1, 3, 2>(
        |case| RobotModel {
            chain: Chain::new([robot_links()[1].with_point_mass(case as f64 % 3.0, 0.215)]),
            viscous: 0.000899,
            coulomb: 0.05048,
            friction: friction(case),
        },
        &mut rng,
    );
}

#[test]
fn scenario_prediction_is_rk4_of_the_robot_model() {
    // Oracle: the model crate's own acceleration (tanh friction) under RK4 with d added to tau.
    let opts = EstimatorOptions {
        substeps: 4,
        ..Default::default()
    };
    let f = scenario(2.0, &opts);
    let model = robot(2.0, TANH);
    let mut rng = Rng::new(5);
    for _ in 0..50 {
        let x = SVector::<f64, 6>::from_fn(|_, _| rng.uniform(-2.0, 2.0));
        let u = Vector2::new(rng.uniform(-20.0, 20.0), rng.uniform(-10.0, 10.0));
        let ti = Vector2::new(rng.uniform(-5.0, 5.0), rng.uniform(-5.0, 5.0));
        let tau = u + ti + Vector2::new(x[4], x[5]);
        let mut s = JointState {
            q: Vector2::new(x[0], x[1]),
            qd: Vector2::new(x[2], x[3]),
        };
        for _ in 0..4 {
            s = rk4_step(
                |_, s: &JointState<f64, 2>| JointState {
                    q: s.qd,
                    qd: model.acceleration(&s.q, &s.qd, &tau),
                },
                0.0,
                &s,
                0.0025,
            );
        }
        let xn = f.predict(&x, &u, &ti);
        let expect = [s.q[0], s.q[1], s.qd[0], s.qd[1], x[4], x[5]];
        for i in 0..6 {
            assert!(
                (xn[i] - expect[i]).abs() < 1e-12,
                "{i}: {} vs {}",
                xn[i],
                expect[i]
            );
        }
    }
}

#[test]
fn scenario_step_rejects_nonfinite_measurement() {
    let mut f = scenario(0.0, &EstimatorOptions::default());
    let before = *f.state();
    let p_before = *f.covariance();
    let y = Vector4::new(0.1, f64::NAN, 0.0, 0.0);
    assert_eq!(
        f.step(&y, &Vector2::zeros(), &Vector2::zeros()),
        Err(EkfError::NonFiniteInput)
    );
    let u = Vector2::new(f64::INFINITY, 0.0);
    assert!(f
        .step(&Vector4::new(0.1, -0.4, 0.0, 0.0), &u, &Vector2::zeros())
        .is_err());
    assert_eq!(*f.state(), before);
    assert_eq!(*f.covariance(), p_before);
    assert!(f.last_innovation().is_none());
}

#[test]
fn settings_defaults_and_validation() {
    let s = EkfSettings::default();
    assert!(s.validate().is_ok());
    let q = s.process_noise::<6>();
    assert_eq!(
        q.diagonal(),
        SVector::<f64, 6>::from([1e-8, 1e-8, 1e-4, 1e-4, 1e-2, 1e-2])
    );
    let r = s.measurement_noise::<4>();
    assert_eq!(
        r.diagonal(),
        SVector::<f64, 4>::from([1e-6, 1e-6, 1.0, 1.0])
    );
    let p0 = s.initial_covariance::<6>();
    assert_eq!(
        p0.diagonal(),
        SVector::<f64, 6>::from([1e-6, 1e-6, 1e-2, 1e-2, 1.0, 1.0])
    );
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(EkfSettings {
            r_velocity: bad,
            ..s
        }
        .validate()
        .is_err());
        assert!(EkfSettings {
            q_disturbance: bad,
            ..s
        }
        .validate()
        .is_err());
    }
    let o = EstimatorOptions::default();
    assert!(o.validate(3).is_ok());
    assert!(EstimatorOptions { floor: 0.34, ..o }.validate(3).is_err());
    assert!(EstimatorOptions { substeps: 0, ..o }.validate(3).is_err());
    assert!(EstimatorOptions { dt: 0.0, ..o }.validate(3).is_err());
    assert!(EstimatorOptions { c1: -1.0, ..o }.validate(3).is_err());
}

// ---------------------------------------------------------------------------------------------
// Probabilities (paper eqs. 10-11)
// ---------------------------------------------------------------------------------------------

fn check_distribution(p: &[f64], floor: f64) {
    let sum: f64 = p.iter().sum();
    assert!((sum - 1.0).abs() < 1e-12, "sum {sum} of {p:?}");
    for &x in p {
        assert!(x.is_finite(), "{p:?}");
        assert!(x >= floor, "{x} below floor {floor} in {p:?}");
    }
}

#[test]
fn probabilities_match_direct_bayes() {
    // Direct eq. 10 with moderate numbers (no underflow), then eq. 11 with no entry floored.
    let prev = [0.2, 0.5, 0.3];
    let ll = [-1.0, -2.5, 0.3];
    let mut out = [0.0; 3];
    update_probabilities(&prev, &ll, 1e-4, &mut out);
    let w: Vec<f64> = prev.iter().zip(ll).map(|(p, l)| p * l.exp()).collect();
    let s: f64 = w.iter().sum();
    for i in 0..3 {
        assert!((out[i] - w[i] / s).abs() < 1e-15);
    }
    // Equal likelihoods keep the prior.
    update_probabilities(&prev, &[5.0; 3], 1e-4, &mut out);
    for i in 0..3 {
        assert!((out[i] - prev[i]).abs() < 1e-15);
    }
    // Floor with renormalisation: one overwhelming scenario.
    update_probabilities(&[1.0 / 3.0; 3], &[0.0, -1e6, -1e300], 1e-4, &mut out);
    assert_eq!(out, [1.0 - 2e-4, 1e-4, 1e-4]);
    check_distribution(&out, 1e-4);
}

#[test]
fn log_likelihood_matches_eq10() {
    let s = SMatrix::<f64, 2, 2>::new(2.0, 0.3, 0.3, 0.5);
    let mut ekf = Ekf::<2, 2>::new(SVector::zeros(), s, SMatrix::zeros(), SMatrix::zeros());
    let v = Vector2::new(0.04, -0.02);
    let stats = ekf
        .update(&v, &Vector2::zeros(), &SMatrix::identity())
        .unwrap();
    let c1 = 100.0;
    let sinv = s.try_inverse().unwrap();
    let direct = (-0.5 * c1 * (v.transpose() * sinv * v)[(0, 0)]).exp()
        / ((2.0 * std::f64::consts::PI).powi(2) * (s * c1).determinant()).sqrt();
    assert!((stats.log_likelihood(c1) - direct.ln()).abs() < 1e-12);
}

fn special_ll() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(0.0),
        Just(1e-12),
        Just(-1e-12),
        Just(1e6),
        Just(-1e6),
        Just(1e200),
        Just(-1e200),
        Just(f64::MAX),
        Just(f64::MIN),
        Just(f64::INFINITY),
        Just(f64::NEG_INFINITY),
        Just(f64::NAN),
        -1e300f64..1e300,
        -50.0f64..50.0,
    ]
}

fn prior() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(0.0),
        Just(1e-300),
        Just(1e-4),
        Just(1.0),
        0.0f64..1.0,
        Just(f64::NAN),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    #[test]
    fn probabilities_sum_to_one_and_respect_floor(
        cases in prop::collection::vec((prior(), special_ll()), 1..7),
        floor_frac in 0.0f64..0.99,
    ) {
        let n = cases.len();
        let floor = floor_frac / n as f64 * 0.999;
        let prev: Vec<f64> = cases.iter().map(|c| c.0).collect();
        let ll: Vec<f64> = cases.iter().map(|c| c.1).collect();
        let mut out = vec![0.0; n];
        update_probabilities(&prev, &ll, floor, &mut out);
        check_distribution(&out, floor);
        // And with the default floor.
        let floor = 1e-4;
        update_probabilities(&prev, &ll, floor, &mut out);
        check_distribution(&out, floor);
    }

    #[test]
    fn probabilities_from_innovations_never_nan(
        sizes in prop::collection::vec(
            prop_oneof![Just(0.0), Just(1e-12), Just(1.0), Just(1e6), Just(1e200), 0.0f64..1e3],
            3,
        ),
        prior_seed in 0.0f64..1.0,
    ) {
        // Innovation statistics of real filter updates with innovations of the given size.
        let mut ll = [0.0; 3];
        for (i, &a) in sizes.iter().enumerate() {
            let mut ekf = Ekf::<2, 2>::new(
                SVector::zeros(),
                SMatrix::identity() * 1e-2,
                SMatrix::zeros(),
                SMatrix::identity(),
            );
            let stats = ekf
                .update(&Vector2::new(a, -a), &Vector2::zeros(), &SMatrix::identity())
                .unwrap();
            ll[i] = stats.log_likelihood(100.0);
            prop_assert!(!ll[i].is_nan());
        }
        let prev = [prior_seed.max(1e-4), 0.3, 1.0 - 0.3 - prior_seed.max(1e-4)].map(|p: f64| p.max(1e-4));
        let mut out = [0.0; 3];
        update_probabilities(&prev, &ll, 1e-4, &mut out);
        check_distribution(&out, 1e-4);
    }
}

// ---------------------------------------------------------------------------------------------
// Scenario identification on a simulated plant
// ---------------------------------------------------------------------------------------------

/// Run of the plant (sign friction, given payload, RK4 at 1 ms, torque held over each
/// 10 ms period), feeding exact measurements to a bank of the 0/1/2 kg scenarios.
/// Returns the probability history (every period) and the final bank.
fn identify(payload: f64, mode: Innovation, seconds: f64) -> (Vec<[f64; 3]>, EkfBank<2, 6, 4>) {
    let plant = robot(payload, Friction::Sign);
    let nominal = robot(0.0, TANH);
    let dt = 0.01;
    let sub = 10;
    let opts = EstimatorOptions {
        innovation: mode,
        ..Default::default()
    };
    let models: Vec<_> = [0.0, 1.0, 2.0].iter().map(|&m| robot(m, TANH)).collect();
    let mut q = Vector2::new(0.1, -0.3);
    let mut qd = Vector2::zeros();
    let mut bank: EkfBank<2, 6, 4> =
        EkfBank::new(&models, &EkfSettings::default(), &opts, &q, &qd).unwrap();
    let steps = (seconds / dt).round() as usize;
    let mut u_prev = nominal.chain.gravity_torque(&q);
    let zero = Vector2::zeros();
    let mut history = Vec::with_capacity(steps);
    let (mut qmax, mut qdmax) = (0.0f64, 0.0f64);
    for k in 0..steps {
        let t = k as f64 * dt;
        // Torque decided at t_k, held over [t_k, t_k+1).
        // Nominal gravity torque plus a stiff PD pull towards a swing-like reference (the
        // payload is unknown to it), so the motion stays in the range of a gait.
        let w = 2.0 * std::f64::consts::PI * 0.8;
        let q_ref = Vector2::new(0.1 + 0.3 * (w * t).sin(), -0.5 * (1.0 - (w * t).cos()));
        let e = q_ref - q;
        let u = nominal.chain.gravity_torque(&q)
            + Vector2::new(40.0 * e[0] - 4.0 * qd[0], 10.0 * e[1] - 0.5 * qd[1]);
        if k > 0 {
            let y = Vector4::new(q[0], q[1], qd[0], qd[1]);
            qmax = qmax.max(q.amax());
            qdmax = qdmax.max(qd.amax());
            bank.step(&y, &u_prev, &zero).unwrap();
            let p = bank.probabilities();
            history.push([p[0], p[1], p[2]]);
        }
        let mut s = JointState { q, qd };
        for _ in 0..sub {
            s = rk4_step(
                |_, s: &JointState<f64, 2>| JointState {
                    q: s.qd,
                    qd: plant.acceleration(&s.q, &s.qd, &u),
                },
                t,
                &s,
                dt / sub as f64,
            );
        }
        q = s.q;
        qd = s.qd;
        u_prev = u;
    }
    eprintln!("payload {payload}: max |q| {qmax:.2} rad, max |qd| {qdmax:.2} rad/s");
    (history, bank)
}

#[test]
fn matching_scenario_wins() {
    for (i, payload) in [0.0, 1.0, 2.0].into_iter().enumerate() {
        let (hist, bank) = identify(payload, Innovation::Standard, 5.0);
        for p in &hist {
            check_distribution(p, 1e-4);
        }
        let last = hist.last().unwrap();
        // Average over the final second as well, so a single lucky step does not pass.
        let tail = &hist[hist.len() - 100..];
        let avg: f64 = tail.iter().map(|p| p[i]).sum::<f64>() / tail.len() as f64;
        eprintln!(
            "payload {payload}: final {last:?}, tail mean of match {avg:.4}, d̂ {:?}",
            (0..3).map(|j| bank.disturbance(j)).collect::<Vec<_>>()
        );
        assert!(last[i] > 0.9, "payload {payload}: {last:?}");
        assert!(avg > 0.9, "payload {payload}: tail mean {avg}");
    }
}

#[test]
fn paper_innovation_runs_and_stays_a_distribution() {
    for payload in [0.0, 2.0] {
        let (hist, _) = identify(payload, Innovation::Paper, 2.0);
        eprintln!(
            "paper mode, payload {payload}: final {:?}",
            hist.last().unwrap()
        );
        for p in &hist {
            check_distribution(p, 1e-4);
        }
    }
}

#[test]
fn bank_failure_keeps_probabilities_and_reset_restores() {
    let models: Vec<_> = [0.0, 1.0, 2.0].iter().map(|&m| robot(m, TANH)).collect();
    let q0 = Vector2::new(0.1, -0.3);
    let mut bank: EkfBank<2, 6, 4> = EkfBank::new(
        &models,
        &EkfSettings::default(),
        &Default::default(),
        &q0,
        &Vector2::zeros(),
    )
    .unwrap();
    assert_eq!(bank.probabilities(), &[1.0 / 3.0; 3]);
    let u = robot(1.0, TANH).chain.gravity_torque(&q0);
    for _ in 0..20 {
        bank.step(&Vector4::new(0.1, -0.3, 0.0, 0.0), &u, &Vector2::zeros())
            .unwrap();
    }
    let probs = bank.probabilities().to_vec();
    let states: Vec<_> = bank.filters().iter().map(|f| *f.state()).collect();
    assert!(bank
        .step(
            &Vector4::new(f64::NAN, 0.0, 0.0, 0.0),
            &u,
            &Vector2::zeros()
        )
        .is_err());
    assert_eq!(bank.probabilities(), probs.as_slice());
    for (f, s) in bank.filters().iter().zip(&states) {
        assert_eq!(f.state(), s);
    }
    // The 1 kg scenario explains a leg held still by the 1 kg gravity torque.
    assert!(probs[1] > probs[0] && probs[1] > probs[2], "{probs:?}");
    assert!(bank.disturbance(1).amax() < bank.disturbance(0).amax());
    bank.reset();
    assert_eq!(bank.probabilities(), &[1.0 / 3.0; 3]);
    for f in bank.filters() {
        assert_eq!(
            f.state(),
            &SVector::<f64, 6>::from([0.1, -0.3, 0.0, 0.0, 0.0, 0.0])
        );
        assert!(f.last_innovation().is_none());
    }
}

#[test]
fn bank_rejects_empty_and_bad_floor() {
    let q0 = Vector2::zeros();
    assert!(matches!(
        EkfBank::<2, 6, 4>::new(&[], &EkfSettings::default(), &Default::default(), &q0, &q0),
        Err(EstimateError::NoScenario)
    ));
    let models = [robot(0.0, TANH), robot(1.0, TANH)];
    let opts = EstimatorOptions {
        floor: 0.5,
        ..Default::default()
    };
    assert!(EkfBank::<2, 6, 4>::new(&models, &EkfSettings::default(), &opts, &q0, &q0).is_err());
}
