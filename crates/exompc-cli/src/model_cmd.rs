//! `exompc model`: evaluate the robot or human leg model at one state.
//!
//! Reads one JSON object on stdin, for example
//! `{"link":"robot","payload_kg":1.0,"q":[0.2,-0.5],"qd":[0.5,-1.0],"tau":[3.0,1.0],"dt":0.01}`,
//! and prints `{"M":..,"Cqd":..,"G":..,"qdd":..,"next":{"q":..,"qd":..}}`:
//!
//! * `link`: `"robot"` (the scenario's exoskeleton with the payload merged into its shank, plant
//!   friction `kf1 qd + kf2 sign(qd)`) or `"human"` (Winter's leg for `body_mass_kg`, default the
//!   scenario's body mass, no friction);
//! * `q`, `qd`, `tau`: joint angles (rad), velocities (rad/s) and the applied joint torque (N·m),
//!   two entries for the hip-knee chain, one for the knee-only (shank) chain;
//! * `qdd = M⁻¹(tau − C qd − G − friction)`; `next` is one RK4 step of `dt` with `tau` held.
//!
//! No interaction and no disturbance are included.

use crate::args::ConfigOpt;
use clap::Args;
use exompc::config::{Experiment, MAX_PAYLOAD_KG};
use exompc::model::{rk4_step, Chain, Friction, JointState, RobotModel};
use exompc::scenario::{Dof, OneDof, TwoDof};
use exompc::sim::{robot_model, HumanLeg};
use exompc_cli::error::CliError;
use exompc_cli::io::{check_vec, joint_count, parse_input, probe_as, read_stdin};
use nalgebra::{SMatrix, SVector};
use serde::Deserialize;
use serde_json::{json, Value};

#[derive(Debug, Args)]
pub(crate) struct ModelArgs {
    #[command(flatten)]
    pub(crate) config: ConfigOpt,
}

/// Which chain to evaluate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum LinkKind {
    Robot,
    Human,
}

/// The request read on stdin.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelInput {
    link: LinkKind,
    #[serde(default)]
    payload_kg: Option<f64>,
    #[serde(default)]
    body_mass_kg: Option<f64>,
    q: Vec<f64>,
    qd: Vec<f64>,
    tau: Vec<f64>,
    dt: f64,
}

fn probe(k: &str, v: &Value) -> Option<Result<(), serde_json::Error>> {
    Some(match k {
        "link" => probe_as::<LinkKind>(v),
        "payload_kg" | "body_mass_kg" => probe_as::<Option<f64>>(v),
        "dt" => probe_as::<f64>(v),
        "q" | "qd" | "tau" => probe_as::<Vec<f64>>(v),
        _ => return None,
    })
}

pub(crate) fn run(a: ModelArgs) -> Result<(), CliError> {
    let s = a.config.load()?;
    let input: ModelInput = parse_input(&read_stdin()?, probe)?;
    let out = evaluate(&s, &input)?;
    println!("{out}");
    Ok(())
}

fn evaluate(s: &Experiment, inp: &ModelInput) -> Result<Value, CliError> {
    let n = joint_count(&inp.q)?;
    for (name, v) in [("q", &inp.q), ("qd", &inp.qd), ("tau", &inp.tau)] {
        check_vec(name, v, n)?;
    }
    if !(inp.dt.is_finite() && inp.dt > 0.0) {
        return Err(CliError::Usage(format!(
            "field `dt` must be a finite time step > 0 (s), found {}",
            inp.dt
        )));
    }
    match inp.link {
        LinkKind::Robot => {
            if inp.body_mass_kg.is_some() {
                return Err(CliError::Usage(
                    "field `body_mass_kg` applies to `\"link\": \"human\"` only".into(),
                ));
            }
            let payload = inp.payload_kg.unwrap_or(0.0);
            if !(payload.is_finite() && (0.0..=MAX_PAYLOAD_KG).contains(&payload)) {
                return Err(CliError::Usage(format!(
                    "field `payload_kg` must be a finite mass in [0, {MAX_PAYLOAD_KG}] kg, found {payload}"
                )));
            }
            if n == 2 {
                robot::<TwoDof, 2>(s, payload, inp)
            } else {
                robot::<OneDof, 1>(s, payload, inp)
            }
        }
        LinkKind::Human => {
            if inp.payload_kg.is_some() {
                return Err(CliError::Usage(
                    "field `payload_kg` applies to `\"link\": \"robot\"` only".into(),
                ));
            }
            let mb = inp.body_mass_kg.unwrap_or(s.human.body_mass_kg);
            if !(mb.is_finite() && mb > 0.0) {
                return Err(CliError::Usage(format!(
                    "field `body_mass_kg` must be a finite mass > 0 (kg), found {mb}"
                )));
            }
            if n == 2 {
                human::<TwoDof, 2>(s, mb, inp)
            } else {
                human::<OneDof, 1>(s, mb, inp)
            }
        }
    }
}

fn robot<D: Dof<N>, const N: usize>(
    s: &Experiment,
    payload: f64,
    inp: &ModelInput,
) -> Result<Value, CliError> {
    let model: RobotModel<N> = robot_model(
        &D::robot_links(s),
        s.robot.viscous_friction,
        s.robot.coulomb_friction,
        Friction::Sign,
        payload,
        s.robot.payload_position_m,
        0.0,
    );
    let (q, qd, tau) = state::<N>(inp);
    let accel = |x: &JointState<f64, N>| model.acceleration(&x.q, &x.qd, &tau);
    report(&model.chain, q, qd, inp.dt, accel)
}

fn human<D: Dof<N>, const N: usize>(
    s: &Experiment,
    body_mass: f64,
    inp: &ModelInput,
) -> Result<Value, CliError> {
    let chain = HumanLeg {
        segments: D::human_segments(s),
        height: s.human.height_m,
    }
    .chain(body_mass);
    let (q, qd, tau) = state::<N>(inp);
    let accel = |x: &JointState<f64, N>| chain.forward_dynamics(&x.q, &x.qd, &tau);
    report(&chain, q, qd, inp.dt, accel)
}

type Vn<const N: usize> = SVector<f64, N>;

fn state<const N: usize>(inp: &ModelInput) -> (Vn<N>, Vn<N>, Vn<N>) {
    (
        Vn::<N>::from_column_slice(&inp.q),
        Vn::<N>::from_column_slice(&inp.qd),
        Vn::<N>::from_column_slice(&inp.tau),
    )
}

fn report<const N: usize>(
    chain: &Chain<N>,
    q: Vn<N>,
    qd: Vn<N>,
    dt: f64,
    accel: impl Fn(&JointState<f64, N>) -> Vn<N>,
) -> Result<Value, CliError> {
    let (m, cqd, g): (SMatrix<f64, N, N>, Vn<N>, Vn<N>) = chain.terms(&q, &qd);
    let x0 = JointState { q, qd };
    let qdd = accel(&x0);
    let next = rk4_step(
        |_t, x: &JointState<f64, N>| JointState {
            q: x.qd,
            qd: accel(x),
        },
        0.0,
        &x0,
        dt,
    );
    let finite = |x: &Vn<N>| x.iter().all(|v| v.is_finite());
    if !(m.iter().all(|v| v.is_finite())
        && finite(&cqd)
        && finite(&g)
        && finite(&qdd)
        && finite(&next.q)
        && finite(&next.qd))
    {
        return Err(CliError::Usage(
            "the model is not finite at this input: `q`, `qd`, `tau`, `dt` or the mass is too large for f64"
                .into(),
        ));
    }
    let rows: Vec<Vec<f64>> = (0..N)
        .map(|i| (0..N).map(|j| m[(i, j)]).collect())
        .collect();
    let v = |x: &Vn<N>| x.iter().copied().collect::<Vec<f64>>();
    Ok(json!({
        "M": rows,
        "Cqd": v(&cqd),
        "G": v(&g),
        "qdd": v(&qdd),
        "next": {"q": v(&next.q), "qd": v(&next.qd)},
    }))
}
