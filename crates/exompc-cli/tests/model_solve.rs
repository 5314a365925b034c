//! `exompc model` and `exompc solve` against oracles written here from docs/MODEL.md (§1-3,
//! §8): the closed-form double pendulum, the parallel-axis payload, plant friction, an RK4
//! step, and the NMPC constraints.

mod common;

use common::exompc_stdin as run;
use nalgebra::{Matrix2, Vector2};
use serde_json::Value;

const G: f64 = 9.81;
const KF1: f64 = 0.000899;
const KF2: f64 = 0.05048;

fn ok_json(args: &[&str], stdin: &str) -> Value {
    let out = run(args, stdin);
    assert!(
        out.status.success(),
        "exompc {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is JSON")
}

fn vec_of(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

fn mat_of(v: &Value) -> Vec<Vec<f64>> {
    v.as_array().expect("array").iter().map(vec_of).collect()
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

fn assert_vec_close(name: &str, got: &[f64], want: &[f64], tol: f64) {
    assert_eq!(got.len(), want.len(), "{name}: length");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(close(*g, *w, tol), "{name}[{i}]: got {g}, want {w}");
    }
}

/// A link as in MODEL.md §1: length, mass, COM distance, COM inertia.
#[derive(Clone, Copy, Debug)]
struct L {
    l: f64,
    m: f64,
    c: f64,
    i: f64,
}

/// The MODEL.md §3 robot links with a point mass `mp` at 0.215 m on the shank (parallel axis).
fn robot_links(mp: f64) -> (L, L) {
    let thigh = L {
        l: 0.43,
        m: 2.0,
        c: 0.20,
        i: 0.035,
    };
    let (m0, c0, i0, d) = (1.2, 0.18, 0.018, 0.215);
    let m = m0 + mp;
    let c = (m0 * c0 + mp * d) / m;
    let i = i0 + m0 * (c0 - c).powi(2) + mp * (d - c).powi(2);
    (thigh, L { l: 0.43, m, c, i })
}

/// The MODEL.md §2 Winter leg for body mass `mb`, height 1.75 m.
fn human_links(mb: f64) -> (L, L) {
    let seg = |fm: f64, fl: f64, fc: f64, fr: f64| {
        let l = fl * 1.75;
        let m = fm * mb;
        L {
            l,
            m,
            c: fc * l,
            i: m * (fr * l).powi(2),
        }
    };
    (
        seg(0.100, 0.245, 0.433, 0.323),
        seg(0.061, 0.246, 0.606, 0.416),
    )
}

/// MODEL.md §1 closed form: (M, C qd, G).
fn closed_form(
    a: L,
    b: L,
    q: Vector2<f64>,
    qd: Vector2<f64>,
) -> (Matrix2<f64>, Vector2<f64>, Vector2<f64>) {
    let (c2, s2) = (q[1].cos(), q[1].sin());
    let m11 = a.i + b.i + a.m * a.c * a.c + b.m * (a.l * a.l + b.c * b.c + 2.0 * a.l * b.c * c2);
    let m12 = b.i + b.m * (b.c * b.c + a.l * b.c * c2);
    let m22 = b.i + b.m * b.c * b.c;
    let h = b.m * a.l * b.c * s2;
    let cm = Matrix2::new(-h * qd[1], -h * (qd[0] + qd[1]), h * qd[0], 0.0);
    let g1 = G * ((a.m * a.c + b.m * a.l) * q[0].sin() + b.m * b.c * (q[0] + q[1]).sin());
    let g2 = G * b.m * b.c * (q[0] + q[1]).sin();
    (
        Matrix2::new(m11, m12, m12, m22),
        cm * qd,
        Vector2::new(g1, g2),
    )
}

fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

fn qdd_2dof(
    a: L,
    b: L,
    friction: bool,
    q: Vector2<f64>,
    qd: Vector2<f64>,
    tau: Vector2<f64>,
) -> Vector2<f64> {
    let (m, cqd, g) = closed_form(a, b, q, qd);
    let fr = if friction {
        qd * KF1 + qd.map(|v| KF2 * sign(v))
    } else {
        Vector2::zeros()
    };
    m.try_inverse().unwrap() * (tau - cqd - g - fr)
}

/// One classical RK4 step of `(q, qd)' = (qd, f(q, qd))`.
fn rk4(
    f: impl Fn(Vector2<f64>, Vector2<f64>) -> Vector2<f64>,
    q: Vector2<f64>,
    qd: Vector2<f64>,
    h: f64,
) -> (Vector2<f64>, Vector2<f64>) {
    let (k1q, k1v) = (qd, f(q, qd));
    let (k2q, k2v) = (
        qd + k1v * (h / 2.0),
        f(q + k1q * (h / 2.0), qd + k1v * (h / 2.0)),
    );
    let (k3q, k3v) = (
        qd + k2v * (h / 2.0),
        f(q + k2q * (h / 2.0), qd + k2v * (h / 2.0)),
    );
    let (k4q, k4v) = (qd + k3v * h, f(q + k3q * h, qd + k3v * h));
    (
        q + (k1q + k2q * 2.0 + k3q * 2.0 + k4q) * (h / 6.0),
        qd + (k1v + k2v * 2.0 + k3v * 2.0 + k4v) * (h / 6.0),
    )
}

/// `x = [q, qd, tau]`.
fn check_2dof(link: &str, extra: &str, (a, b): (L, L), friction: bool, x: [[f64; 2]; 3], dt: f64) {
    let [q, qd, tau] = x;
    let input = format!(
        r#"{{"link":"{link}"{extra},"q":[{},{}],"qd":[{},{}],"tau":[{},{}],"dt":{dt}}}"#,
        q[0], q[1], qd[0], qd[1], tau[0], tau[1]
    );
    let out = ok_json(&["model"], &input);
    let (q, qd, tau) = (Vector2::from(q), Vector2::from(qd), Vector2::from(tau));
    let (m, cqd, g) = closed_form(a, b, q, qd);
    let mm = mat_of(&out["M"]);
    for i in 0..2 {
        assert_vec_close(
            &format!("{input}: M row {i}"),
            &mm[i],
            &[m[(i, 0)], m[(i, 1)]],
            1e-12,
        );
    }
    assert_vec_close(
        &format!("{input}: Cqd"),
        &vec_of(&out["Cqd"]),
        cqd.as_slice(),
        1e-12,
    );
    assert_vec_close(
        &format!("{input}: G"),
        &vec_of(&out["G"]),
        g.as_slice(),
        1e-12,
    );
    let qdd = qdd_2dof(a, b, friction, q, qd, tau);
    assert_vec_close(
        &format!("{input}: qdd"),
        &vec_of(&out["qdd"]),
        qdd.as_slice(),
        1e-10,
    );
    let (nq, nqd) = rk4(|q, qd| qdd_2dof(a, b, friction, q, qd, tau), q, qd, dt);
    assert_vec_close(
        &format!("{input}: next.q"),
        &vec_of(&out["next"]["q"]),
        nq.as_slice(),
        1e-10,
    );
    assert_vec_close(
        &format!("{input}: next.qd"),
        &vec_of(&out["next"]["qd"]),
        nqd.as_slice(),
        1e-10,
    );
}

#[test]
fn model_robot_matches_closed_form_with_payload_and_friction() {
    let cases = [
        (0.0, [0.2, -0.5], [0.5, -1.0], [3.0, 1.0]),
        (1.0, [0.2, -0.5], [0.5, -1.0], [3.0, 1.0]),
        (2.0, [-0.7, -1.3], [-2.0, 0.3], [-5.0, 2.5]),
        (0.5, [1.0, 0.0], [0.0, 0.0], [0.0, 0.0]),
        (1.5, [0.05, -2.0], [3.0, 2.5], [20.0, -12.0]),
    ];
    for (mp, q, qd, tau) in cases {
        let extra = format!(r#","payload_kg":{mp}"#);
        check_2dof("robot", &extra, robot_links(mp), true, [q, qd, tau], 0.01);
    }
    // Payload defaults to 0 kg.
    let x = [[0.3, -0.2], [0.1, 0.2], [1.0, 0.5]];
    check_2dof("robot", "", robot_links(0.0), true, x, 0.005);
}

#[test]
fn model_human_matches_closed_form() {
    // MODEL.md §2 numbers at 60 kg.
    let (a, b) = human_links(60.0);
    assert!(close(a.c, 0.18565, 1e-4) && close(a.i, 0.11507, 1e-4));
    assert!(close(b.c, 0.26088, 1e-4) && close(b.i, 0.11739, 1e-4));
    let x = [[0.2, -0.5], [0.5, -1.0], [3.0, 1.0]];
    check_2dof("human", "", (a, b), false, x, 0.01);
    let x = [[-0.3, -1.1], [1.5, -2.0], [-10.0, 4.0]];
    let extra = r#","body_mass_kg":85"#;
    check_2dof("human", extra, human_links(85.0), false, x, 0.01);
}

#[test]
fn model_one_dof_is_the_shank_pendulum() {
    let (_, b) = robot_links(2.0);
    let (q, qd, tau, dt) = (-0.6, -1.2, 1.5, 0.01);
    let out = ok_json(
        &["model"],
        &format!(
            r#"{{"link":"robot","payload_kg":2,"q":[{q}],"qd":[{qd}],"tau":[{tau}],"dt":{dt}}}"#
        ),
    );
    let m = b.i + b.m * b.c * b.c;
    let grav = |q: f64| G * b.m * b.c * q.sin();
    let f = |q: f64, v: f64| (tau - grav(q) - KF1 * v - KF2 * sign(v)) / m;
    assert_vec_close("M", &mat_of(&out["M"])[0], &[m], 1e-12);
    assert_vec_close("Cqd", &vec_of(&out["Cqd"]), &[0.0], 1e-12);
    assert_vec_close("G", &vec_of(&out["G"]), &[grav(q)], 1e-12);
    assert_vec_close("qdd", &vec_of(&out["qdd"]), &[f(q, qd)], 1e-10);
    let fv = |q: Vector2<f64>, v: Vector2<f64>| Vector2::new(f(q[0], v[0]), 0.0);
    let (nq, nv) = rk4(fv, Vector2::new(q, 0.0), Vector2::new(qd, 0.0), dt);
    assert_vec_close("next.q", &vec_of(&out["next"]["q"]), &[nq[0]], 1e-10);
    assert_vec_close("next.qd", &vec_of(&out["next"]["qd"]), &[nv[0]], 1e-10);
}

fn assert_usage_error(cmd: &str, input: &str, mention: &str) {
    let out = run(&[cmd], input);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(2),
        "exompc {cmd} with {input:?} should exit 2; stderr: {err}"
    );
    assert!(
        err.contains(mention),
        "exompc {cmd} with {input:?}: stderr should mention {mention:?}: {err}"
    );
    assert!(out.stdout.is_empty(), "no output on a usage error");
}

#[test]
fn model_rejects_bad_input() {
    let good = r#""q":[0.2,-0.5],"qd":[0.5,-1.0],"tau":[3.0,1.0],"dt":0.01"#;
    assert_usage_error("model", "{not json", "JSON");
    assert_usage_error("model", "[1, 2]", "object");
    assert_usage_error("model", &format!(r#"{{{good}}}"#), "link");
    assert_usage_error("model", &format!(r#"{{"link":"alien",{good}}}"#), "link");
    assert_usage_error(
        "model",
        &format!(r#"{{"link":"robot","extra":1,{good}}}"#),
        "extra",
    );
    assert_usage_error(
        "model",
        r#"{"link":"robot","q":[0.2,-0.5],"qd":[0.5,-1.0],"dt":0.01}"#,
        "tau",
    );
    assert_usage_error(
        "model",
        r#"{"link":"robot","q":[0.2,-0.5],"qd":[0.5],"tau":[3.0,1.0],"dt":0.01}"#,
        "qd",
    );
    assert_usage_error(
        "model",
        r#"{"link":"robot","q":[0.2,-0.5,1],"qd":[0.5,1,1],"tau":[3.0,1.0,1],"dt":0.01}"#,
        "q",
    );
    assert_usage_error(
        "model",
        r#"{"link":"robot","q":[0.2,"a"],"qd":[0.5,1],"tau":[3.0,1.0],"dt":0.01}"#,
        "q",
    );
    assert_usage_error(
        "model",
        r#"{"link":"robot","q":[0.2,1e999],"qd":[0.5,1],"tau":[3.0,1.0],"dt":0.01}"#,
        "q",
    );
    assert_usage_error(
        "model",
        r#"{"link":"robot","q":[0.2,1],"qd":[0.5,1],"tau":[3.0,1.0],"dt":-0.01}"#,
        "dt",
    );
    assert_usage_error(
        "model",
        r#"{"link":"robot","q":[0.2,1],"qd":[0.5,1],"tau":[3.0,1.0],"dt":"x"}"#,
        "dt",
    );
    assert_usage_error(
        "model",
        &format!(r#"{{"link":"robot","payload_kg":-1,{good}}}"#),
        "payload_kg",
    );
    assert_usage_error(
        "model",
        &format!(r#"{{"link":"human","body_mass_kg":0,{good}}}"#),
        "body_mass_kg",
    );
}

// ---------------------------------------------------------------------------------------------
// exompc solve
// ---------------------------------------------------------------------------------------------

const TMAX: f64 = 30.0;
const RATE: f64 = 10.0;

/// Checks the printed solution: converged, `T_j = t_prev + Σ_{i ≤ min(j, nc−1)} dT_i`, every
/// torque and increment within the limits of paper eqs. 8-9, and the predicted trajectory's shape.
fn check_solution(out: &Value, t_prev: &[f64], np: usize, nc: usize, tmax: f64, rate: f64) {
    assert_eq!(out["status"], "converged", "{out}");
    assert!(out["iterations"].as_u64().unwrap() >= 1);
    assert!(out["kkt_residual"].as_f64().unwrap() <= 1e-8, "{out}");
    assert!(out["cost"].as_f64().unwrap() >= 0.0);
    let dt = mat_of(&out["dT"]);
    let t = mat_of(&out["T"]);
    assert_eq!(dt.len(), nc);
    assert_eq!(t.len(), np);
    assert_eq!(mat_of(&out["q_pred"]).len(), np);
    assert_eq!(mat_of(&out["qd_pred"]).len(), np);
    let n = t_prev.len();
    let mut acc = t_prev.to_vec();
    for j in 0..np {
        assert_eq!(t[j].len(), n);
        if j < nc {
            for a in 0..n {
                acc[a] += dt[j][a];
                assert!(dt[j][a].abs() <= rate + 1e-9, "|dT| limit: {out}");
            }
        }
        let prev = if j == 0 {
            t_prev.to_vec()
        } else {
            t[j - 1].clone()
        };
        for a in 0..n {
            assert!(
                close(t[j][a], acc[a], 1e-12),
                "T[{j}] vs cumulative dT: {out}"
            );
            assert!(t[j][a].abs() <= tmax + 1e-9, "|T| limit: {out}");
            assert!(
                (t[j][a] - prev[a]).abs() <= rate + 1e-9,
                "rate limit: {out}"
            );
        }
    }
}

#[test]
fn solve_returns_a_converged_plan_within_limits() {
    let out = ok_json(
        &["solve"],
        r#"{"payload_kg":0.0,"q":[0.2,-0.5],"qd":[0.5,-1.0],"t_prev":[3.0,1.0],"force":[2.0,-3.0],"disturbance":[0,0]}"#,
    );
    check_solution(&out, &[3.0, 1.0], 3, 3, TMAX, RATE);

    // Large forces and a previous torque near the bound: the limits become active.
    let out = ok_json(
        &["solve"],
        r#"{"payload_kg":2.0,"q":[0.1,-1.0],"qd":[2.0,-3.0],"t_prev":[29.5,-29.0],"force":[150.0,-150.0]}"#,
    );
    check_solution(&out, &[29.5, -29.0], 3, 3, TMAX, RATE);
    let t = mat_of(&out["T"]);
    assert!(
        t.iter().flatten().any(|v| v.abs() > TMAX - 1e-6),
        "expected an active torque bound: {out}"
    );

    // Config overrides: longer prediction horizon, shorter control horizon, tighter limits.
    let out = ok_json(
        &["solve"],
        r#"{"q":[0.2,-0.5],"qd":[0.5,-1.0],"t_prev":[3.0,1.0],"force":[40.0,-40.0],
            "config":{"np":5,"nc":2,"r_d":0.2,"r_t":1e-4,"interaction":"hold","torque_max":8,"torque_rate_max":300}}"#,
    );
    check_solution(&out, &[3.0, 1.0], 5, 2, 8.0, 3.0);

    // 1-DOF knee.
    let out = ok_json(
        &["solve"],
        r#"{"payload_kg":1.0,"q":[-0.6],"qd":[-1.0],"t_prev":[1.0],"force":[5.0]}"#,
    );
    check_solution(&out, &[1.0], 3, 3, TMAX, RATE);
}

#[test]
fn solve_plan_tracks_the_intent_estimate() {
    // With a positive thigh strap force the human is ahead on the hip: the plan accelerates the
    // hip (dT[0][0] > 0) relative to the zero-force plan from the same state.
    let base = r#""q":[0.0,0.0],"qd":[0.0,0.0],"t_prev":[0.0,0.0]"#;
    let f0 = ok_json(&["solve"], &format!(r#"{{{base},"force":[0.0,0.0]}}"#));
    let f1 = ok_json(&["solve"], &format!(r#"{{{base},"force":[10.0,0.0]}}"#));
    let d0 = mat_of(&f0["dT"]);
    let d1 = mat_of(&f1["dT"]);
    assert!(d1[0][0] > d0[0][0] + 0.1, "{f0} vs {f1}");
    let q0 = mat_of(&f0["q_pred"]);
    let q1 = mat_of(&f1["q_pred"]);
    assert!(q1[2][0] > q0[2][0], "{f0} vs {f1}");
}

#[test]
fn solve_rejects_bad_input() {
    let good = r#""q":[0.2,-0.5],"qd":[0.5,-1.0],"t_prev":[3.0,1.0]"#;
    assert_usage_error("solve", "", "JSON");
    assert_usage_error("solve", &format!(r#"{{{good}}}"#), "force");
    assert_usage_error("solve", &format!(r#"{{{good},"force":[1]}}"#), "force");
    assert_usage_error(
        "solve",
        &format!(r#"{{{good},"force":[1,2],"bogus":0}}"#),
        "bogus",
    );
    assert_usage_error(
        "solve",
        &format!(r#"{{{good},"force":[1,2],"disturbance":[1]}}"#),
        "disturbance",
    );
    assert_usage_error("solve", &format!(r#"{{{good},"force":[1,"x"]}}"#), "force");
    assert_usage_error(
        "solve",
        &format!(r#"{{{good},"force":[1,2],"config":{{"np":0}}}}"#),
        "np",
    );
    assert_usage_error(
        "solve",
        &format!(r#"{{{good},"force":[1,2],"config":{{"horizon":3}}}}"#),
        "horizon",
    );
    assert_usage_error(
        "solve",
        &format!(r#"{{{good},"force":[1,2],"config":{{"interaction":"guess"}}}}"#),
        "config",
    );
    assert_usage_error(
        "solve",
        &format!(r#"{{{good},"force":[1,2],"payload_kg":-2}}"#),
        "payload_kg",
    );
    assert_usage_error(
        "solve",
        r#"{"q":[0.2,-0.5],"qd":[0.5,-1.0],"t_prev":[31.0,1.0],"force":[1,2]}"#,
        "t_prev",
    );
}
