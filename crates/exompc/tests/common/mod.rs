//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod alloc;

/// A tiny deterministic random generator (xorshift64*), so tests need no `rand`.
///
/// `Rng::new(seed)` scrambles the seed; `Rng(state)` starts from the raw state (non-zero).
pub struct Rng(pub u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [0, 1).
    pub fn unif(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unif()
    }
    /// Uniform in [a, b) (same as [`Rng::uniform`]).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        self.uniform(a, b)
    }
    /// Uniform integer in 0..k.
    pub fn below(&mut self, k: usize) -> usize {
        (self.next_u64() % k as u64) as usize
    }
}

/// The default robot's links (docs/MODEL.md §3): thigh, then shank.
pub fn robot_links() -> [exompc::model::Link; 2] {
    use exompc::model::Link;
    [
        Link {
            length: 0.43,
            mass: 2.0,
            com: 0.20,
            inertia: 0.035,
        },
        Link {
            length: 0.43,
            mass: 1.2,
            com: 0.18,
            inertia: 0.018,
        },
    ]
}

/// Drive the default plant of `s` with `driver` for `steps` control periods (sensors of
/// docs/MODEL.md §5); `each` sees the step index, the filtered measurement, the previous torque,
/// the driver's output torque and the driver.
pub fn closed_loop(
    s: &exompc::config::Experiment,
    driver: &mut dyn exompc::control::Controller<2>,
    steps: usize,
    mut each: impl FnMut(
        usize,
        &exompc::control::Measurement<2>,
        nalgebra::Vector2<f64>,
        nalgebra::Vector2<f64>,
        &dyn exompc::control::Controller<2>,
    ),
) {
    use exompc::scenario::{plant_params, uncertainty, Dof, TwoDof};
    use exompc::sim::{Plant, Sensors};
    let mut plant = Plant::new(plant_params::<TwoDof, 2>(s), TwoDof::trajectory(s));
    let mut sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window);
    for k in 0..steps {
        let st = *plant.state();
        let f = plant.strap_force();
        let (_, meas) = sensors.read(plant.time(), &st.robot.q, &st.robot.qd, &f);
        let prev = driver.previous_torque();
        let out = driver.step(&meas);
        each(k, &meas, prev, out.torque, &*driver);
        plant.step(&out.torque);
    }
}

/// The rows `(e_i, hi_i)` and `(−e_i, −lo_i)` of `lo ≤ z ≤ hi` as `a·z ≤ b` (infinite bounds
/// skipped), in the order upper then lower for each `i`.
pub fn box_rows(lo: &[f64], hi: &[f64]) -> Vec<(Vec<f64>, f64)> {
    let n = lo.len();
    let mut rows = vec![];
    for i in 0..n {
        let mut e = vec![0.0; n];
        e[i] = 1.0;
        if hi[i].is_finite() {
            rows.push((e.clone(), hi[i]));
        }
        if lo[i].is_finite() {
            rows.push((e.iter().map(|v| -v).collect(), -lo[i]));
        }
    }
    rows
}

/// Clarabel's upper-triangle CSC form of the dense symmetric matrix `h`.
pub fn clarabel_upper(h: &nalgebra::DMatrix<f64>) -> clarabel::algebra::CscMatrix<f64> {
    let n = h.nrows();
    let (mut pi, mut pj, mut pv) = (vec![], vec![], vec![]);
    for j in 0..n {
        for i in 0..=j {
            pi.push(i);
            pj.push(j);
            pv.push(h[(i, j)]);
        }
    }
    clarabel::algebra::CscMatrix::new_from_triplets(n, n, pi, pj, pv)
}

/// Clarabel's CSC form of a dense constraint matrix given row by row (`n` columns).
pub fn clarabel_rows<'a>(
    rows: impl IntoIterator<Item = &'a [f64]>,
    n: usize,
) -> clarabel::algebra::CscMatrix<f64> {
    let (mut ai, mut aj, mut av, mut m) = (vec![], vec![], vec![], 0);
    for (r, row) in rows.into_iter().enumerate() {
        for (k, v) in row.iter().enumerate() {
            if *v != 0.0 {
                ai.push(r);
                aj.push(k);
                av.push(*v);
            }
        }
        m = r + 1;
    }
    clarabel::algebra::CscMatrix::new_from_triplets(m, n, ai, aj, av)
}

/// Tight Clarabel settings for oracle solves (tolerances 1e-12, 200 iterations, quiet).
pub fn clarabel_settings() -> clarabel::solver::DefaultSettings<f64> {
    clarabel::solver::DefaultSettingsBuilder::default()
        .verbose(false)
        .tol_gap_abs(1e-12)
        .tol_gap_rel(1e-12)
        .tol_feas(1e-12)
        .tol_ktratio(1e-10)
        .max_iter(200)
        .build()
        .unwrap()
}

/// A value for property tests: mostly moderate, sometimes huge or non-finite.
pub fn value() -> impl proptest::strategy::Strategy<Value = f64> {
    use proptest::prelude::*;
    prop_oneof![
        8 => -5.0..5.0f64,
        2 => -1e4..1e4f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => any::<f64>(),
    ]
}

/// An arbitrary 2-DOF measurement built from [`value`]s.
pub fn measurement() -> impl proptest::strategy::Strategy<Value = exompc::control::Measurement<2>> {
    use proptest::prelude::*;
    prop::array::uniform6(value()).prop_map(|v| exompc::control::Measurement {
        t: 0.0,
        q: nalgebra::Vector2::new(v[0], v[1]),
        qd: nalgebra::Vector2::new(v[2], v[3]),
        force: nalgebra::Vector2::new(v[4], v[5]),
    })
}

/// Per step of a closed loop: torque, SQP iterations, status.
pub type Trace<const N: usize> = Vec<(nalgebra::SVector<f64, N>, u32, exompc::control::StepStatus)>;

/// The closed loop of scenario `s` with controller `kind` for `steps` steps (plant, sensors
/// and controller as `exompc simulate` builds them).
pub fn closed_loop_trace<D: exompc::scenario::Dof<N>, const N: usize>(
    s: &exompc::config::Experiment,
    kind: exompc::config::ControllerKind,
    steps: usize,
) -> Trace<N> {
    use exompc::scenario::{build_controller, plant_params, uncertainty};
    use exompc::sim::{Plant, Sensors};
    let mut c = build_controller::<D, N>(s, kind).unwrap();
    let mut plant = Plant::new(plant_params::<D, N>(s), D::trajectory(s));
    let mut sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window);
    let mut out = vec![];
    for _ in 0..steps {
        let st = *plant.state();
        let f = plant.strap_force();
        let (_, meas) = sensors.read(plant.time(), &st.robot.q, &st.robot.qd, &f);
        let o = c.step(&meas);
        out.push((o.torque, o.iterations, o.status));
        plant.step(&o.torque);
    }
    out
}

/// The condensing map of a stage QP: the `len × nc·nu` matrix `T` with `(u, x) = T u` by the
/// dynamics `x_{j+1} = A_j x_j + B_j u_j`, `x_0 = 0` (the dense oracle's view of `qp`).
pub fn condensing_map(
    qp: &exompc::solver::RiccatiQp,
    nx: usize,
    nu: usize,
    np: usize,
    nc: usize,
) -> nalgebra::DMatrix<f64> {
    use nalgebra::{DMatrix, DVector};
    let len = qp.len();
    let nuv = nc * nu;
    let mut t = DMatrix::zeros(len, nuv);
    for k in 0..nuv {
        t[(k, k)] = 1.0;
        let mut x = DVector::zeros(nx);
        for j in 0..np {
            let aj = DMatrix::from_column_slice(nx, nx, &qp.a[j * nx * nx..(j + 1) * nx * nx]);
            let mut xn = &aj * &x;
            if j < nc {
                let bj = DMatrix::from_column_slice(nx, nu, &qp.b[j * nx * nu..(j + 1) * nx * nu]);
                let u = DVector::from_fn(nu, |i, _| t[(j * nu + i, k)]);
                xn += bj * u;
            }
            for i in 0..nx {
                t[(nuv + j * nx + i, k)] = xn[i];
            }
            x = xn;
        }
    }
    t
}

/// Random bounds of a stage QP (the oracle tests' instances): every input boxed tightly
/// enough to bind, and one state component per stage (`j mod nx`) boxed; returns the
/// trajectory indices of the boxed states (the dense oracle's general rows).
pub fn random_stage_bounds(
    qp: &mut exompc::solver::RiccatiQp,
    rng: &mut Rng,
    nx: usize,
    nu: usize,
    np: usize,
    nc: usize,
) -> Vec<usize> {
    for k in 0..nc * nu {
        qp.lo[k] = rng.uniform(-1.0, -0.1);
        qp.hi[k] = rng.uniform(0.1, 1.0);
    }
    let mut rows = vec![];
    for j in 1..=np {
        let i = qp.x_index(j, j % nx);
        qp.lo[i] = rng.uniform(-1.5, -0.2);
        qp.hi[i] = rng.uniform(0.2, 1.5);
        rows.push(i);
    }
    rows
}

/// The Hessian of a stage QP's cost over the whole trajectory `(u, x)`: blocks `R_j`, `Q_j`
/// and the cross terms `S_j` (between `u_j` and `x_j`), so that the condensed Hessian is
/// `Tᵀ W T` with `T` = [`condensing_map`].
pub fn trajectory_hessian(
    qp: &exompc::solver::RiccatiQp,
    nx: usize,
    nu: usize,
    np: usize,
    nc: usize,
) -> nalgebra::DMatrix<f64> {
    let len = qp.len();
    let nuv = nc * nu;
    let mut w = nalgebra::DMatrix::zeros(len, len);
    for j in 0..nc {
        for c in 0..nu {
            for r in 0..nu {
                w[(j * nu + r, j * nu + c)] = qp.r[j * nu * nu + c * nu + r];
            }
        }
        if j >= 1 {
            let xo = nuv + (j - 1) * nx;
            for c in 0..nx {
                for r in 0..nu {
                    let v = qp.s[j * nu * nx + c * nu + r];
                    w[(j * nu + r, xo + c)] = v;
                    w[(xo + c, j * nu + r)] = v;
                }
            }
        }
    }
    for j in 0..np {
        let xo = nuv + j * nx;
        for c in 0..nx {
            for r in 0..nx {
                w[(xo + r, xo + c)] = qp.q[j * nx * nx + c * nx + r];
            }
        }
    }
    w
}

/// The NMPC problem at joint state `(q, qd)`, strap force `force` and previous torque
/// `t_prev` (intent from `intent`, no disturbance), solved from a cold start by the dense and
/// the structured core: their outcomes, in that order.
#[allow(clippy::too_many_arguments)]
pub fn solve_both_cold<const N: usize>(
    dense: &mut exompc::control::NmpcCore<N>,
    structured: &mut exompc::control::NmpcCore<N>,
    model: &exompc::control::PredictionModel<N>,
    intent: &exompc::control::IntentEstimator,
    lim: &exompc::control::TorqueLimits,
    (q, qd): (nalgebra::SVector<f64, N>, nalgebra::SVector<f64, N>),
    force: nalgebra::SVector<f64, N>,
    t_prev: nalgebra::SVector<f64, N>,
) -> (exompc::solver::SqpInfo, exompc::solver::SqpInfo) {
    let m = exompc::control::Measurement {
        t: 0.0,
        q,
        qd,
        force,
    };
    let inputs = exompc::control::horizon_inputs(intent, model, &m, nalgebra::SVector::zeros());
    let x0 = exompc::model::JointState { q, qd };
    dense.reset();
    structured.reset();
    (
        dense.solve(x0, t_prev, inputs, lim),
        structured.solve(x0, t_prev, inputs, lim),
    )
}

/// The scenario `s` in two closed loops of `steps` steps, one with the dense and one with the
/// structured QP back-end (`[controller.sqp] qp`), controller `kind`: the largest difference
/// between their torques (N·m). Prints the first step that differs by more than 1e-9.
pub fn dense_vs_structured_torque_diff<D: exompc::scenario::Dof<N>, const N: usize>(
    s: &exompc::config::Experiment,
    kind: exompc::config::ControllerKind,
    steps: usize,
) -> f64 {
    use exompc::control::QpBackend;
    let run = |qp: QpBackend| {
        let mut sc = s.clone();
        sc.controller.sqp.qp = qp;
        closed_loop_trace::<D, N>(&sc, kind, steps)
    };
    let a = run(QpBackend::Dense);
    let b = run(QpBackend::Structured);
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        if (x.0 - y.0).amax() > 1e-9 {
            eprintln!(
                "step {k}: {:?} {} {:?} / {:?} {} {:?}",
                x.0, x.1, x.2, y.0, y.1, y.2
            );
            break;
        }
    }
    a.iter()
        .zip(&b)
        .map(|(x, y)| (x.0 - y.0).amax())
        .fold(0.0, f64::max)
}

/// The provoked limit cycle of issue 10: the paper's method (`controller.method = "paper"`)
/// with a 9-sample filter and 2 kg at the ankle (0.43 m) oscillates at 4 Hz from the start.
pub fn provoked_limit_cycle() -> exompc::config::Experiment {
    let mut s = exompc::config::Experiment::default();
    s.controller.method = exompc::config::Method::Paper;
    s.uncertainty.filter_window = 9;
    s.uncertainty.payload_kg = 2.0;
    s.robot.payload_position_m = 0.43;
    s
}

/// The condensed dense form of a stage or tree QP, the oracle `DenseQp` solves:
/// `min ½xᵀHx + gᵀx` over the inputs, `lb ≤ x ≤ ub`, `bl ≤ A x ≤ bu`.
#[allow(dead_code)]
pub struct Condensed {
    pub h: nalgebra::DMatrix<f64>,
    pub g: nalgebra::DVector<f64>,
    pub lb: nalgebra::DVector<f64>,
    pub ub: nalgebra::DVector<f64>,
    pub a: nalgebra::DMatrix<f64>,
    pub bl: nalgebra::DVector<f64>,
    pub bu: nalgebra::DVector<f64>,
    /// Trajectory index of each general row (a state bound of the structured QP).
    pub rows: Vec<usize>,
}

#[allow(dead_code)]
impl Condensed {
    /// The condensed form of a QP with trajectory Hessian `w`, linear term `g`, bounds `lo`,
    /// `hi` (trajectory layout) and condensing map `t` (inputs → trajectory; its first
    /// `t.ncols()` trajectory entries are the inputs): `H = sym(Tᵀ W T)`, `g = Tᵀ g`, the inputs'
    /// boxes, and one general row per bounded trajectory index in `rows`.
    pub fn new(
        t: &nalgebra::DMatrix<f64>,
        w: &nalgebra::DMatrix<f64>,
        g: &[f64],
        lo: &[f64],
        hi: &[f64],
        rows: Vec<usize>,
    ) -> Self {
        use nalgebra::{DMatrix, DVector};
        let nv = t.ncols();
        let h = t.transpose() * w * t;
        let h = (&h + h.transpose()) * 0.5;
        Condensed {
            h,
            g: t.transpose() * DVector::from_column_slice(g),
            lb: DVector::from_fn(nv, |k, _| lo[k]),
            ub: DVector::from_fn(nv, |k, _| hi[k]),
            a: DMatrix::from_fn(rows.len(), nv, |r, c| t[(rows[r], c)]),
            bl: DVector::from_fn(rows.len(), |r, _| lo[rows[r]]),
            bu: DVector::from_fn(rows.len(), |r, _| hi[rows[r]]),
            rows,
        }
    }
}

/// Solves `c` with `DenseQp` and asserts that a structured solver's trajectory `sol` (inputs
/// first), multipliers `mult` (trajectory layout) and objective match it: inputs to
/// `1e-8·(1 + max|x|)`, box and row multipliers to `1e-7·(1 + |m|)`, the objective to
/// `1e-9·(1 + |f|)`. Returns the dense solution.
#[allow(dead_code)]
pub fn assert_matches_dense(
    case: usize,
    c: &Condensed,
    sol: &[f64],
    mult: &[f64],
    objective: f64,
) -> nalgebra::DVector<f64> {
    use exompc::solver::{DenseQp, QpStatus};
    let nv = c.g.len();
    let mut dense = DenseQp::new(nv, c.rows.len());
    let mut xd = nalgebra::DVector::zeros(nv);
    let di = dense.solve(&c.h, &c.g, &c.lb, &c.ub, &c.a, &c.bl, &c.bu, &mut xd);
    assert_eq!(di.status, QpStatus::Solved, "case {case}");
    let scale = 1.0 + xd.amax();
    for k in 0..nv {
        assert!(
            (sol[k] - xd[k]).abs() <= 1e-8 * scale,
            "case {case}: u[{k}] structured {} dense {}",
            sol[k],
            xd[k]
        );
    }
    for (k, (m, md)) in mult
        .iter()
        .zip(dense.multipliers_box())
        .take(nv)
        .enumerate()
    {
        assert!(
            (m - md).abs() <= 1e-7 * (1.0 + m.abs()),
            "case {case}: box multiplier {k}"
        );
    }
    for (r, &i) in c.rows.iter().enumerate() {
        assert!(
            (mult[i] - dense.multipliers_general()[r]).abs() <= 1e-7 * (1.0 + mult[i].abs()),
            "case {case}: row multiplier {r}"
        );
    }
    assert!(
        (objective - di.objective).abs() <= 1e-9 * (1.0 + di.objective.abs()),
        "case {case}: objective {objective} vs {}",
        di.objective
    );
    xd
}
