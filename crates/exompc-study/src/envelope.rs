//! Operating-envelope scans: a grid of scenario changes × payloads × controllers, every run
//! classified ([`exompc::sim::classify_run`]) and every cell judged against the acceptance
//! of [`exompc::sim::cell_verdict`] (the robust controller against the plain NMPC).
//!
//! A grid is either a list of named cells (the standard envelope, [`STANDARD_GRID`], or a
//! TOML file in its format) or the Cartesian product of `--set key=v1,v2` lists.

use crate::error::CliError;
use crate::io::{parse_value, set_keys};
use exompc::config::{ControllerKind, Experiment};
use exompc::control::{MonitorAction, SafetyReport};
use exompc::scenario::{gait_demand, limits, run_experiment_report, OneDof, TwoDof};
use exompc::sim::{
    cell_verdict, classify_run, ActuatorDemand, CellVerdict, Recorder, RunClass, RunStability,
    StabilityCriteria, StopWhen, Summary, TraceLog,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The standard envelope of issue 10 (`envelopes/standard.toml`): one change from the default
/// at a time, payloads 0-3 kg, NMPC and MS-NMPC.
pub const STANDARD_GRID: &str = include_str!("../../../envelopes/standard.toml");

/// One cell: a named set of scenario changes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cell {
    /// Display name.
    pub name: String,
    /// Experiment layout: 1 (knee) or 2 (hip and knee).
    #[serde(default = "two")]
    pub dof: u8,
    /// Dotted scenario keys and their values, applied in order.
    #[serde(default)]
    pub set: toml::Table,
}

fn two() -> u8 {
    2
}

/// A grid: cells × payloads × controllers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grid {
    /// True payloads (kg).
    pub payloads_kg: Vec<f64>,
    /// Controllers (`nmpc`, `msnmpc`, `pd`).
    pub controllers: Vec<String>,
    /// Cells.
    #[serde(rename = "cell")]
    pub cells: Vec<Cell>,
    /// Folder that gait files named by the cells (`trajectory.file`) are relative to: the grid
    /// file's folder (empty: the working directory).
    #[serde(skip)]
    pub base: std::path::PathBuf,
}

/// Controller kind from its command-line name.
pub fn controller_kind(name: &str) -> Result<ControllerKind, CliError> {
    match exompc::scenario::controller_by_name(name) {
        Some(c) => Ok(c.kind),
        None => Err(CliError::Usage(format!(
            "unknown controller `{name}` (allowed: {})",
            exompc::scenario::controllers()
                .iter()
                .map(|c| c.name())
                .collect::<Vec<_>>()
                .join(", ")
        ))),
    }
}

impl Grid {
    /// Parses a grid file (the format of [`STANDARD_GRID`]); `what` names it in errors.
    pub fn parse(text: &str, what: &str) -> Result<Grid, CliError> {
        let g: Grid = toml::from_str(text)
            .map_err(|e| CliError::Config(format!("{what}: {}", e.message().trim())))?;
        if g.cells.is_empty() || g.payloads_kg.is_empty() || g.controllers.is_empty() {
            return Err(CliError::Config(format!(
                "{what}: needs at least one [[cell]], payload and controller"
            )));
        }
        for c in &g.controllers {
            controller_kind(c).map_err(|e| CliError::Config(format!("{what}: {e}")))?;
        }
        Ok(g)
    }

    /// The standard envelope.
    pub fn standard() -> Grid {
        Grid::parse(STANDARD_GRID, "standard envelope").expect("the embedded grid parses")
    }

    /// The Cartesian product of `sets` (each `key=v1,v2,...`) as cells of layout `dof`.
    pub fn product(
        sets: &[String],
        dof: u8,
        payloads_kg: Vec<f64>,
        controllers: Vec<String>,
    ) -> Result<Grid, CliError> {
        let mut cells = vec![Cell {
            name: String::new(),
            dof,
            set: toml::Table::new(),
        }];
        for spec in sets {
            let (key, values) = spec.split_once('=').ok_or_else(|| {
                CliError::Usage(format!("--set `{spec}`: expected key=value[,value...]"))
            })?;
            let key = key.trim();
            let values = split_values(values);
            if key.is_empty() || values.is_empty() {
                return Err(CliError::Usage(format!(
                    "--set `{spec}`: expected key=value[,value...]"
                )));
            }
            let mut next = Vec::with_capacity(cells.len() * values.len());
            for c in &cells {
                for v in &values {
                    let mut c = c.clone();
                    c.set.insert(key.to_string(), parse_value(v));
                    let label = format!("{key}={}", v.trim());
                    c.name = if c.name.is_empty() {
                        label
                    } else {
                        format!("{}, {label}", c.name)
                    };
                    next.push(c);
                }
            }
            cells = next;
        }
        if cells.len() == 1 && cells[0].name.is_empty() {
            cells[0].name = "base".into();
        }
        Ok(Grid {
            payloads_kg,
            controllers,
            cells,
            base: std::path::PathBuf::new(),
        })
    }

    /// The scenario of `cell` on top of `base`, validated (errors name the cell and key); gait
    /// files relative to the working directory. See [`Grid::cell_scenario`].
    pub fn scenario(base: &Experiment, cell: &Cell) -> Result<Experiment, CliError> {
        Self::scenario_in(base, cell, std::path::Path::new(""))
    }

    /// The scenario of the grid's `cell` on top of `base`, gait files relative to the grid
    /// file's folder ([`Grid::base`]).
    pub fn cell_scenario(&self, base: &Experiment, cell: &Cell) -> Result<Experiment, CliError> {
        Self::scenario_in(base, cell, &self.base)
    }

    /// The cell's keys set together and validated once (a recorded gait needs
    /// `trajectory.kind = "recorded"` and `trajectory.file` at the same time; a cell that
    /// names only `trajectory.file` gets `kind = "recorded"` too), gait files read relative to
    /// `folder`.
    fn scenario_in(
        base: &Experiment,
        cell: &Cell,
        folder: &std::path::Path,
    ) -> Result<Experiment, CliError> {
        let mut changes: Vec<(String, toml::Value)> = cell
            .set
            .iter()
            .map(|(k, v)| (k.trim().to_string(), v.clone()))
            .collect();
        let names: Vec<&str> = changes.iter().map(|(k, _)| k.as_str()).collect();
        if names.contains(&"trajectory.file") && !names.contains(&"trajectory.kind") {
            changes.push((
                "trajectory.kind".into(),
                toml::Value::String("recorded".into()),
            ));
        }
        set_keys(base, &changes, folder)
            .map_err(|e| CliError::Config(format!("cell `{}`: {e}", cell.name)))
    }
}

/// Splits `a,b,[1,2],"x,y"` at the commas outside brackets and quotes.
fn split_values(s: &str) -> Vec<String> {
    let (mut out, mut cur, mut depth, mut quote) = (Vec::new(), String::new(), 0i32, false);
    for ch in s.chars() {
        match ch {
            '"' => quote = !quote,
            '[' | '{' if !quote => depth += 1,
            ']' | '}' if !quote => depth -= 1,
            ',' if !quote && depth == 0 => {
                out.push(std::mem::take(&mut cur));
                continue;
            }
            _ => {}
        }
        cur.push(ch);
    }
    out.push(cur);
    out.into_iter()
        .map(|v| v.trim().to_string())
        .filter(|v| !v.is_empty())
        .collect()
}

/// One classified run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvelopeRun {
    /// Index of the cell in the grid.
    pub cell: usize,
    /// True payload (kg).
    pub payload_kg: f64,
    /// Controller name.
    pub controller: String,
    /// The run's summary (`None` if it failed).
    pub summary: Option<Summary>,
    /// Its classification (`None` if it failed).
    pub stability: Option<RunStability>,
    /// Safety monitor trips.
    pub monitor_trips: u64,
    /// Time of the first trip (s).
    pub first_trip_s: Option<f64>,
    /// Why the run failed (e.g. the plant diverged).
    pub error: Option<String>,
}

impl EnvelopeRun {
    /// RMS strap forces (N), thigh then shank (1-DOF: shank).
    pub fn rms(&self) -> Vec<f64> {
        self.stability
            .as_ref()
            .map(|s| s.straps.iter().map(|x| x.rms_n).collect())
            .unwrap_or_default()
    }

    /// Class name, or `failed`.
    pub fn class_name(&self) -> &'static str {
        self.stability.as_ref().map_or("failed", |s| s.class.name())
    }
}

/// One (cell, payload) judged: the robust controller against the NMPC.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvelopeVerdict {
    /// Cell index.
    pub cell: usize,
    /// Cell name.
    pub name: String,
    /// True payload (kg).
    pub payload_kg: f64,
    /// The acceptance (`None` when a run is missing or failed: counts as failing).
    pub verdict: Option<CellVerdict>,
}

impl EnvelopeVerdict {
    /// Passes every acceptance criterion.
    pub fn pass(&self) -> bool {
        self.verdict.as_ref().is_some_and(|v| v.pass)
    }

    /// The failed criteria, comma-separated (`run failed` without a verdict).
    pub fn failures(&self) -> String {
        let Some(v) = &self.verdict else {
            return "run failed".into();
        };
        let mut f = Vec::new();
        if !v.stable {
            f.push("unstable");
        }
        if !v.rms_ok {
            f.push("RMS ≥ 20 N");
        }
        if !v.within_limits {
            f.push("limit violation");
        }
        if !v.no_worse_than_nmpc {
            f.push("worse than NMPC");
        }
        if !v.no_monitor_trip {
            f.push("monitor trips");
        }
        f.join(", ")
    }
}

/// What the gait of one (cell, payload) asks of the actuator ([`exompc::sim::actuator_demand`]):
/// the torque the robot needs to move exactly with the human's desired motion, so that the
/// straps carry nothing. It depends on the cell and payload, not on the controller; where it
/// exceeds the torque limit, no controller can keep the strap forces small.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvelopeDemand {
    /// Cell index.
    pub cell: usize,
    /// True payload (kg).
    pub payload_kg: f64,
    /// Largest required `|T|` per joint (N·m), hip then knee (1-DOF: knee).
    pub peak_nm: Vec<f64>,
    /// RMS of the required torque per joint (N·m).
    pub rms_nm: Vec<f64>,
    /// Share of the control instants at which some joint needs more than `torque_max_nm`.
    pub beyond_limit_fraction: f64,
    /// The torque limit (`controller.torque_max`, N·m).
    pub torque_max_nm: f64,
}

impl EnvelopeDemand {
    fn of(s: &Experiment, cell: usize, dof: u8) -> Self {
        match dof {
            1 => Self::from_demand(gait_demand::<OneDof, 1>(s), cell, s.uncertainty.payload_kg),
            _ => Self::from_demand(gait_demand::<TwoDof, 2>(s), cell, s.uncertainty.payload_kg),
        }
    }

    fn from_demand<const N: usize>(d: ActuatorDemand<N>, cell: usize, payload_kg: f64) -> Self {
        EnvelopeDemand {
            cell,
            payload_kg,
            peak_nm: d.peak_nm.iter().copied().collect(),
            rms_nm: d.rms_nm.iter().copied().collect(),
            beyond_limit_fraction: d.beyond_limit_fraction,
            torque_max_nm: d.torque_max,
        }
    }

    /// Whether the gait needs more than the torque limit at some instant.
    pub fn exceeds_limit(&self) -> bool {
        self.beyond_limit_fraction > 0.0
    }
}

/// The result of a scan (`envelope.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// Thresholds used.
    pub criteria: StabilityCriteria,
    /// The grid.
    pub grid: Grid,
    /// Every run, cell-major, then payload, then controller.
    pub runs: Vec<EnvelopeRun>,
    /// Every (cell, payload) with both `msnmpc` and `nmpc` runs.
    pub verdicts: Vec<EnvelopeVerdict>,
    /// What each (cell, payload)'s gait asks of the actuator, cell-major.
    #[serde(default)]
    pub demands: Vec<EnvelopeDemand>,
    /// The scan was interrupted (SIGINT/SIGTERM): the runs not completed carry the error
    /// `not run (interrupted)` and count as failed.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub partial: bool,
}

impl Envelope {
    /// The run of `(cell, payload, controller)`.
    pub fn run(&self, cell: usize, payload: f64, controller: &str) -> Option<&EnvelopeRun> {
        self.runs
            .iter()
            .find(|r| r.cell == cell && r.payload_kg == payload && r.controller == controller)
    }

    /// What the gait of `(cell, payload)` asks of the actuator.
    pub fn demand(&self, cell: usize, payload: f64) -> Option<&EnvelopeDemand> {
        self.demands
            .iter()
            .find(|d| d.cell == cell && d.payload_kg == payload)
    }

    /// The verdicts that fail.
    pub fn failing(&self) -> Vec<&EnvelopeVerdict> {
        self.verdicts.iter().filter(|v| !v.pass()).collect()
    }
}

fn first_trip(rep: &SafetyReport) -> Option<f64> {
    rep.events
        .iter()
        .find(|e| e.action == MonitorAction::Trip)
        .map(|e| e.t)
}

/// The error of a run a SIGINT/SIGTERM stopped or kept from starting.
const NOT_RUN: &str = "not run (interrupted)";

fn run_one(
    s: &Experiment,
    dof: u8,
    c: &StabilityCriteria,
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<(Summary, RunStability, SafetyReport), String> {
    if crate::interrupt::requested() {
        return Err(NOT_RUN.into());
    }
    let lim = limits(s);
    let dt = s.timing.dt;
    let mut stop = StopWhen(|| stop() || crate::interrupt::requested());
    let planned = s.control_steps(usize::from(dof));
    let (sum, rep, stability) = match dof {
        1 => {
            let mut log = TraceLog::<1>::default();
            let (sum, rep) = run_experiment_report::<OneDof, 1>(
                s,
                &mut [&mut log as &mut dyn Recorder<1>, &mut stop],
            )
            .map_err(|e| e.to_string())?;
            let st = (sum.steps >= planned).then(|| classify_run(&log, &lim, dt, c));
            (sum, rep, st)
        }
        _ => {
            let mut log = TraceLog::<2>::default();
            let (sum, rep) = run_experiment_report::<TwoDof, 2>(
                s,
                &mut [&mut log as &mut dyn Recorder<2>, &mut stop],
            )
            .map_err(|e| e.to_string())?;
            let st = (sum.steps >= planned).then(|| classify_run(&log, &lim, dt, c));
            (sum, rep, st)
        }
    };
    // A run stopped early by a signal is not classified: it counts as not run.
    let stability = stability.ok_or_else(|| NOT_RUN.to_string())?;
    Ok((sum, stability, rep))
}

/// `s` with the safety monitors out of the way (thresholds beyond reach), to scan the bare
/// controller; plausibility checks and torque limits stay.
pub fn without_monitors(s: &Experiment) -> Experiment {
    let mut s = s.clone();
    let m = &mut s.monitors;
    m.tracking_error_max_rad = 1e300;
    m.force_max_n = 1e300;
    m.sensor_timeout_s = 1e300;
    m.oscillation_force_rms_n = 1e300;
    m.oscillation_torque_rms_nm = 1e300;
    s
}

/// Runs `grid` on top of `base` in parallel (rayon), calling `progress` after each run.
/// Bad cells (unknown key, invalid value) are reported before anything runs.
pub fn scan(
    base: &Experiment,
    grid: &Grid,
    criteria: &StabilityCriteria,
    progress: &(dyn Fn() + Sync),
) -> Result<Envelope, CliError> {
    scan_until(base, grid, criteria, progress, &|| false)
}

/// [`scan`] that can be cancelled: once `stop()` returns true (polled before each cell's gait
/// demand and once per control step of every run), the scan ends with
/// [`CliError::Interrupted`] before its runs, or the running runs end between two steps and
/// the runs not started yet are skipped, all with an error entry (the caller discards that
/// partial envelope).
pub fn scan_until(
    base: &Experiment,
    grid: &Grid,
    criteria: &StabilityCriteria,
    progress: &(dyn Fn() + Sync),
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<Envelope, CliError> {
    let mut jobs = Vec::new();
    let mut demands = Vec::new();
    for (i, cell) in grid.cells.iter().enumerate() {
        if !(1..=2).contains(&cell.dof) {
            return Err(CliError::Config(format!(
                "cell `{}`: dof {} (allowed: 1 or 2)",
                cell.name, cell.dof
            )));
        }
        let s = grid.cell_scenario(base, cell)?;
        for &p in &grid.payloads_kg {
            let mut sp = s.clone();
            sp.uncertainty.payload_kg = p;
            sp.validate().map_err(|e| {
                CliError::Config(format!("cell `{}`, payload {p} kg: {e}", cell.name))
            })?;
            if stop() {
                return Err(CliError::Interrupted(
                    "envelope scan stopped before its runs".into(),
                ));
            }
            demands.push(EnvelopeDemand::of(&sp, i, cell.dof));
            for c in &grid.controllers {
                let mut s = s.clone();
                s.controller.kind = controller_kind(c)?;
                s.uncertainty.payload_kg = p;
                s.validate().map_err(|e| {
                    CliError::Config(format!("cell `{}`, payload {p} kg: {e}", cell.name))
                })?;
                jobs.push((i, p, c.clone(), s, cell.dof));
            }
        }
    }
    let runs: Vec<EnvelopeRun> = jobs
        .par_iter()
        .map(|(i, p, c, s, dof)| {
            let r = if stop() {
                Err("not run: the scan was stopped".to_string())
            } else {
                run_one(s, *dof, criteria, stop)
            };
            progress();
            let (summary, stability, trips, first, error) = match r {
                Ok((sum, st, rep)) => (
                    Some(sum),
                    Some(st),
                    rep.monitor_trips,
                    first_trip(&rep),
                    None,
                ),
                Err(e) => (None, None, 0, None, Some(e)),
            };
            EnvelopeRun {
                cell: *i,
                payload_kg: *p,
                controller: c.clone(),
                summary,
                stability,
                monitor_trips: trips,
                first_trip_s: first,
                error,
            }
        })
        .collect();
    let mut env = Envelope {
        criteria: *criteria,
        grid: grid.clone(),
        runs,
        verdicts: Vec::new(),
        demands,
        partial: false,
    };
    env.partial = env.runs.iter().any(|r| r.error.as_deref() == Some(NOT_RUN));
    if grid.controllers.iter().any(|c| c == "msnmpc")
        && grid.controllers.iter().any(|c| c == "nmpc")
    {
        for (i, cell) in grid.cells.iter().enumerate() {
            for &p in &grid.payloads_kg {
                let (ms, nm) = (env.run(i, p, "msnmpc"), env.run(i, p, "nmpc"));
                let demand = env.demand(i, p);
                let verdict = match (ms, nm) {
                    (Some(ms), Some(nm)) => match (&ms.stability, &ms.summary, &nm.stability) {
                        (Some(st), Some(sum), Some(_)) => Some(cell_verdict(
                            st,
                            &nm.rms(),
                            nm.monitor_trips,
                            sum.limit_violations,
                            ms.monitor_trips,
                            p,
                            demand.map_or(0.0, |d| d.beyond_limit_fraction),
                            criteria,
                        )),
                        _ => None,
                    },
                    _ => None,
                };
                env.verdicts.push(EnvelopeVerdict {
                    cell: i,
                    name: cell.name.clone(),
                    payload_kg: p,
                    verdict,
                });
            }
        }
    }
    Ok(env)
}

fn pair(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:.1}"))
        .collect::<Vec<_>>()
        .join(" / ")
}

/// The Markdown report (`envelope.md`): one row per (cell, payload).
pub fn markdown(env: &Envelope) -> String {
    let ctrls = &env.grid.controllers;
    let mut out = String::new();
    if env.partial {
        let not_run = env
            .runs
            .iter()
            .filter(|r| r.error.as_deref() == Some(NOT_RUN))
            .count();
        out += &format!(
            "Partial: the scan was interrupted; {} of {} runs completed (the others show as failed).\n\n",
            env.runs.len() - not_run,
            env.runs.len()
        );
    }
    out += "| cell | payload (kg) | gait needs, peak (N·m) | beyond ±T_max (%) |";
    for c in ctrls {
        out += &format!(
            " {c} RMS F (N) | {c} class | {c} HF % | {c} growth | {c} T-lim % | {c} trips |"
        );
    }
    let judged = !env.verdicts.is_empty();
    if judged {
        out += " verdict |";
    }
    out += "\n|---|---:|---:|---:|";
    out += &"---:|---|---:|---:|---:|---:|".repeat(ctrls.len());
    if judged {
        out += "---|";
    }
    out += "\n";
    for (i, cell) in env.grid.cells.iter().enumerate() {
        for &p in &env.grid.payloads_kg {
            out += &format!("| {} | {p} |", cell.name);
            out += &match env.demand(i, p) {
                Some(d) => format!(
                    " {} | {:.1} |",
                    pair(&d.peak_nm),
                    100.0 * d.beyond_limit_fraction
                ),
                None => " – | – |".to_string(),
            };
            for c in ctrls {
                match env.run(i, p, c) {
                    Some(r) => match &r.stability {
                        Some(st) => {
                            out += &format!(
                                " {} | {} | {:.0} | {:.2} | {:.1} | {} |",
                                pair(&r.rms()),
                                st.class.name(),
                                100.0 * st.max_high_frequency_fraction(),
                                st.max_growth(),
                                100.0 * st.torque_limit_fraction,
                                r.monitor_trips
                            );
                        }
                        None => out += " – | failed | – | – | – | – |",
                    },
                    None => out += " – | – | – | – | – | – |",
                }
            }
            if judged {
                let v = env
                    .verdicts
                    .iter()
                    .find(|v| v.cell == i && v.payload_kg == p);
                out += &match v {
                    Some(v) if v.pass() => match &v.verdict {
                        Some(x) if x.trips_waived => {
                            " pass (beyond the actuator: torque-limited, trips waived) |"
                                .to_string()
                        }
                        Some(x) if x.rms_waived => " pass (torque-limited) |".to_string(),
                        _ => " pass |".to_string(),
                    },
                    Some(v) => format!(" **fail**: {} |", v.failures()),
                    None => " – |".to_string(),
                };
            }
            out += "\n";
        }
    }
    if judged {
        let fail = env.failing();
        out += &format!(
            "\n{} of {} cells pass (MS-NMPC against NMPC: power above {} Hz < {:.0} %, last {} s RMS ≤ {}× the first, RMS < {} N unless on the torque limit in > {:.0} % of the steps, no limit violation, RMS ≤ NMPC's at ≥ 1 kg and ≤ 1.1× at 0 kg unless only the NMPC run tripped a monitor, no monitor trip unless the gait needs more than the torque limit on > {:.0} % of the instants and the NMPC tripped too).\n",
            env.verdicts.len() - fail.len(),
            env.verdicts.len(),
            env.criteria.cutoff_hz,
            100.0 * env.criteria.max_high_frequency_fraction,
            env.criteria.window_s,
            env.criteria.max_growth,
            env.criteria.max_rms_n,
            100.0 * env.criteria.max_limit_fraction,
            100.0 * env.criteria.max_limit_fraction
        );
        let waived: Vec<String> = env
            .verdicts
            .iter()
            .filter(|v| v.pass() && v.verdict.as_ref().is_some_and(|x| x.trips_waived))
            .map(|v| format!("{} at {} kg", v.name, v.payload_kg))
            .collect();
        if !waived.is_empty() {
            out += &format!(
                "Passing with their monitor trips waived (the gait needs more torque than the actuator has, the NMPC tripped too): {}.\n",
                waived.join("; ")
            );
        }
        let beyond: Vec<String> = fail
            .iter()
            .filter_map(|v| {
                let d = env.demand(v.cell, v.payload_kg)?;
                d.exceeds_limit().then(|| {
                    format!(
                        "{} at {} kg (up to {} N·m against ±{} N·m, {:.0} % of the time)",
                        v.name,
                        v.payload_kg,
                        d.peak_nm
                            .iter()
                            .map(|x| format!("{x:.0}"))
                            .collect::<Vec<_>>()
                            .join(" / "),
                        d.torque_max_nm,
                        100.0 * d.beyond_limit_fraction
                    )
                })
            })
            .collect();
        if !beyond.is_empty() {
            out += &format!(
                "Failing cells whose gait needs more torque than the actuator has (the straps carry the shortfall whatever the controller does): {}.\n",
                beyond.join("; ")
            );
        }
    }
    out
}

/// Count of runs per class, for a one-line summary.
pub fn class_counts(env: &Envelope, controller: &str) -> Vec<(RunClass, usize)> {
    [
        RunClass::Stable,
        RunClass::Saturating,
        RunClass::LimitCycle,
        RunClass::Growing,
    ]
    .into_iter()
    .map(|k| {
        (
            k,
            env.runs
                .iter()
                .filter(|r| {
                    r.controller == controller && r.stability.as_ref().is_some_and(|s| s.class == k)
                })
                .count(),
        )
    })
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_grid_and_products() {
        let g = Grid::standard();
        assert_eq!(g.cells.len(), 18);
        assert_eq!(g.payloads_kg, vec![0.0, 1.0, 2.0, 3.0]);
        let base = Experiment::default();
        for c in &g.cells {
            Grid::scenario(&base, c).unwrap();
        }
        let s = Grid::scenario(&base, &g.cells[12]).unwrap();
        assert_eq!((s.straps.stiffness, s.straps.damping), (1875.0, 187.4));
        let p = Grid::product(
            &[
                "robot.payload_position_m=0.1,0.3,0.43".into(),
                "uncertainty.filter_window=1,5,9".into(),
            ],
            2,
            vec![0.0],
            vec!["nmpc".into()],
        )
        .unwrap();
        assert_eq!(p.cells.len(), 9);
        assert_eq!(
            p.cells[4].name,
            "robot.payload_position_m=0.3, uncertainty.filter_window=5"
        );
        let s = Grid::scenario(&base, &p.cells[8]).unwrap();
        assert_eq!(s.robot.payload_position_m, 0.43);
        assert_eq!(s.uncertainty.filter_window, 9);
        assert_eq!(
            split_values("1, [1,2], \"a,b\""),
            vec!["1", "[1,2]", "\"a,b\""]
        );
        // Bad keys and values name the cell and the field.
        let bad = Grid::product(&["robot.payload_pos=0.1".into()], 2, vec![0.0], vec![]).unwrap();
        let e = Grid::scenario(&base, &bad.cells[0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("payload_position_m"), "{e}");
        let bad = Grid::product(
            &["robot.payload_position_m=0.5".into()],
            2,
            vec![0.0],
            vec![],
        )
        .unwrap();
        let e = Grid::scenario(&base, &bad.cells[0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("robot.payload_position_m"), "{e}");
        assert!(Grid::product(&["novalue".into()], 2, vec![0.0], vec![]).is_err());
        assert!(Grid::parse(
            "payloads_kg = [0.0]\ncontrollers = [\"x\"]\n[[cell]]\nname = \"a\"\n",
            "f"
        )
        .is_err());
    }
}
