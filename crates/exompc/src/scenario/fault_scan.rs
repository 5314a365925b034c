//! The fault-response scan (`exompc faults`, issue 28): sensor fault kinds × channel groups ×
//! durations × start times × payloads, each run against the same run without the fault, with
//! a verdict per cell (peak true strap force, RMS ratio, monitor trips, held steps, latch).

use super::error::RunError;
use super::fault_goals::{meets_goals, peak_goal_n, rms_ratio, spike_magnitude, ChannelGroup};
use super::layout::TwoDof;
use super::run::run_experiment_report;
use crate::config::Experiment;
use crate::sim::{FaultEvent, FaultKind, Recorder, StepRecord};
use rayon::prelude::*;
use serde::Serialize;

/// The scan's axes; every combination is one faulted run (2-DOF, the scenario's controller).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FaultGrid {
    /// Fault kinds.
    pub kinds: Vec<FaultKind>,
    /// Channel groups.
    pub groups: Vec<ChannelGroup>,
    /// Fault durations (s).
    pub durations_s: Vec<f64>,
    /// Fault start times (s).
    pub starts_s: Vec<f64>,
    /// True payloads (kg).
    pub payloads_kg: Vec<f64>,
    /// Run length (s).
    pub run_s: f64,
}

impl Default for FaultGrid {
    /// The 64-run grid: spike, dropout, NaN, stuck × all, angles, velocities, forces ×
    /// 60 and 200 ms × a start at 3 s × 0 and 2 kg, 10-s runs.
    fn default() -> Self {
        FaultGrid {
            kinds: vec![
                FaultKind::Spike,
                FaultKind::Dropout,
                FaultKind::Nan,
                FaultKind::Stuck,
            ],
            groups: ChannelGroup::ALL.to_vec(),
            durations_s: vec![0.06, 0.2],
            starts_s: vec![3.0],
            payloads_kg: vec![0.0, 2.0],
            run_s: 10.0,
        }
    }
}

/// One scanned cell and its verdict.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FaultCell {
    /// Fault kind.
    pub kind: FaultKind,
    /// Channel group.
    pub group: ChannelGroup,
    /// Fault duration (s).
    pub duration_s: f64,
    /// Fault start (s).
    pub start_s: f64,
    /// True payload (kg).
    pub payload_kg: f64,
    /// Peak true strap force over the run (N).
    pub peak_force_n: f64,
    /// The same run without the fault: peak true strap force (N).
    pub clean_peak_force_n: f64,
    /// Largest per-strap ratio of the RMS true strap force to the clean run's.
    pub rms_ratio: f64,
    /// Monitor trips.
    pub monitor_trips: u64,
    /// Steps a monitor response set the torque.
    pub monitor_steps: u64,
    /// Steps the controller stepped on estimates of rejected channels.
    pub estimated_steps: u64,
    /// The supervisor latched.
    pub latched: bool,
    /// Torque-limit violations.
    pub limit_violations: u64,
    /// The goal on the peak force of this cell ([`peak_goal_n`]).
    pub peak_goal_n: f64,
    /// Verdict: limits held, no latch, peak ≤ its goal and (faults up to 200 ms) RMS ratio
    /// ≤ [`RMS_RATIO_GOAL`](super::RMS_RATIO_GOAL) ([`meets_goals`]).
    pub pass: bool,
}

/// Peak |true strap force| of a run.
#[derive(Default)]
struct Peak(f64);

impl<const N: usize> Recorder<N> for Peak {
    fn record(&mut self, r: &StepRecord<'_, N>) -> std::io::Result<()> {
        for f in r.force_true.iter() {
            self.0 = self.0.max(f.abs());
        }
        Ok(())
    }
}

struct Outcome {
    peak: f64,
    rms: [f64; 2],
    trips: u64,
    monitor_steps: u64,
    estimated: u64,
    latched: bool,
    violations: u64,
}

fn run_one(s: &Experiment) -> Result<Outcome, RunError> {
    let mut peak = Peak::default();
    let (sum, rep) = run_experiment_report::<TwoDof, 2>(s, &mut [&mut peak])?;
    Ok(Outcome {
        peak: peak.0,
        rms: [
            sum.rms_force_n.thigh.unwrap_or(0.0),
            sum.rms_force_n.shank.unwrap_or(0.0),
        ],
        trips: rep.monitor_trips,
        monitor_steps: rep.monitor_steps,
        estimated: rep.estimated_steps,
        latched: rep.latched_at.is_some(),
        violations: sum.limit_violations,
    })
}

/// The faulted scenario of a cell: `base` (2-DOF, `run_s` long, `payload_kg`) with one
/// `[[faults.events]]` per channel of `group`.
pub fn cell_scenario(
    base: &Experiment,
    run_s: f64,
    payload_kg: f64,
    fault: Option<(FaultKind, ChannelGroup, f64, f64)>,
) -> Experiment {
    let mut s = base.clone();
    s.uncertainty.payload_kg = payload_kg;
    s.timing.duration_2dof_s = run_s;
    s.faults.events = match fault {
        None => Vec::new(),
        Some((kind, group, start_s, duration_s)) => group
            .channels()
            .iter()
            .map(|&channel| FaultEvent {
                kind,
                channel,
                start_s,
                duration_s,
                magnitude: if kind == FaultKind::Spike {
                    spike_magnitude(channel)
                } else {
                    0.0
                },
            })
            .collect(),
    };
    s
}

/// Runs every cell of `grid` on top of `base` (and, per payload, the clean run it is judged
/// against) in parallel, calling `progress` after each run; cells in the order kinds ×
/// groups × durations × starts × payloads. A scenario that does not validate (a payload out of
/// range, a start beyond the run) is an error before anything runs.
pub fn run_fault_scan(
    base: &Experiment,
    grid: &FaultGrid,
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<FaultCell>, RunError> {
    let mut cells = Vec::new();
    for &kind in &grid.kinds {
        for &group in &grid.groups {
            for &dur in &grid.durations_s {
                for &start in &grid.starts_s {
                    for &p in &grid.payloads_kg {
                        cells.push((kind, group, dur, start, p));
                    }
                }
            }
        }
    }
    for &p in &grid.payloads_kg {
        cell_scenario(base, grid.run_s, p, None).validate()?;
    }
    if let Some(&(k, g, d, st, p)) = cells.first() {
        cell_scenario(base, grid.run_s, p, Some((k, g, st, d))).validate()?;
    }
    let clean: Vec<Outcome> = grid
        .payloads_kg
        .par_iter()
        .map(|&p| {
            let o = run_one(&cell_scenario(base, grid.run_s, p, None));
            progress();
            o
        })
        .collect::<Result<_, _>>()?;
    cells
        .par_iter()
        .map(|&(kind, group, dur, start, p)| {
            let o = run_one(&cell_scenario(
                base,
                grid.run_s,
                p,
                Some((kind, group, start, dur)),
            ));
            progress();
            let o = o?;
            let ci = grid
                .payloads_kg
                .iter()
                .position(|&q| q == p)
                .unwrap_or_default();
            let c = &clean[ci];
            let ratio = rms_ratio(o.rms, c.rms);
            let goal = peak_goal_n(group, dur);
            let pass = meets_goals(group, dur, o.peak, ratio, o.latched, o.violations);
            Ok(FaultCell {
                kind,
                group,
                duration_s: dur,
                start_s: start,
                payload_kg: p,
                peak_force_n: o.peak,
                clean_peak_force_n: c.peak,
                rms_ratio: ratio,
                monitor_trips: o.trips,
                monitor_steps: o.monitor_steps,
                estimated_steps: o.estimated,
                latched: o.latched,
                limit_violations: o.violations,
                peak_goal_n: goal,
                pass,
            })
        })
        .collect()
}

/// The scan as a markdown table (one row per cell) with a pass count.
pub fn fault_scan_markdown(cells: &[FaultCell]) -> String {
    let mut s = String::from(
        "| kind | group | duration (s) | start (s) | payload (kg) | peak F (N) | goal (N) | RMS × clean | trips | held steps | estimated steps | latched | verdict |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|\n",
    );
    for c in cells {
        s += &format!(
            "| {} | {} | {:.2} | {:.2} | {:.1} | {:.1} | {:.0} | {:.2} | {} | {} | {} | {} | {} |\n",
            c.kind.name(),
            c.group.name(),
            c.duration_s,
            c.start_s,
            c.payload_kg,
            c.peak_force_n,
            c.peak_goal_n,
            c.rms_ratio,
            c.monitor_trips,
            c.monitor_steps,
            c.estimated_steps,
            if c.latched { "yes" } else { "no" },
            if c.pass { "pass" } else { "FAIL" },
        );
    }
    let n = cells.iter().filter(|c| c.pass).count();
    s += &format!("\n{n} of {} cells pass.\n", cells.len());
    s
}
