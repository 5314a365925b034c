//! `exompc solve`: solve one NMPC problem (paper eq. 7 with constraints 8-9) and print it.
//!
//! Reads one JSON object on stdin:
//! `{"payload_kg":0.0,"q":[..],"qd":[..],"t_prev":[..],"force":[..],"disturbance":[0,0]}`
//! with the robot state (`q` exact angles, `qd` filtered velocities), the previous torque
//! `T(k−1)`, the measured (filtered) strap forces in N, an optional disturbance estimate (N·m,
//! default zero) and an optional `"config"` object overriding the scenario's `np`, `nc`, `r_d`,
//! `r_t`, `interaction` (`"predict"`/`"hold"`), `torque_max` and `torque_rate_max`. Two entries
//! per array for the hip-knee robot, one for the knee-only robot.
//!
//! Prints `{"status":..,"iterations":..,"kkt_residual":..,"cost":..,"dT":..,"T":..,
//! "q_pred":..,"qd_pred":..}`: the increments `dT(k..k+Nc−1)`, the absolute torques
//! `T(k..k+Np−1)` (held after `Nc`) and the predicted states `k+1..k+Np`. A solver failure
//! still prints the result, then exits 1.

use crate::args::ConfigOpt;
use clap::Args;
use exompc::config::{Experiment, Interaction};
use exompc::control::{horizon_inputs, Measurement, NmpcCore};
use exompc::model::JointState;
use exompc::scenario::{intent, limits, nmpc_settings, prediction_model, Dof, OneDof, TwoDof};
use exompc::solver::SqpStatus;
use exompc_cli::error::CliError;
use exompc_cli::io::{check_vec, joint_count, parse_input, probe_as, read_stdin};
use nalgebra::SVector;
use serde::Deserialize;
use serde_json::{json, Value};

#[derive(Debug, Args)]
pub(crate) struct SolveArgs {
    #[command(flatten)]
    pub(crate) config: ConfigOpt,
}

/// Optional controller overrides of the request.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SolveConfig {
    np: Option<usize>,
    nc: Option<usize>,
    r_d: Option<f64>,
    r_t: Option<f64>,
    interaction: Option<Interaction>,
    torque_max: Option<f64>,
    torque_rate_max: Option<f64>,
}

/// The request read on stdin.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SolveInput {
    #[serde(default)]
    payload_kg: Option<f64>,
    q: Vec<f64>,
    qd: Vec<f64>,
    t_prev: Vec<f64>,
    force: Vec<f64>,
    #[serde(default)]
    disturbance: Option<Vec<f64>>,
    #[serde(default)]
    config: Option<SolveConfig>,
}

fn probe(k: &str, v: &Value) -> Option<Result<(), serde_json::Error>> {
    Some(match k {
        "payload_kg" => probe_as::<Option<f64>>(v),
        "q" | "qd" | "t_prev" | "force" => probe_as::<Vec<f64>>(v),
        "disturbance" => probe_as::<Option<Vec<f64>>>(v),
        "config" => probe_as::<Option<SolveConfig>>(v),
        _ => return None,
    })
}

pub(crate) fn run(a: SolveArgs) -> Result<(), CliError> {
    let mut s = a.config.load()?;
    let input: SolveInput = parse_input(&read_stdin()?, probe)?;
    apply_config(&mut s, input.config.as_ref())?;
    let n = joint_count(&input.q)?;
    for (name, v) in [
        ("q", &input.q),
        ("qd", &input.qd),
        ("t_prev", &input.t_prev),
        ("force", &input.force),
    ] {
        check_vec(name, v, n)?;
    }
    if let Some(d) = &input.disturbance {
        check_vec("disturbance", d, n)?;
    }
    let payload = input.payload_kg.unwrap_or(0.0);
    if !(payload.is_finite() && payload >= 0.0) {
        return Err(CliError::Usage(format!(
            "field `payload_kg` must be a finite mass >= 0 (kg), found {payload}"
        )));
    }
    let tmax = s.controller.torque_max;
    if let Some(i) = input.t_prev.iter().position(|t| t.abs() > tmax) {
        return Err(CliError::Usage(format!(
            "field `t_prev[{i}]` = {} is outside the torque limit ±{tmax} N·m",
            input.t_prev[i]
        )));
    }
    let (out, status) = if n == 2 {
        solve::<TwoDof, 2>(&s, payload, &input)?
    } else {
        solve::<OneDof, 1>(&s, payload, &input)?
    };
    println!("{out}");
    match status {
        SqpStatus::Converged
        | SqpStatus::MaxIterations
        | SqpStatus::MaxTime
        | SqpStatus::RealTimeIteration => Ok(()),
        other => Err(CliError::Runtime(format!(
            "the solver did not find a usable solution ({})",
            status_name(other)
        ))),
    }
}

/// Applies the request's `config` overrides to the scenario and validates it, naming the field.
fn apply_config(s: &mut Experiment, c: Option<&SolveConfig>) -> Result<(), CliError> {
    let Some(c) = c else { return Ok(()) };
    let k = &mut s.controller;
    if let Some(v) = c.np {
        k.np = v;
    }
    if let Some(v) = c.nc {
        k.nc = v;
    }
    if let Some(v) = c.r_d {
        k.r_d = v;
    }
    if let Some(v) = c.r_t {
        k.r_t = v;
    }
    if let Some(v) = c.interaction {
        k.interaction = v;
    }
    if let Some(v) = c.torque_max {
        k.torque_max = v;
    }
    if let Some(v) = c.torque_rate_max {
        k.torque_rate_max = v;
    }
    s.validate().map_err(|e| {
        let msg = e.to_string().replace("controller.", "config.");
        CliError::Usage(format!("invalid field in `config`: {msg}"))
    })
}

/// Snake-case name of a solver status.
fn status_name(s: SqpStatus) -> &'static str {
    match s {
        SqpStatus::Converged => "converged",
        SqpStatus::MaxIterations => "max_iterations",
        SqpStatus::MaxTime => "max_time",
        SqpStatus::RealTimeIteration => "real_time_iteration",
        SqpStatus::QpFailed => "qp_failed",
        SqpStatus::Infeasible => "infeasible",
        SqpStatus::NonFiniteInput => "non_finite_input",
        SqpStatus::LineSearchFailed => "line_search_failed",
        SqpStatus::DimensionMismatch => "dimension_mismatch",
    }
}

fn solve<D: Dof<N>, const N: usize>(
    s: &Experiment,
    payload: f64,
    inp: &SolveInput,
) -> Result<(Value, SqpStatus), CliError> {
    let v = |x: &[f64]| SVector::<f64, N>::from_column_slice(x);
    let model = prediction_model::<D, N>(s, payload);
    let mut core = NmpcCore::new(model, &nmpc_settings(s))
        .map_err(|e| CliError::Usage(format!("invalid solver settings: {e}")))?;
    let m = Measurement {
        t: 0.0,
        q: v(&inp.q),
        qd: v(&inp.qd),
        force: v(&inp.force),
    };
    let d = inp
        .disturbance
        .as_deref()
        .map_or_else(SVector::<f64, N>::zeros, v);
    let inputs = horizon_inputs(&intent(s), &model, &m, d);
    let x0 = JointState { q: m.q, qd: m.qd };
    let info = core.solve(x0, v(&inp.t_prev), inputs, &limits(s));
    let z = core.solution().as_slice().to_vec();
    let (xs, us) = core.problem.predict(&z);
    let rows = |it: &mut dyn Iterator<Item = Vec<f64>>| it.collect::<Vec<Vec<f64>>>();
    let dt = rows(&mut z.chunks(N).map(<[f64]>::to_vec));
    let t = rows(&mut us.iter().map(|u| u.iter().copied().collect()));
    let qp = rows(&mut xs.iter().map(|x| x.q.iter().copied().collect()));
    let qdp = rows(&mut xs.iter().map(|x| x.qd.iter().copied().collect()));
    let num = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    Ok((
        json!({
            "status": status_name(info.status),
            "iterations": info.iterations,
            "kkt_residual": num(info.kkt_residual),
            "cost": num(info.cost),
            "dT": dt,
            "T": t,
            "q_pred": qp,
            "qd_pred": qdp,
        }),
        info.status,
    ))
}
