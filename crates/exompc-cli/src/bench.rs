//! `exompc bench`: time the controllers' step alone in closed loops of the 2-DOF scenario, and
//! a scaling table over the horizon and the number of scenarios (see `docs/PERFORMANCE.md`).

use crate::args::ConfigOpt;
use clap::Args;
use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::control::QpBackend;
use exompc::scenario::{build_controller, plant_params, uncertainty, Dof, TwoDof};
use exompc::sim::{Plant, Sensors, StepTimeStats};
use exompc_cli::error::CliError;
use exompc_cli::interrupt;
use serde_json::json;
use std::time::{Duration, Instant};

/// Horizons `Np = Nc` of the scaling table.
const HORIZONS: [usize; 6] = [3, 5, 10, 20, 25, 50];
/// Prediction horizons of the fixed-`Nc = 3` rows of the scaling table.
const FIXED_NC_HORIZONS: [usize; 4] = [10, 20, 50, 100];
/// Scenario counts of the scaling table (payloads spread evenly over 0..2 kg).
const SCENARIOS: [usize; 4] = [1, 3, 5, 9];
/// Wall-clock budget per scaling case (the case stops after it, with at least 3 steps).
const CASE_BUDGET: Duration = Duration::from_millis(700);
/// Steps per scaling case at most.
const CASE_STEPS: usize = 300;

/// Largest `--steps` (80 MB of step times per controller).
const MAX_STEPS: i64 = 10_000_000;

/// Timing of one closed loop.
struct LoopStats {
    steps: usize,
    step: StepTimeStats,
    iterations_mean: f64,
    /// Simulated seconds per wall-clock second of the whole loop (plant, sensors, controller).
    sim_speed: f64,
    wall_s: f64,
}

/// Run `steps` closed-loop steps of `s` with controller `kind` (stopping early once `budget`
/// is spent and at least `min_steps` ran); time the controller's `step` alone.
fn closed_loop(
    s: &Experiment,
    kind: ControllerKind,
    steps: usize,
    budget: Option<Duration>,
) -> Result<LoopStats, CliError> {
    s.validate().map_err(|e| CliError::Config(e.to_string()))?;
    let mut controller =
        build_controller::<TwoDof, 2>(s, kind).map_err(|e| CliError::Runtime(e.to_string()))?;
    let mut plant = Plant::new(plant_params::<TwoDof, 2>(s), TwoDof::trajectory(s));
    let mut sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window);
    let mut times = Vec::with_capacity(steps);
    let mut iterations = 0u64;
    let start = Instant::now();
    for k in 0..steps {
        // SIGINT/SIGTERM: stop here; the report marks the results partial.
        if interrupt::requested() {
            break;
        }
        if let Some(b) = budget {
            let spent = start.elapsed();
            if (k >= 3 && spent > b) || (k >= 1 && spent > 4 * b) {
                break;
            }
        }
        let t = plant.time();
        let st = *plant.state();
        let force = plant.strap_force();
        let (_raw, meas) = sensors.read(t, &st.robot.q, &st.robot.qd, &force);
        let t0 = Instant::now();
        let out = controller.step(&meas);
        times.push(t0.elapsed().as_secs_f64() * 1e6);
        iterations += u64::from(out.iterations);
        plant.step(&out.torque);
    }
    let wall = start.elapsed().as_secs_f64();
    let n = times.len();
    Ok(LoopStats {
        steps: n,
        step: StepTimeStats::from_samples(&mut times),
        iterations_mean: iterations as f64 / n.max(1) as f64,
        sim_speed: n as f64 * s.timing.dt / wall,
        wall_s: wall,
    })
}

/// The scenario with the controller kind and multi-stage formulation set.
fn variant(base: &Experiment, kind: ControllerKind, formulation: Formulation) -> Experiment {
    let mut s = base.clone();
    s.controller.kind = kind;
    s.multistage.formulation = formulation;
    s.multistage.parallel = false;
    s
}

/// One row of the scaling table.
struct ScalingRow {
    np: usize,
    nc: usize,
    scenarios: usize,
    formulation: &'static str,
    /// The dense (condensed) QP path.
    stats: LoopStats,
    /// The structured QP path (Riccati per scenario; block-arrowhead tree when coupled), same
    /// case, same run.
    structured: Option<LoopStats>,
    /// The structured path with one real-time iteration per step (`rti = true`), same run.
    rti: Option<LoopStats>,
}

/// Runs the benchmark and prints the report (`--json`: one JSON object on stdout).
#[derive(Debug, Args)]
pub(crate) struct BenchArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Print one JSON object instead of tables.
    #[arg(long)]
    json: bool,
    /// Closed-loop steps per controller, in [1, 10000000] (default: the scenario's 2-DOF run).
    #[arg(long, value_name = "N", allow_negative_numbers = true, value_parser = clap::value_parser!(i64).range(1..=MAX_STEPS))]
    steps: Option<i64>,
}

/// `exompc bench`.
pub(crate) fn run(a: BenchArgs) -> Result<(), CliError> {
    bench(&a.config.load()?, a.json, a.steps.map(|n| n as usize))
}

/// Run the benchmark on scenario `base`.
pub fn bench(base: &Experiment, as_json: bool, steps: Option<usize>) -> Result<(), CliError> {
    let steps = steps
        .unwrap_or_else(|| base.control_steps(2))
        .clamp(1, MAX_STEPS as usize);
    let mut base = base.clone();
    // A loop of `steps` periods.
    base.timing.duration_2dof_s = base
        .timing
        .duration_2dof_s
        .max(steps as f64 * base.timing.dt);

    let nmpc = closed_loop(
        &variant(&base, ControllerKind::NMPC, Formulation::Decoupled),
        ControllerKind::NMPC,
        steps,
        None,
    )?;
    let ms = closed_loop(
        &variant(&base, ControllerKind::MSNMPC, Formulation::Decoupled),
        ControllerKind::MSNMPC,
        steps,
        None,
    )?;
    let msc = closed_loop(
        &variant(&base, ControllerKind::MSNMPC, Formulation::Coupled),
        ControllerKind::MSNMPC,
        steps,
        None,
    )?;

    let mut rows = Vec::new();
    // Np = Nc over HORIZONS × SCENARIOS, then Np alone (Nc = 3, 3 scenarios) to show the cost
    // per step against the prediction horizon for a fixed control horizon.
    let mut cases: Vec<(usize, usize, usize)> = Vec::new();
    for &np in &HORIZONS {
        for &ns in &SCENARIOS {
            cases.push((np, np, ns));
        }
    }
    for &np in &FIXED_NC_HORIZONS {
        cases.push((np, 3, 3));
    }
    for (formulation, name) in [
        (Formulation::Decoupled, "decoupled"),
        (Formulation::Coupled, "coupled"),
    ] {
        for &(np, nc, ns) in &cases {
            if interrupt::requested() {
                break;
            }
            {
                let mut s = variant(&base, ControllerKind::MSNMPC, formulation);
                s.controller.np = np;
                s.controller.nc = nc;
                // The scaling grid is over payload scenarios (named ones would override it).
                s.multistage.scenarios.clear();
                s.multistage.payloads_kg = (0..ns)
                    .map(|i| {
                        if ns == 1 {
                            0.0
                        } else {
                            2.0 * i as f64 / (ns - 1) as f64
                        }
                    })
                    .collect();
                s.multistage.robust_horizon = s.multistage.robust_horizon.clamp(1, nc);
                let floor = s.multistage.probability_floor;
                s.multistage.probability_floor = floor.min(0.5 / ns as f64);
                s.controller.sqp.qp = QpBackend::Dense;
                let stats = closed_loop(
                    &s,
                    ControllerKind::MSNMPC,
                    steps.min(CASE_STEPS),
                    Some(CASE_BUDGET),
                )?;
                let (structured, rti) = {
                    s.controller.sqp.qp = QpBackend::Structured;
                    let full = closed_loop(
                        &s,
                        ControllerKind::MSNMPC,
                        steps.min(CASE_STEPS),
                        Some(CASE_BUDGET),
                    )?;
                    s.controller.sqp.rti = true;
                    let rti = closed_loop(
                        &s,
                        ControllerKind::MSNMPC,
                        steps.min(CASE_STEPS),
                        Some(CASE_BUDGET),
                    )?;
                    (Some(full), Some(rti))
                };
                rows.push(ScalingRow {
                    np,
                    nc,
                    scenarios: ns,
                    formulation: name,
                    stats,
                    structured,
                    rti,
                });
            }
        }
    }

    let partial = interrupt::requested();
    let interrupted = || {
        CliError::Interrupted(format!(
            "interrupted by {}: the timings above are partial ({} of {} scaling rows)",
            interrupt::signal_name(),
            rows.len(),
            2 * cases.len()
        ))
    };
    if as_json {
        let stat = |l: &LoopStats| {
            json!({
                "p50_us": l.step.p50,
                "p99_us": l.step.p99,
                "mean_us": l.step.mean,
                "max_us": l.step.max,
                "iterations_mean": l.iterations_mean,
                "steps": l.steps,
                "wall_s": l.wall_s,
            })
        };
        let scaling: Vec<_> = rows
            .iter()
            .map(|r| {
                json!({
                    "np": r.np,
                    "nc": r.nc,
                    "scenarios": r.scenarios,
                    "formulation": r.formulation,
                    "p50_us": r.stats.step.p50,
                    "p99_us": r.stats.step.p99,
                    "mean_us": r.stats.step.mean,
                    "iterations_mean": r.stats.iterations_mean,
                    "steps": r.stats.steps,
                    "structured": r.structured.as_ref().map(|st| json!({
                        "p50_us": st.step.p50,
                        "p99_us": st.step.p99,
                        "mean_us": st.step.mean,
                        "iterations_mean": st.iterations_mean,
                        "steps": st.steps,
                    })),
                    "structured_rti": r.rti.as_ref().map(|st| json!({
                        "p50_us": st.step.p50,
                        "p99_us": st.step.p99,
                        "mean_us": st.step.mean,
                        "iterations_mean": st.iterations_mean,
                        "steps": st.steps,
                    })),
                })
            })
            .collect();
        let out = json!({
            "nmpc": stat(&nmpc),
            "msnmpc": stat(&ms),
            "msnmpc_coupled": stat(&msc),
            "sim_speed": ms.sim_speed,
            "scaling": scaling,
            "partial": partial,
        });
        println!("{out}");
        return if partial { Err(interrupted()) } else { Ok(()) };
    }
    if partial {
        println!("partial: interrupted, the timings below cover the steps run before it");
    }

    println!(
        "control step alone, 2-DOF default scenario, {steps} closed-loop steps (dt = {} s)",
        base.timing.dt
    );
    println!(
        "{:<16} {:>9} {:>9} {:>9} {:>9} {:>8} {:>10} {:>8}",
        "controller", "mean µs", "p50 µs", "p99 µs", "max µs", "iters", "sim s/s", "wall s"
    );
    for (name, l) in [("nmpc", &nmpc), ("msnmpc", &ms), ("msnmpc_coupled", &msc)] {
        println!(
            "{:<16} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>8.2} {:>10.1} {:>8.3}",
            name,
            l.step.mean,
            l.step.p50,
            l.step.p99,
            l.step.max,
            l.iterations_mean,
            l.sim_speed,
            l.wall_s
        );
    }
    println!();
    println!(
        "scaling (payloads spread over 0..2 kg; at most {} steps / {:.1} s per case)",
        steps.min(CASE_STEPS),
        CASE_BUDGET.as_secs_f64()
    );
    println!(
        "dense = condensed QP (scenario's Hessian model), structured = Riccati QP (Gauss-Newton, or exact if the scenario's model is; coupled: block-arrowhead tree, Gauss-Newton);"
    );
    println!(
        "ratio = dense p50 / structured p50, per-iteration ratio = (p50/iters) dense / structured;"
    );
    println!("rti p50 = structured with one real-time iteration per step (rti = true)");
    println!(
        "{:<10} {:>4} {:>4} {:>4} {:>11} {:>7} {:>11} {:>7} {:>7} {:>9} {:>9} {:>6}",
        "form",
        "Np",
        "Nc",
        "scen",
        "dense p50",
        "iters",
        "struct p50",
        "iters",
        "ratio",
        "per-iter",
        "rti p50",
        "steps"
    );
    for r in &rows {
        let (sp50, sit, ratio, per_iter) = match &r.structured {
            Some(st) => (
                format!("{:.1}", st.step.p50),
                format!("{:.2}", st.iterations_mean),
                format!("{:.2}", r.stats.step.p50 / st.step.p50),
                format!(
                    "{:.2}",
                    (r.stats.step.p50 / r.stats.iterations_mean.max(1e-9))
                        / (st.step.p50 / st.iterations_mean.max(1e-9))
                ),
            ),
            None => ("-".into(), "-".into(), "-".into(), "-".into()),
        };
        let rti_p50 = r
            .rti
            .as_ref()
            .map_or("-".into(), |l| format!("{:.1}", l.step.p50));
        println!(
            "{:<10} {:>4} {:>4} {:>4} {:>11.1} {:>7.2} {:>11} {:>7} {:>7} {:>9} {:>9} {:>6}",
            r.formulation,
            r.np,
            r.nc,
            r.scenarios,
            r.stats.step.p50,
            r.stats.iterations_mean,
            sp50,
            sit,
            ratio,
            per_iter,
            rti_p50,
            r.stats.steps
        );
    }
    if partial {
        return Err(interrupted());
    }
    Ok(())
}
