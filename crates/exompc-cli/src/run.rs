//! Running one experiment of a scenario into an output folder (`trace.csv`, `summary.json`).

use crate::error::CliError;
use crate::interrupt::stop_on_interrupt;
use crate::io::write_atomic;
use crate::trace::CsvTrace;
use exompc::config::Experiment;
use exompc::scenario::multistage;
use exompc::scenario::{run_experiment, OneDof, RunError, TwoDof};
use exompc::sim::{Recorder, Summary};
use std::path::Path;

/// Number of scenarios the controller of `s` reports.
pub fn scenario_count(s: &Experiment) -> usize {
    scenario_keys(s).len()
}

/// Trace column keys of the scenarios the controller of `s` reports (none unless it is a
/// multi-stage controller).
pub fn scenario_keys(s: &Experiment) -> Vec<String> {
    if is_multistage(s) {
        multistage_keys(s)
    } else {
        Vec::new()
    }
}

/// Trace column keys (`mu_K`, `dist_K_J`) of the multi-stage scenarios of `s`: `1, 2, ...` for
/// the `payloads_kg` shorthand (the columns tools already read), the names for
/// `[[multistage.scenarios]]`.
pub fn multistage_keys(s: &Experiment) -> Vec<String> {
    if multistage::is_named(s) {
        multistage::names(s)
    } else {
        crate::trace::numbered(multistage::count(s))
    }
}

/// One warning line (for stderr) per pair of multi-stage scenarios of `s` that the estimator
/// cannot tell apart in the `dof`-DOF layout (`exompc::scenario::multistage::warnings`); none
/// unless the controller is the multi-stage one.
pub fn scenario_warnings(s: &Experiment, dof: u8) -> Vec<String> {
    if !is_multistage(s) {
        return Vec::new();
    }
    multistage::warnings(s, usize::from(dof))
        .iter()
        .map(|w| format!("warning: {w}"))
        .collect()
}

/// Whether the controller of `s` blends the multi-stage scenarios (its registry entry says so).
fn is_multistage(s: &Experiment) -> bool {
    exompc::scenario::controller_info(s.controller.kind).is_ok_and(|c| c.multistage)
}

fn run_error(e: RunError) -> CliError {
    match e {
        RunError::Config(c) => CliError::Config(c.to_string()),
        RunError::Io(e) => CliError::io("writing trace", e),
        // The scenario's values put the plant beyond what RK4 integrates: bad input (exit 2).
        d @ RunError::Diverged { .. } => CliError::Config(format!(
            "{d}, or smaller gains (a value of the scenario is beyond the plant's stable range)"
        )),
        other => CliError::Runtime(other.to_string()),
    }
}

/// Run scenario `s` in the `dof` layout; with `out`, stream `out/trace.csv` and write
/// `out/summary.json` (both through temporary files renamed at the end).
///
/// On SIGINT/SIGTERM the run stops at the next control step; its trace so far and its summary
/// (marked `"partial": true`, with `completed_steps` and `planned_steps`) are kept in `out`,
/// and the result is [`CliError::Interrupted`] saying what was completed.
pub fn run_to_dir(s: &Experiment, dof: u8, out: Option<&Path>) -> Result<Summary, CliError> {
    let n = usize::from(dof);
    let mut trace = match out {
        Some(dir) => Some(CsvTrace::create_with(
            &dir.join("trace.csv"),
            n,
            &scenario_keys(s),
        )?),
        None => None,
    };
    let mut stop = stop_on_interrupt();
    let summary = match dof {
        1 => {
            let mut recs: Vec<&mut dyn Recorder<1>> = Vec::with_capacity(2);
            if let Some(t) = trace.as_mut() {
                recs.push(t);
            }
            recs.push(&mut stop);
            run_experiment::<OneDof, 1>(s, &mut recs)
        }
        _ => {
            let mut recs: Vec<&mut dyn Recorder<2>> = Vec::with_capacity(2);
            if let Some(t) = trace.as_mut() {
                recs.push(t);
            }
            recs.push(&mut stop);
            run_experiment::<TwoDof, 2>(s, &mut recs)
        }
    }
    .map_err(|e| {
        if crate::interrupt::requested() {
            // The trace's temporary file is removed as `trace` drops.
            CliError::Interrupted(format!(
                "interrupted: run not completed{}",
                out.map_or(String::new(), |d| format!(
                    ", nothing written to {}",
                    d.display()
                ))
            ))
        } else {
            run_error(e)
        }
    })?;
    let planned = s.control_steps(usize::from(dof));
    let partial = summary.steps < planned;
    if let (Some(t), Some(dir)) = (trace, out) {
        t.finish()?;
        let mut json = serde_json::to_value(&summary)
            .map_err(|e| CliError::Runtime(format!("serialising summary: {e}")))?;
        if partial {
            if let Some(obj) = json.as_object_mut() {
                obj.insert("partial".into(), true.into());
                obj.insert("completed_steps".into(), summary.steps.into());
                obj.insert("planned_steps".into(), planned.into());
            }
        }
        let text = serde_json::to_string_pretty(&json)
            .map_err(|e| CliError::Runtime(format!("serialising summary: {e}")))?;
        write_atomic(&dir.join("summary.json"), text.as_bytes())?;
    }
    if partial {
        return Err(CliError::Interrupted(format!(
            "interrupted by {}: {} of {planned} steps ({:.2} of {:.2} s) completed{}",
            crate::interrupt::signal_name(),
            summary.steps,
            summary.duration_s,
            planned as f64 * s.timing.dt,
            out.map_or(String::new(), |d| format!(
                "; partial results kept in {} (trace.csv, summary.json marked \"partial\": true)",
                d.display()
            ))
        )));
    }
    Ok(summary)
}

/// [`scenario_warnings`] computed on a helper thread, abandoned on SIGINT/SIGTERM
/// ([`CliError::Interrupted`]): with a tiny `timing.dt` the identifiability check takes long.
pub fn scenario_warnings_interruptible(s: &Experiment, dof: u8) -> Result<Vec<String>, CliError> {
    let s = s.clone();
    crate::interrupt::interruptible("before the run started, nothing written", move || {
        scenario_warnings(&s, dof)
    })
}

/// A short human-readable rendering of a summary.
pub fn describe(s: &Summary) -> String {
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.2}"));
    let mut out = format!(
        "{} | {}-DOF | payload {:.2} kg | {:.1} s, {} steps\n",
        s.controller, s.dof, s.payload_kg, s.duration_s, s.steps
    );
    out += &format!(
        "  RMS strap force   thigh {} N   shank {} N\n",
        f(s.rms_force_n.thigh),
        f(s.rms_force_n.shank)
    );
    out += &format!(
        "  max angle error   hip {} deg   knee {} deg\n",
        f(s.delta_max_deg.hip),
        f(s.delta_max_deg.knee)
    );
    if let Some(p) = &s.mean_probability {
        let ps: Vec<String> = p
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let name = s.scenarios.as_ref().and_then(|n| n.get(i));
                match name {
                    Some(name) => format!("{name} {:.2}%", 100.0 * v),
                    None => format!("mu{} {:.2}%", i + 1, 100.0 * v),
                }
            })
            .collect();
        out += &format!("  mean probability  {}\n", ps.join("   "));
    }
    if let Some(c) = &s.solver {
        out += &format!("  solver            {}\n", solver_label(c));
    }
    out += &format!(
        "  step time         mean {:.1} us   p50 {:.1} us   p99 {:.1} us   max {:.1} us\n",
        s.step_time_us.mean, s.step_time_us.p50, s.step_time_us.p99, s.step_time_us.max
    );
    out += &format!(
        "  limit violations {}   solver failures {}\n",
        s.limit_violations, s.solver_failures
    );
    out += &describe_safety(&s.safety);
    out
}

/// `qp dense, hessian structured_secant`: what `[controller.sqp] qp` and `hessian` resolved
/// to (the summary's `solver`).
pub fn solver_label(c: &exompc::control::SolverChoice) -> String {
    let name = |v: serde_json::Value| v.as_str().unwrap_or("?").to_string();
    format!(
        "qp {}, hessian {}",
        name(serde_json::to_value(c.qp).unwrap_or_default()),
        name(serde_json::to_value(c.hessian).unwrap_or_default())
    )
}

/// The printed safety lines of a summary (`exompc simulate` and `exompc run`): trips and held
/// steps, each monitor's trips and first trip, the latch.
pub fn describe_safety(sa: &exompc::sim::SafetySummary) -> String {
    let mut out = format!(
        "  safety            monitor trips {}   monitor-held steps {}   rejected measurements {}",
        sa.monitor_trips, sa.monitor_steps, sa.bad_measurement_steps
    );
    for m in &sa.monitors {
        out += &format!(
            "\n    {:<20}{} trips, first at {:.2} s",
            m.monitor, m.trips, m.first_trip_s
        );
    }
    if sa.estimated_steps > 0 {
        out += &format!(
            "\n    sensor faults {}: the controller stepped on estimates on {} steps",
            sa.sensor_faults, sa.estimated_steps
        );
    }
    if sa.fallback_stops > 0 {
        out += &format!(
            "\n    fallback stops {}: the transparent fallback failed (oscillated or diverged) and \
             the protective stop replaced it",
            sa.fallback_stops
        );
    }
    if sa.escalations > 0 {
        out += &format!(
            "\n    escalations {}: the configured response handed the torque to the transparent \
             fallback (its cause persisted)",
            sa.escalations
        );
    }
    if sa.revocations > 0 {
        out += &format!(
            "\n    revocations {}: encoder channels believed on smoothness alone were rejected \
             again (the controller failed right after; for an angle the protective stop followed)",
            sa.revocations
        );
    }
    if let Some(t) = sa.latched_at_s {
        out += &format!(
            "\n    latched at {t:.2} s by {} (handover {}): the monitor response kept the torque \
             for {:.2} s, until a reset",
            sa.latched_by.as_deref().unwrap_or("a monitor"),
            sa.handovers,
            sa.latched_for_s
        );
    }
    if sa.events_dropped > 0 {
        out += &format!(
            "\n    ({} monitor events not logged: the counts above miss their trips)",
            sa.events_dropped
        );
    }
    out
}
