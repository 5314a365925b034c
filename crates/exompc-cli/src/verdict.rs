//! The one-line verdict printed by `simulate`, `sweep` and `soak`.
//!
//! * **failed**: a check the run must pass did not hold: a torque limit was violated or a value
//!   was not finite. The command exits 1 (after writing its results).
//! * **degraded**: the run completed within its limits, but the safety supervisor took over on
//!   some steps (monitor trips, torque held on a rejected measurement) or the solver did not
//!   converge on some steps (fallback torque used). Exit 0, or 3 with `--strict`; the reasons
//!   are listed.
//! * **ok**: none of the above.

use exompc::sim::{SafetySummary, Summary};
use std::fmt;

/// Outcome class of a run, ordered from best to worst.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    /// Every check passed and nothing took over.
    Ok,
    /// Within limits, but the supervisor or the solver's fallback acted on some steps.
    Degraded,
    /// A limit was violated or a value was not finite.
    Failed,
}

impl fmt::Display for Level {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Level::Ok => "ok",
            Level::Degraded => "degraded",
            Level::Failed => "failed",
        })
    }
}

/// A verdict: its level and the reasons (empty for `ok`).
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    /// Outcome class.
    pub level: Level,
    /// Why (most severe first).
    pub reasons: Vec<String>,
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "verdict: {}", self.level)?;
        if !self.reasons.is_empty() {
            write!(f, " ({})", self.reasons.join("; "))?;
        }
        Ok(())
    }
}

fn pct(part: u64, whole: u64) -> String {
    format!(
        "{part} of {whole} steps ({:.1} %)",
        100.0 * part as f64 / whole.max(1) as f64
    )
}

/// Reasons for `degraded` from the supervisor counters (`holds_expected`: rejected measurements
/// are the intended response to injected faults and are not reasons).
fn safety_reasons(s: &SafetySummary, steps: u64, holds_expected: bool) -> Vec<String> {
    let mut r = Vec::new();
    if s.monitor_trips > 0 {
        let kinds: Vec<String> = s
            .monitors
            .iter()
            .map(|m| {
                format!(
                    "{} ×{} first at {:.2} s",
                    m.monitor, m.trips, m.first_trip_s
                )
            })
            .collect();
        let detail = if kinds.is_empty() {
            String::new()
        } else {
            format!(": {}", kinds.join(", "))
        };
        r.push(format!(
            "{} monitor trips{detail}; monitor response on {}",
            s.monitor_trips,
            pct(s.monitor_steps, steps)
        ));
    }
    if s.fallback_stops > 0 {
        r.push(format!(
            "the transparent fallback failed (oscillated or diverged) and was replaced by the \
             protective stop {} times",
            s.fallback_stops
        ));
    }
    if s.escalations > 0 {
        r.push(format!(
            "the configured response handed the torque to the transparent fallback {} times \
             (its cause persisted)",
            s.escalations
        ));
    }
    if s.revocations > 0 {
        r.push(format!(
            "encoder channels believed on smoothness alone were rejected again {} times (the \
             controller failed right after; for an angle the protective stop followed)",
            s.revocations
        ));
    }
    if let Some(t) = s.latched_at_s {
        r.push(format!(
            "latched at {t:.2} s by {} (handover {}): the controller was not handed the torque \
             back for {:.2} s",
            s.latched_by.as_deref().unwrap_or("a monitor"),
            s.handovers,
            s.latched_for_s
        ));
    }
    if s.bad_measurement_steps > 0 && !holds_expected {
        r.push(format!(
            "torque held on a rejected measurement on {}",
            pct(s.bad_measurement_steps, steps)
        ));
    }
    r
}

impl Verdict {
    fn from_parts(failed: Vec<String>, degraded: Vec<String>) -> Self {
        if !failed.is_empty() {
            let mut reasons = failed;
            reasons.extend(degraded);
            Verdict {
                level: Level::Failed,
                reasons,
            }
        } else if !degraded.is_empty() {
            Verdict {
                level: Level::Degraded,
                reasons: degraded,
            }
        } else {
            Verdict {
                level: Level::Ok,
                reasons: Vec::new(),
            }
        }
    }

    /// The verdict of one `simulate` run.
    pub fn of_run(s: &Summary) -> Self {
        let steps = s.steps as u64;
        let mut failed = Vec::new();
        if s.limit_violations > 0 {
            failed.push(format!(
                "torque limits violated on {}",
                pct(s.limit_violations, steps)
            ));
        }
        let mut degraded = safety_reasons(&s.safety, steps, false);
        if s.solver_failures > 0 {
            degraded.push(format!(
                "solver did not converge on {}",
                pct(s.solver_failures, steps)
            ));
        }
        Verdict::from_parts(failed, degraded)
    }

    /// The verdict of a sweep: the worst run's level, with the runs named per level.
    pub fn of_sweep(rows: &[Summary]) -> Self {
        let mut failed = Vec::new();
        let mut degraded = Vec::new();
        for r in rows {
            let v = Verdict::of_run(r);
            let name = format!("{} at {} kg", r.controller, r.payload_kg);
            match v.level {
                Level::Failed => failed.push(format!("{name}: {}", v.reasons.join(", "))),
                Level::Degraded => degraded.push(format!("{name}: {}", v.reasons.join(", "))),
                Level::Ok => {}
            }
        }
        Verdict::from_parts(failed, degraded)
    }

    /// The verdict of a soak: failed on NaN or limit violations; degraded on monitor trips or
    /// solver failures (torque held on a rejected measurement is the expected response to the
    /// injected faults).
    pub fn of_soak(r: &exompc::scenario::SoakReport) -> Self {
        let s = &r.stats;
        let mut failed = Vec::new();
        if s.limit_violations > 0 {
            failed.push(format!(
                "torque limits violated on {}",
                pct(s.limit_violations, s.steps)
            ));
        }
        if s.nan_count > 0 {
            failed.push(format!(
                "non-finite values on {}",
                pct(s.nan_count, s.steps)
            ));
        }
        let mut safety = SafetySummary {
            monitor_trips: r.monitor_trips,
            monitor_steps: s.monitor_steps,
            bad_measurement_steps: s.bad_measurement_steps,
            monitors: Vec::new(),
            events_dropped: r.monitor_events_dropped,
            handovers: r.handovers,
            fallback_stops: r.fallback_stops,
            escalations: r.escalations,
            revocations: r.revocations,
            latched_at_s: r.latched_at_s,
            latched_by: r.latched_by.clone(),
            latched_for_s: r.latched_for_s,
            estimated_steps: r.estimated_steps,
            sensor_faults: r.sensor_faults,
        };
        let report = exompc::control::SafetyReport {
            events: r.monitor_events.clone(),
            ..Default::default()
        };
        safety.monitors = SafetySummary::from_report(&report).monitors;
        let mut degraded = safety_reasons(&safety, s.steps, true);
        if s.solver_failures > 0 {
            degraded.push(format!(
                "solver did not converge on {}",
                pct(s.solver_failures, s.steps)
            ));
        }
        if r.fault_episodes_passing < r.fault_episodes {
            let over: Vec<&str> = r
                .fault_classes
                .iter()
                .filter(|c| c.passing < c.episodes)
                .map(|c| c.fault.as_str())
                .collect();
            degraded.push(format!(
                "{} of {} fault episodes over issue 28's goals ({})",
                r.fault_episodes - r.fault_episodes_passing,
                r.fault_episodes,
                over.join("; ")
            ));
        }
        Verdict::from_parts(failed, degraded)
    }

    /// True for `failed` (the command exits 1).
    pub fn is_failed(&self) -> bool {
        self.level == Level::Failed
    }

    /// The command's outcome: `failed` → exit 1; `degraded` with `strict` → exit 3
    /// ([`crate::error::EXIT_DEGRADED`]); otherwise success. `what` names the run (`run`,
    /// `sweep`, `soak`).
    pub fn outcome(&self, what: &str, strict: bool) -> Result<(), crate::error::CliError> {
        use crate::error::CliError;
        match self.level {
            Level::Failed => Err(CliError::Runtime(format!(
                "{what} failed its checks: {self}"
            ))),
            Level::Degraded if strict => Err(CliError::Degraded(format!(
                "{what} degraded (--strict): {self}"
            ))),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use exompc::sim::MonitorTally;

    fn run(limit: u64, solver: u64, trips: u64) -> Summary {
        Summary {
            controller: "msnmpc".into(),
            steps: 2000,
            payload_kg: 2.0,
            limit_violations: limit,
            solver_failures: solver,
            safety: SafetySummary {
                monitor_trips: trips,
                monitor_steps: 100 * trips,
                bad_measurement_steps: 0,
                monitors: if trips > 0 {
                    vec![MonitorTally {
                        monitor: "strap_force".into(),
                        trips,
                        first_trip_s: 1.25,
                    }]
                } else {
                    vec![]
                },
                events_dropped: 0,
                ..Default::default()
            },
            ..Default::default()
        }
    }

    #[test]
    fn levels_and_reasons() {
        assert_eq!(Verdict::of_run(&run(0, 0, 0)).to_string(), "verdict: ok");
        let d = Verdict::of_run(&run(0, 0, 2));
        assert_eq!(d.level, Level::Degraded);
        assert_eq!(
            d.to_string(),
            "verdict: degraded (2 monitor trips: strap_force ×2 first at 1.25 s; \
             monitor response on 200 of 2000 steps (10.0 %))"
        );
        let s = Verdict::of_run(&run(0, 5, 0));
        assert_eq!(s.level, Level::Degraded);
        assert!(s.reasons[0].contains("solver did not converge on 5 of 2000"));
        let f = Verdict::of_run(&run(1, 0, 1));
        assert!(f.is_failed());
        assert!(f.reasons[0].starts_with("torque limits violated"));
        assert_eq!(f.reasons.len(), 2);
        let sw = Verdict::of_sweep(&[run(0, 0, 0), run(0, 0, 1)]);
        assert_eq!(sw.level, Level::Degraded);
        assert!(sw.reasons[0].starts_with("msnmpc at 2 kg: 1 monitor trips"));
    }
}
