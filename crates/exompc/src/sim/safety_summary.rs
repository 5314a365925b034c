//! The safety supervisor's counters of one run, as carried in a [`Summary`](super::Summary):
//! monitor trips per monitor kind with the time of the first, steps whose torque a monitor
//! response set, and steps held on a rejected measurement (read from the [`SafetyReport`]).

use crate::control::{MonitorAction, SafetyReport};
use alloc::{format, string::String, vec::Vec};
use serde::{Deserialize, Serialize};

/// Trips of one monitor kind during a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MonitorTally {
    /// The monitor, in the event log's spelling (`tracking_error`, `strap_force`, ...).
    pub monitor: String,
    /// Logged trips of this monitor.
    pub trips: u64,
    /// Supervisor time of its first trip (s).
    pub first_trip_s: f64,
}

/// Supervisor counters of a run (all zero and empty for an undisturbed run).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SafetySummary {
    /// Monitor trips, all monitors (including trips beyond the event log's capacity).
    pub monitor_trips: u64,
    /// Steps on which a monitor's response (hold, ramp to zero or the fallback controller)
    /// set the torque.
    pub monitor_steps: u64,
    /// Steps whose measurement was rejected as implausible (previous torque held).
    pub bad_measurement_steps: u64,
    /// Trips per monitor kind, in order of first trip (from the logged events).
    pub monitors: Vec<MonitorTally>,
    /// Monitor events not logged because the event log was full: when non-zero, `monitors`
    /// counts only the logged trips (`monitor_trips` counts all).
    #[serde(default)]
    pub events_dropped: u64,
    /// Times the supervisor took the torque from the controller because it failed (a
    /// tracking-error, strap-force or oscillation monitor tripped while none of them was):
    /// what counts toward the latch.
    #[serde(default)]
    pub handovers: u64,
    /// Times the transparent fallback failed (its torque oscillated above
    /// `oscillation_torque_rms_nm`, or its demand diverged) and the protective stop replaced
    /// it until the monitors cleared.
    #[serde(default)]
    pub fallback_stops: u64,
    /// Times the configured `hold` or `ramp_to_zero` handed the torque to the transparent
    /// fallback because the trip's cause persisted (`control::RESPONSE_ESCALATE_S`).
    #[serde(default)]
    pub escalations: u64,
    /// Times encoder channels believed again on smoothness alone were rejected again because
    /// a monitor that sees the controller fail tripped within `control::UNVERIFIED_S` (the
    /// believed value taken for an offset; for an angle the protective stop follows).
    #[serde(default)]
    pub revocations: u64,
    /// Supervisor time (s) at which repeated handovers latched the response
    /// (`[monitors] latch_trips`); `null` when it did not latch.
    #[serde(default)]
    pub latched_at_s: Option<f64>,
    /// The monitor whose trip latched the response (`tracking_error`, ...); `null` when it
    /// did not latch.
    #[serde(default)]
    pub latched_by: Option<String>,
    /// How long (s) the latch alone kept the torque from the controller (monitors clear,
    /// the response still on): the cost of the latch.
    #[serde(default)]
    pub latched_for_s: f64,
    /// Steps on which some sensor channel was rejected and the controller stepped on its
    /// estimate (counted in `bad_measurement_steps` too).
    #[serde(default)]
    pub estimated_steps: u64,
    /// Sensor channel fault episodes (a channel rejected after being good).
    #[serde(default)]
    pub sensor_faults: u64,
}

/// `TrackingError` → `tracking_error` (the serde spelling of a unit variant's `Debug` name), so
/// that any monitor kind shows up here without a list to keep in step.
fn snake_case(name: &str) -> String {
    let mut out = String::with_capacity(name.len() + 4);
    for (i, c) in name.chars().enumerate() {
        if c.is_uppercase() {
            if i > 0 {
                out.push('_');
            }
            out.extend(c.to_lowercase());
        } else {
            out.push(c);
        }
    }
    out
}

impl SafetySummary {
    /// The counters of `r` and its trips grouped by monitor kind.
    pub fn from_report(r: &SafetyReport) -> Self {
        let mut monitors: Vec<MonitorTally> = Vec::new();
        for e in r.events.iter().filter(|e| e.action == MonitorAction::Trip) {
            let name = snake_case(&format!("{:?}", e.monitor));
            match monitors.iter_mut().find(|m| m.monitor == name) {
                Some(m) => m.trips += 1,
                None => monitors.push(MonitorTally {
                    monitor: name,
                    trips: 1,
                    first_trip_s: e.t,
                }),
            }
        }
        SafetySummary {
            monitor_trips: r.monitor_trips,
            monitor_steps: r.monitor_steps,
            bad_measurement_steps: r.bad_measurement_steps,
            monitors,
            events_dropped: r.events_dropped,
            handovers: r.handovers,
            fallback_stops: r.fallback_stops,
            escalations: r.escalations,
            revocations: r.revocations,
            latched_at_s: r.latched_at,
            latched_by: r.latched_by.map(|k| snake_case(&format!("{k:?}"))),
            latched_for_s: r.latched_for_s,
            estimated_steps: r.estimated_steps,
            sensor_faults: r.sensor_faults,
        }
    }

    /// True when no monitor tripped and no measurement was rejected.
    pub fn is_clean(&self) -> bool {
        self.monitor_trips == 0 && self.monitor_steps == 0 && self.bad_measurement_steps == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::{MonitorEvent, MonitorKind};

    #[test]
    fn groups_trips_by_kind_with_first_time() {
        let ev = |t, monitor, action| MonitorEvent {
            t,
            monitor,
            action,
            value: 1.0,
        };
        let r = SafetyReport {
            steps: 100,
            bad_measurement_steps: 3,
            monitor_trips: 3,
            monitor_steps: 40,
            events: vec![
                ev(0.5, MonitorKind::StrapForce, MonitorAction::Trip),
                ev(0.7, MonitorKind::StrapForce, MonitorAction::Clear),
                ev(0.9, MonitorKind::TrackingError, MonitorAction::Trip),
                ev(1.2, MonitorKind::StrapForce, MonitorAction::Trip),
            ],
            events_dropped: 0,
            handovers: 2,
            fallback_stops: 1,
            escalations: 1,
            revocations: 2,
            latched_at: Some(1.2),
            latched_by: Some(MonitorKind::StrapForce),
            latched_for_s: 0.3,
            estimated_steps: 5,
            sensor_faults: 1,
        };
        let s = SafetySummary::from_report(&r);
        assert_eq!((s.handovers, s.latched_at_s), (2, Some(1.2)));
        assert_eq!(s.fallback_stops, 1);
        assert_eq!(s.escalations, 1);
        assert_eq!(s.revocations, 2);
        assert_eq!(s.latched_by.as_deref(), Some("strap_force"));
        assert!((s.latched_for_s - 0.3).abs() < 1e-12);
        assert_eq!((s.estimated_steps, s.sensor_faults), (5, 1));
        assert_eq!(s.monitor_trips, 3);
        assert_eq!(s.monitor_steps, 40);
        assert_eq!(s.bad_measurement_steps, 3);
        assert_eq!(
            s.monitors,
            vec![
                MonitorTally {
                    monitor: "strap_force".into(),
                    trips: 2,
                    first_trip_s: 0.5
                },
                MonitorTally {
                    monitor: "tracking_error".into(),
                    trips: 1,
                    first_trip_s: 0.9
                },
            ]
        );
        assert!(!s.is_clean());
        assert_eq!(s.events_dropped, 0);
        let full = SafetyReport {
            events_dropped: 7,
            ..r
        };
        assert_eq!(SafetySummary::from_report(&full).events_dropped, 7);
        assert!(SafetySummary::from_report(&SafetyReport::default()).is_clean());
        assert_eq!(snake_case("SensorTimeout"), "sensor_timeout");
    }
}
