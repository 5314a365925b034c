//! Running one experiment of an [`Experiment`] (closed loop, metrics, safety report) and the
//! fault-injected soak run.

use super::build::limits;
use super::error::RunError;
use super::fault_goals::{episodes, soak_fault_classes, EpisodeStats, SoakFaultClass};
use super::layout::{plant_params, uncertainty, Dof, TwoDof};
use super::registry::build_supervised;
#[cfg(not(feature = "std"))]
use crate::clock::Instant;
use crate::config::{ControllerKind, Experiment};
use crate::control::{Controller, MonitorEvent, SafetyReport};
use crate::sim::{
    default_schedule, repeat_schedule, run_closed_loop, Metrics, Plant, Recorder, SafetySummary,
    Sensors, SoakStats, StepRecord, Summary,
};
use alloc::{string::String, vec::Vec};
use nalgebra::SVector;
use serde::Serialize;
#[cfg(feature = "std")]
use std::time::Instant;

/// Run the closed loop of scenario `s` with controller `s.controller.kind` in layout `D` for
/// `s.duration_s(D::DOF)`, feeding every step to `recorders`; returns the summary (paper
/// Table 2 metrics). The sensors inject the `[faults]` of `s`; the controller runs under the
/// safety [`Supervisor`](crate::control::Supervisor) (see [`run_experiment_report`] for its event log).
/// A recorder returning [`stop_requested`](crate::sim::stop_requested) ends the run early
/// with the summary of the steps run so far.
pub fn run_experiment<D: Dof<N>, const N: usize>(
    s: &Experiment,
    recorders: &mut [&mut dyn Recorder<N>],
) -> Result<Summary, RunError> {
    run_experiment_report::<D, N>(s, recorders).map(|(summary, _)| summary)
}

/// Stops a run whose plant state stops being finite (e.g. a plant step too long for RK4).
struct DivergenceGuard {
    diverged_at: Option<f64>,
}

impl<const N: usize> Recorder<N> for DivergenceGuard {
    fn record(&mut self, r: &StepRecord<'_, N>) -> crate::sim::RecordResult {
        let finite = |v: &SVector<f64, N>| v.iter().all(|x| x.is_finite());
        if finite(&r.robot.q) && finite(&r.robot.qd) && finite(&r.human.q) && finite(&r.human.qd) {
            Ok(())
        } else {
            self.diverged_at = Some(r.t);
            Err(crate::sim::record_error("plant state is not finite"))
        }
    }
}

/// Step-time samples preallocated at most (longer runs grow the buffer as they go, instead
/// of aborting on a huge up-front allocation).
const MAX_PREALLOCATED_STEPS: usize = 1 << 22;

/// [`run_experiment`], also returning the safety supervisor's counters and monitor events.
pub fn run_experiment_report<D: Dof<N>, const N: usize>(
    s: &Experiment,
    recorders: &mut [&mut dyn Recorder<N>],
) -> Result<(Summary, SafetyReport), RunError> {
    s.validate()?;
    s.check_trajectory(D::DOF)?;
    let mut controller = build_supervised::<D, N>(s, s.controller.kind)?;
    let mut plant = Plant::new(plant_params::<D, N>(s), D::trajectory(s));
    let mut sensors =
        Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults);
    let steps = s.control_steps(D::DOF);
    let mut metrics = Metrics::with_capacity(steps.min(MAX_PREALLOCATED_STEPS));
    let mut guard = DivergenceGuard { diverged_at: None };
    {
        let mut all: Vec<&mut dyn Recorder<N>> = Vec::with_capacity(recorders.len() + 2);
        all.push(&mut guard);
        all.push(&mut metrics);
        for r in recorders.iter_mut() {
            all.push(&mut **r);
        }
        let result = run_closed_loop(
            &mut plant,
            &mut sensors,
            &mut controller,
            &limits(s),
            steps,
            &mut all,
        );
        if let Some(t) = guard.diverged_at {
            return Err(RunError::Diverged { t });
        }
        match result {
            // Ended early on request: the summary covers the steps run (`steps` tells).
            #[cfg(feature = "std")]
            Err(e) if crate::sim::is_stop_requested(&e) => {}
            r => r?,
        }
    }
    let mut summary = metrics.summary(
        controller.name(),
        D::DOF,
        s.uncertainty.payload_kg,
        s.timing.dt,
    );
    if super::controller_info(s.controller.kind)?.multistage {
        summary.scenarios = Some(crate::config::scenarios::names(s));
    }
    summary.solver = summary_solver(s, D::DOF)?;
    summary.safety = SafetySummary::from_report(controller.report());
    Ok((summary, controller.report().clone()))
}

/// The run summary's `solver` for the controller of `s` with `joints` joints: what
/// `[controller.sqp] qp` and `hessian` resolve to ([`super::solver_choice`]) for the plain
/// NMPC and the multi-stage entries of the registry, `None` for the others (`pd`). Fails
/// only for a `controller.kind` the registry does not know.
pub fn summary_solver(
    s: &Experiment,
    joints: usize,
) -> Result<Option<crate::control::SolverChoice>, RunError> {
    let multistage = super::controller_info(s.controller.kind)?.multistage;
    Ok((multistage || s.controller.kind == ControllerKind::NMPC)
        .then(|| super::build::solver_choice(s, joints, multistage)))
}

/// Result of [`run_soak`] (written as `soak.json` by `exompc soak`).
#[derive(Clone, Debug, Serialize)]
pub struct SoakReport {
    /// Controller name.
    pub controller: String,
    /// True payload (kg).
    pub payload_kg: f64,
    /// Simulated time (s).
    pub simulated_s: f64,
    /// Injected fault events.
    pub fault_events: usize,
    /// Online counters.
    #[serde(flatten)]
    pub stats: SoakStats,
    /// Monitor trips (all monitors).
    pub monitor_trips: u64,
    /// Wall time (s) of the run and its fault-free reference, informative only.
    pub wall_time_s: f64,
    /// The first logged monitor events (at most 4096).
    pub monitor_events: Vec<MonitorEvent>,
    /// Monitor events not logged (log full).
    pub monitor_events_dropped: u64,
    /// Handovers (a controller-failure monitor taking the torque; what counts toward the
    /// latch).
    pub handovers: u64,
    /// Times the oscillating transparent fallback was replaced by the protective stop.
    pub fallback_stops: u64,
    /// Times the configured `hold` or `ramp_to_zero` handed the torque to the transparent
    /// fallback because the trip's cause persisted.
    pub escalations: u64,
    /// Times encoder channels believed on smoothness alone were rejected again because the
    /// controller failed right after (for an angle the protective stop followed).
    pub revocations: u64,
    /// Simulated time (s) at which the supervisor latched its response, `null` if it did not.
    pub latched_at_s: Option<f64>,
    /// The monitor whose trip latched it (`tracking_error`, ...), `null` if it did not.
    pub latched_by: Option<String>,
    /// How long (s) the latch alone kept the torque from the controller.
    pub latched_for_s: f64,
    /// Steps on which a rejected sensor channel was replaced by its estimate.
    pub estimated_steps: u64,
    /// Sensor channel fault episodes detected.
    pub sensor_faults: u64,
    /// Injected fault episodes judged against issue 28's goals ([`soak_fault_classes`]: peak
    /// true strap force, RMS over the episode against the same run without faults, limits,
    /// no latch).
    pub fault_episodes: u64,
    /// Of those, the episodes that met the goals.
    pub fault_episodes_passing: u64,
    /// The verdicts per class of injected fault (kind, channels, duration).
    pub fault_classes: Vec<SoakFaultClass>,
}

/// The soak scenario: `base` as a 2-DOF MS-NMPC run of `seconds` simulated seconds with true
/// payload `payload_kg`; when `base` has no fault events, [`default_schedule`] repeated every
/// 60 s.
pub fn soak_scenario(base: &Experiment, seconds: f64, payload_kg: f64) -> Experiment {
    let mut s = base.clone();
    s.controller.kind = ControllerKind::MSNMPC;
    s.uncertainty.payload_kg = payload_kg;
    s.timing.duration_2dof_s = seconds;
    if s.faults.events.is_empty() {
        s.faults.events = repeat_schedule(&default_schedule(0.0, 2), 60.0, seconds);
    }
    s
}

/// Run the soak scenario of [`soak_scenario`] (2-DOF), feeding every step to `recorders` as
/// well, then (when it has fault episodes) the same scenario without faults for as long as the
/// first run got (its steps fed to `reference`; the same length, as the plant's body-mass ramp
/// spans the run), against which every injected fault episode is judged
/// ([`soak_fault_classes`]). Memory stays constant apart from the summary's step-time samples
/// and a few counters per fault episode.
pub fn run_soak(
    base: &Experiment,
    seconds: f64,
    payload_kg: f64,
    recorders: &mut [&mut dyn Recorder<2>],
    reference: &mut [&mut dyn Recorder<2>],
) -> Result<SoakReport, RunError> {
    let s = soak_scenario(base, seconds, payload_kg);
    let eps = episodes(&s.faults.events);
    let mut stats = SoakStats::default();
    let mut faulted = EpisodeStats::new(&eps);
    let start = Instant::now();
    let (summary, report) = {
        let mut all: Vec<&mut dyn Recorder<2>> = Vec::with_capacity(recorders.len() + 2);
        all.push(&mut stats);
        all.push(&mut faulted);
        for r in recorders.iter_mut() {
            all.push(&mut **r);
        }
        run_experiment_report::<TwoDof, 2>(&s, &mut all)?
    };
    let mut clean = s.clone();
    clean.faults.events.clear();
    clean.timing.duration_2dof_s = summary.duration_s.max(s.timing.dt);
    let mut fault_free = EpisodeStats::new(&eps);
    // Nothing to judge (no fault of non-zero duration): no reference run.
    if !eps.is_empty() {
        let mut all: Vec<&mut dyn Recorder<2>> = Vec::with_capacity(reference.len() + 1);
        all.push(&mut fault_free);
        for r in reference.iter_mut() {
            all.push(&mut **r);
        }
        run_experiment_report::<TwoDof, 2>(&clean, &mut all)?;
    }
    let fault_classes =
        soak_fault_classes(&eps, &faulted, &fault_free, summary.safety.latched_at_s);
    Ok(SoakReport {
        controller: summary.controller,
        payload_kg,
        simulated_s: summary.duration_s,
        fault_events: s.faults.events.len(),
        stats,
        monitor_trips: report.monitor_trips,
        wall_time_s: start.elapsed().as_secs_f64(),
        monitor_events_dropped: report.events_dropped,
        handovers: summary.safety.handovers,
        fallback_stops: summary.safety.fallback_stops,
        escalations: summary.safety.escalations,
        revocations: summary.safety.revocations,
        latched_at_s: summary.safety.latched_at_s,
        latched_by: summary.safety.latched_by,
        latched_for_s: summary.safety.latched_for_s,
        estimated_steps: summary.safety.estimated_steps,
        sensor_faults: summary.safety.sensor_faults,
        fault_episodes: fault_classes.iter().map(|c| c.episodes).sum(),
        fault_episodes_passing: fault_classes.iter().map(|c| c.passing).sum(),
        fault_classes,
        monitor_events: report.events,
    })
}
