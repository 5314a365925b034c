//! Model tests against independent oracles: the closed form of docs/MODEL.md, energy conservation,
//! the skew-symmetry identity, a direct payload computation and strap energy gradients.

mod common;
use common::{robot_links, Rng};
use exompc::model::*;
use nalgebra::{SMatrix, SVector, Vector1, Vector2, Vector3};

/// MODEL.md §1 closed form of the double pendulum.
fn closed_form(
    l: &[Link; 2],
    q: [f64; 2],
    qd: [f64; 2],
) -> (SMatrix<f64, 2, 2>, Vector2<f64>, Vector2<f64>) {
    let g = 9.81;
    let (m1, m2, c1, c2, l1, i1, i2) = (
        l[0].mass,
        l[1].mass,
        l[0].com,
        l[1].com,
        l[0].length,
        l[0].inertia,
        l[1].inertia,
    );
    let h = m2 * l1 * c2 * q[1].sin();
    let m11 = i1 + i2 + m1 * c1 * c1 + m2 * (l1 * l1 + c2 * c2 + 2.0 * l1 * c2 * q[1].cos());
    let m12 = i2 + m2 * (c2 * c2 + l1 * c2 * q[1].cos());
    let m22 = i2 + m2 * c2 * c2;
    let cmat = SMatrix::<f64, 2, 2>::new(-h * qd[1], -h * (qd[0] + qd[1]), h * qd[0], 0.0);
    let gv = Vector2::new(
        g * ((m1 * c1 + m2 * l1) * q[0].sin() + m2 * c2 * (q[0] + q[1]).sin()),
        g * m2 * c2 * (q[0] + q[1]).sin(),
    );
    (
        SMatrix::<f64, 2, 2>::new(m11, m12, m12, m22),
        cmat * Vector2::new(qd[0], qd[1]),
        gv,
    )
}

#[test]
fn two_link_chain_equals_spec_closed_form() {
    let mut rng = Rng::new(1);
    for _ in 0..500 {
        let links = [
            Link {
                length: rng.uniform(0.2, 0.6),
                mass: rng.uniform(0.5, 8.0),
                com: rng.uniform(0.05, 0.3),
                inertia: rng.uniform(0.01, 0.2),
            },
            Link {
                length: rng.uniform(0.2, 0.6),
                mass: rng.uniform(0.5, 8.0),
                com: rng.uniform(0.05, 0.3),
                inertia: rng.uniform(0.01, 0.2),
            },
        ];
        let chain = Chain::new(links);
        let q = [rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0)];
        let qd = [rng.uniform(-10.0, 10.0), rng.uniform(-10.0, 10.0)];
        let (m, cqd, g) = closed_form(&links, q, qd);
        let qv = Vector2::from(q);
        let qdv = Vector2::from(qd);
        let (m2, cqd2, g2) = chain.terms(&qv, &qdv);
        assert!((m - m2).abs().max() < 1e-12, "M {m} vs {m2}");
        assert!((cqd - cqd2).abs().max() < 1e-12, "Cqd {cqd} vs {cqd2}");
        assert!((g - g2).abs().max() < 1e-12, "G {g} vs {g2}");
        assert!((chain.mass_matrix(&qv) - m).abs().max() < 1e-12);
        assert!((chain.coriolis_matrix(&qv, &qdv) * qdv - cqd).abs().max() < 1e-12);
        assert!((chain.gravity_torque(&qv) - g).abs().max() < 1e-12);
        // Forward dynamics inverts M qdd + C qd + G = tau.
        let tau = Vector2::new(rng.uniform(-30.0, 30.0), rng.uniform(-30.0, 30.0));
        let qdd = chain.forward_dynamics(&qv, &qdv, &tau);
        assert!((m * qdd + cqd + g - tau).abs().max() < 1e-10);
    }
}

#[test]
fn one_link_chain_is_a_single_pendulum() {
    let l = Link {
        length: 0.43,
        mass: 1.2,
        com: 0.18,
        inertia: 0.018,
    };
    let chain = Chain::new([l]);
    let mut rng = Rng::new(2);
    for _ in 0..100 {
        let q = Vector1::new(rng.uniform(-3.0, 3.0));
        let qd = Vector1::new(rng.uniform(-10.0, 10.0));
        let (m, cqd, g) = chain.terms(&q, &qd);
        assert!((m[(0, 0)] - (l.inertia + l.mass * l.com * l.com)).abs() < 1e-14);
        assert_eq!(cqd[0], 0.0);
        assert!((g[0] - l.mass * 9.81 * l.com * q[0].sin()).abs() < 1e-14);
    }
}

fn energy_drift<const N: usize>(chain: &Chain<N>, q0: SVector<f64, N>) -> f64 {
    let mut x = JointState {
        q: q0,
        qd: SVector::<f64, N>::zeros(),
    };
    let e =
        |x: &JointState<f64, N>| chain.kinetic_energy(&x.q, &x.qd) + chain.potential_energy(&x.q);
    let e0 = e(&x);
    let scale = chain
        .links
        .iter()
        .map(|l| l.mass * 9.81 * l.length)
        .sum::<f64>();
    let mut worst: f64 = 0.0;
    let tau = SVector::<f64, N>::zeros();
    for k in 0..10_000 {
        x = rk4_step(
            |_t, s: &JointState<f64, N>| JointState {
                q: s.qd,
                qd: chain.forward_dynamics(&s.q, &s.qd, &tau),
            },
            k as f64 * 1e-3,
            &x,
            1e-3,
        );
        worst = worst.max((e(&x) - e0).abs());
    }
    worst / scale
}

#[test]
fn energy_is_conserved_without_friction_for_one_two_and_three_links() {
    let l = robot_links();
    let d1 = energy_drift(&Chain::new([l[1]]), Vector1::new(1.0));
    let d2 = energy_drift(&Chain::new(l), Vector2::new(0.8, -0.6));
    let third = Link {
        length: 0.2,
        mass: 0.8,
        com: 0.1,
        inertia: 0.004,
    };
    let d3 = energy_drift(
        &Chain::new([l[0], l[1], third]),
        Vector3::new(0.7, -0.5, 0.4),
    );
    for (n, d) in [(1, d1), (2, d2), (3, d3)] {
        assert!(d < 1e-6, "N = {n}: relative energy drift {d:e}");
    }
}

#[test]
fn mdot_minus_two_c_is_skew_and_m_is_spd() {
    let third = Link {
        length: 0.25,
        mass: 0.9,
        com: 0.12,
        inertia: 0.006,
    };
    let l = robot_links();
    let chain = Chain::new([l[0], l[1], third]);
    let mut rng = Rng::new(3);
    for _ in 0..200 {
        let q = Vector3::new(
            rng.uniform(-3.0, 3.0),
            rng.uniform(-3.0, 3.0),
            rng.uniform(-3.0, 3.0),
        );
        let qd = Vector3::new(
            rng.uniform(-5.0, 5.0),
            rng.uniform(-5.0, 5.0),
            rng.uniform(-5.0, 5.0),
        );
        // Ṁ by central finite differences along qd (independent of the analytic ∂M/∂q).
        let h = 1e-6;
        let mdot =
            (chain.mass_matrix(&(q + qd * h)) - chain.mass_matrix(&(q - qd * h))) / (2.0 * h);
        let n = mdot - chain.coriolis_matrix(&q, &qd) * 2.0;
        assert!((n + n.transpose()).abs().max() < 1e-6, "not skew: {n}");
        let m = chain.mass_matrix(&q);
        assert!((m - m.transpose()).abs().max() == 0.0);
        assert!(m.cholesky().is_some());
        assert!(m.symmetric_eigenvalues().min() > 0.0);
    }
}

#[test]
fn payload_equals_direct_point_mass_computation() {
    let l = robot_links();
    let mut rng = Rng::new(4);
    for _ in 0..100 {
        let mp = rng.uniform(0.0, 2.0);
        let d = rng.uniform(0.0, 0.43);
        let with = Chain::new([l[0], l[1].with_point_mass(mp, d)]);
        let without = Chain::new(l);
        let q = Vector2::new(rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0));
        // Point at p = l1 e(θ1) + d e(θ2), e(θ) = (sin θ, −cos θ); Jacobian columns ∂p/∂q.
        let (t1, t2) = (q[0], q[0] + q[1]);
        let jp = SMatrix::<f64, 2, 2>::new(
            l[0].length * t1.cos() + d * t2.cos(),
            d * t2.cos(),
            l[0].length * t1.sin() + d * t2.sin(),
            d * t2.sin(),
        );
        let m_direct = without.mass_matrix(&q) + jp.transpose() * jp * mp;
        let g_direct = without.gravity_torque(&q) + jp.transpose() * Vector2::new(0.0, 9.81 * mp);
        assert!((with.mass_matrix(&q) - m_direct).abs().max() < 1e-12);
        assert!((with.gravity_torque(&q) - g_direct).abs().max() < 1e-12);
    }
    // Combined link by hand: 1.2 kg at 0.18 m plus 2 kg at 0.215 m.
    let s = l[1].with_point_mass(2.0, 0.215);
    let com = (1.2 * 0.18 + 2.0 * 0.215) / 3.2;
    assert!((s.mass - 3.2).abs() < 1e-15);
    assert!((s.com - com).abs() < 1e-15);
    let inertia = 0.018 + 1.2 * (0.18 - com).powi(2) + 2.0 * (0.215 - com).powi(2);
    assert!((s.inertia - inertia).abs() < 1e-15);
}

#[test]
fn strap_torque_is_the_negative_energy_gradient_and_forces_are_opposite() {
    let straps = Straps::two_dof(0.28, 0.16, 937.5, 93.7);
    let mut rng = Rng::new(5);
    for _ in 0..100 {
        let qh = Vector2::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
        let qr = Vector2::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
        let t_robot = straps.torque(&straps.force(&(qh - qr), &Vector2::zeros()));
        let energy = |qh: Vector2<f64>, qr: Vector2<f64>| straps.spring_energy(&(qh - qr));
        let h = 1e-6;
        for i in 0..2 {
            let e = Vector2::ith(i, h);
            let d_robot = (energy(qh, qr + e) - energy(qh, qr - e)) / (2.0 * h);
            let d_human = (energy(qh + e, qr) - energy(qh - e, qr)) / (2.0 * h);
            assert!((t_robot[i] + d_robot).abs() < 1e-5, "robot side");
            // The human receives −T_int.
            assert!((-t_robot[i] + d_human).abs() < 1e-5, "human side");
        }
    }
    // MODEL.md §4 numbers: thigh strap sees only the hip difference.
    let f: Vector2<f64> = straps.force(&Vector2::new(0.01, 0.02), &Vector2::new(0.1, 0.0));
    assert!((f[0] - (937.5 * 0.28 * 0.01 + 93.7 * 0.28 * 0.1)).abs() < 1e-12);
    assert!((f[1] - (937.5 * (0.28 * 0.01 + 0.16 * 0.02) + 93.7 * 0.28 * 0.1)).abs() < 1e-12);
}

#[test]
fn winter_segments_match_spec_numbers() {
    // MODEL.md §2: thigh m = 6.0, c = 0.18565, I = 0.11507; shank m = 3.66, c = 0.26088, I = 0.11739.
    let thigh = HumanSegment::WINTER_THIGH.link(60.0, 1.75);
    let shank = HumanSegment::WINTER_SHANK.link(60.0, 1.75);
    assert!((thigh.mass - 6.0).abs() < 1e-12 && (thigh.length - 0.42875).abs() < 1e-12);
    assert!((thigh.com - 0.18565).abs() < 1e-5 && (thigh.inertia - 0.11507).abs() < 1e-5);
    assert!((shank.mass - 3.66).abs() < 1e-12 && (shank.length - 0.4305).abs() < 1e-12);
    assert!((shank.com - 0.26088).abs() < 1e-5 && (shank.inertia - 0.11739).abs() < 1e-5);
}

#[test]
fn dual_numbers_give_the_exact_derivative_of_forward_dynamics() {
    use num_dual::Dual64;
    let robot = RobotModel {
        chain: Chain::new(robot_links()),
        viscous: 0.000899,
        coulomb: 0.05048,
        friction: Friction::Tanh { width: 0.01 },
    };
    let q = Vector2::new(0.3, -0.7);
    let qd = Vector2::new(0.02, -1.0);
    let tau = Vector2::new(2.0, 1.0);
    for i in 0..2 {
        let qdual = q.map(Dual64::from) + Vector2::ith(i, Dual64::new(0.0, 1.0));
        let a = robot.acceleration(&qdual, &qd.map(Dual64::from), &tau.map(Dual64::from));
        let h = 1e-6;
        let e = Vector2::ith(i, h);
        let fd = (robot.acceleration(&(q + e), &qd, &tau)
            - robot.acceleration(&(q - e), &qd, &tau))
            / (2.0 * h);
        for r in 0..2 {
            assert!(
                (a[r].eps - fd[r]).abs() < 1e-6 * (1.0 + fd[r].abs()),
                "{} vs {}",
                a[r].eps,
                fd[r]
            );
            assert!((a[r].re - robot.acceleration(&q, &qd, &tau)[r]).abs() < 1e-14);
        }
    }
}

#[test]
fn safe_tanh_matches_std_and_has_finite_exact_derivative_everywhere() {
    // The saturated branch (|x| ≥ 19, no exp) returns what the formula gives there: exactly ±1.
    for i in 0..=2100 {
        let x = 19.0 + 0.01 * i as f64;
        let e = (-2.0 * x).exp();
        assert_eq!((1.0 - e) / (1.0 + e), 1.0, "formula at {x}");
        assert_eq!(exompc::model::tanh(x), 1.0);
        assert_eq!(exompc::model::tanh(-x), -1.0);
    }
    use num_dual::Dual64;
    for &x in &[
        -1e6, -800.0, -355.0, -19.0, -18.99, -3.0, -1e-9, 0.0, 1e-9, 0.5, 3.0, 18.99, 19.0, 400.0,
        800.0, 1e300,
    ] {
        let v: f64 = exompc::model::tanh(x);
        assert!((v - x.tanh()).abs() < 1e-15, "tanh({x})");
        let d = exompc::model::tanh(Dual64::new(x, 1.0));
        let exact = 1.0 - x.tanh().powi(2);
        assert!(
            d.eps.is_finite() && (d.eps - exact).abs() < 1e-15,
            "d tanh({x}) = {}",
            d.eps
        );
    }
}

/// Units in the last place between `a` and the reference `b`.
fn ulps(a: f64, b: f64) -> f64 {
    let unit = if b == 0.0 {
        f64::MIN_POSITIVE
    } else {
        (b.abs().log2().floor() - 52.0).exp2()
    };
    (a - b).abs() / unit
}

#[test]
fn fast_sin_cos_is_within_an_ulp_of_std() {
    use exompc::model::sin_cos;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut worst: f64 = 0.0;
    let mut check = |x: f64| {
        let (s, c) = sin_cos(x);
        let (s0, c0) = x.sin_cos();
        // Near a zero of sin or cos the reference's own last bit is the floor.
        let es = if s0.abs() > 1e-300 { ulps(s, s0) } else { 0.0 };
        let ec = if c0.abs() > 1e-300 { ulps(c, c0) } else { 0.0 };
        assert!(
            es <= 1.0 && ec <= 1.0,
            "x = {x:e}: sin {es} ulp, cos {ec} ulp"
        );
        worst = worst.max(es).max(ec);
    };
    for _ in 0..200_000 {
        check((next() - 0.5) * 40.0);
    }
    for _ in 0..20_000 {
        check((next() - 0.5) * 2.0e6);
    }
    // Near multiples of π/2 (heavy cancellation in the reduction) and on the branch edges.
    for k in -2000i64..=2000 {
        let m = k as f64 * std::f64::consts::FRAC_PI_2;
        for d in [-2.0, -1.0, 0.0, 1.0, 2.0] {
            check(m + d * m.abs().max(1.0) * f64::EPSILON);
        }
    }
    for x in [
        0.0,
        -0.0,
        1e-300,
        std::f64::consts::FRAC_PI_4,
        -std::f64::consts::FRAC_PI_4,
        1_647_098.9,
        1_647_099.0,
        1e22,
    ] {
        check(x);
    }
    assert!(worst <= 1.0);
    for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let (s, c) = sin_cos(x);
        assert!(s.is_nan() && c.is_nan());
    }
}

/// `sin_cos_near` (the prediction model's later RK4 stages, rotated from the first stage's
/// `sin_cos`) against `f64::sin_cos`: the absolute error stays within two units of `2⁻⁵³`
/// (`sin`, `cos` ≤ 1 in magnitude; near a zero of the result that is more units in its own last
/// place, as for any absolute-accurate evaluation), and beyond the rotation's range or for
/// non-finite arguments it is `sin_cos` itself.
#[test]
fn rotated_sin_cos_is_within_two_half_epsilons_of_std() {
    use exompc::model::{sin_cos, sin_cos_near};
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut worst: f64 = 0.0;
    for case in 0..400_000 {
        let x0 = (next() - 0.5) * 12.0;
        // Increments over the whole range `|d| ≤ 1/16`, and many small ones (h·q̇).
        let d = if case % 2 == 0 {
            (next() - 0.5) * 0.125
        } else {
            (next() - 0.5) * 1e-3
        };
        let x = x0 + d;
        let (s0, c0) = sin_cos(x0);
        let (s, c) = sin_cos_near(x, x0, s0, c0);
        let (sr, cr) = x.sin_cos();
        let err = (s - sr).abs().max((c - cr).abs()) / (0.5 * f64::EPSILON);
        assert!(err <= 2.0, "x0 = {x0:e}, d = {d:e}: {err} half-epsilons");
        worst = worst.max(err);
    }
    eprintln!("worst {worst} half-epsilons");
    // Beyond 1/16 and for non-finite arguments: `sin_cos` of `x`.
    for (x, x0) in [(1.0, 0.9), (-3.0, -2.5), (0.5, 0.5 + 0.0625 + 1e-12)] {
        let (s0, c0) = sin_cos(x0);
        assert_eq!(sin_cos_near(x, x0, s0, c0), sin_cos(x));
    }
    for (x, x0) in [(f64::NAN, 0.0), (f64::INFINITY, 1.0), (0.1, f64::NAN)] {
        let (s0, c0) = sin_cos(x0);
        let (s, c) = sin_cos_near(x, x0, s0, c0);
        if x.is_finite() {
            assert_eq!((s, c), sin_cos(x));
        } else {
            assert!(s.is_nan() && c.is_nan());
        }
    }
}
