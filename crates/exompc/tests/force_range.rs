//! A strap force beyond the force sensor's range (`[faults] saturation_n`, 70 N) is an
//! over-force, and the strap-force monitor reports it (control/safety.rs, docs/ROBUSTNESS.md,
//! "Seventh pass"). The sensor clips its reading to the range, so with the default
//! `force_max_n` (70 N, the range itself) no reading could ever exceed the threshold: before,
//! such a force showed only as a rejected measurement and, 50 ms later, as a *sensor timeout*
//! (a sensor fault, which does not count toward the latch).

use exompc::config::{ControllerKind, Experiment};
use exompc::control::{
    Controller, Measurement, MonitorAction, MonitorKind, SafetyReport, SafetySettings, Supervisor,
};
use exompc::scenario::{run_experiment_report, TwoDof};
use nalgebra::SVector;

/// A supervisor around a PD controller at rest, fed the thigh strap force `thigh(t)` with
/// fresh encoder samples (and a noisy shank strap).
fn feed(s: &Experiment, seconds: f64, thigh: impl Fn(f64) -> f64) -> SafetyReport {
    let inner = exompc::build_controller::<TwoDof, 2>(s, ControllerKind::PD).unwrap();
    let mut sup = Supervisor::new(inner, SafetySettings::from_scenario(s));
    let n = (seconds / s.timing.dt).round() as usize;
    for k in 0..n {
        let t = k as f64 * s.timing.dt;
        sup.step(&Measurement {
            t,
            q: SVector::from([0.1 + 1e-4 * (k % 7) as f64, -0.2 + 1e-4 * (k % 5) as f64]),
            qd: SVector::from([1e-3 * (k % 5) as f64 + 1e-3, 1e-3 * (k % 3) as f64 + 1e-3]),
            force: SVector::from([thigh(t), 1e-3 * (k % 11) as f64]),
        });
    }
    sup.report().clone()
}

fn trips(rep: &SafetyReport) -> Vec<(MonitorKind, f64)> {
    rep.events
        .iter()
        .filter(|e| e.action == MonitorAction::Trip)
        .map(|e| (e.monitor, e.t))
        .collect()
}

/// A reading at full scale (−70 N from 1 s on) trips the strap-force monitor on that very
/// step, as a handover, unless `force_max_n` is above the range; a force ramped to 98 % of the
/// range does not trip it.
#[test]
fn a_reading_at_the_sensors_full_scale_trips_the_strap_force_monitor_at_once() {
    let s = Experiment::default();
    assert_eq!(s.monitors.force_max_n, s.faults.saturation_n);
    let sat = s.faults.saturation_n;
    let rep = feed(&s, 1.5, |t| if t >= 1.0 - 1e-9 { -sat } else { 5.0 + t });
    let tr = trips(&rep);
    assert!(!tr.is_empty(), "{:?}", rep.events);
    assert_eq!(tr[0].0, MonitorKind::StrapForce, "{:?}", rep.events);
    assert!((tr[0].1 - 1.0).abs() < 1e-9, "{:?}", rep.events);
    assert_eq!(rep.handovers, 1, "{:?}", rep.events);

    // A threshold above the range (the bare scan's `--no-monitors`): full scale cannot tell.
    let mut above = s.clone();
    above.monitors.force_max_n = 1000.0;
    let rep = feed(
        &above,
        1.5,
        |t| if t >= 1.0 - 1e-9 { -sat } else { 5.0 + t },
    );
    assert!(
        !trips(&rep).iter().any(|e| e.0 == MonitorKind::StrapForce),
        "{:?}",
        rep.events
    );

    let inside = feed(&s, 1.5, |t| -0.98 * sat * t.min(1.0) - 0.01 * t);
    // (It trips the tracking-error monitor, 0.35 rad ≈ 70 N of strap stretch; not the others.)
    let kinds: Vec<_> = trips(&inside).iter().map(|e| e.0).collect();
    assert!(
        !kinds.contains(&MonitorKind::StrapForce) && !kinds.contains(&MonitorKind::SensorTimeout),
        "{:?}",
        inside.events
    );
}

/// The fast-gait cell of the envelope that drives the straps past the sensor's range (gait
/// 1.3 Hz, 3 kg; the ±30 N·m limit is far below the 75 N·m the gait needs): the over-force
/// is reported as `strap_force`, before any sensor timeout (before: 13 sensor timeouts and no
/// strap-force trip in the 20-s run).
#[test]
fn an_over_force_in_the_fast_gait_cell_is_reported_as_strap_force() {
    let mut s = Experiment::default();
    s.trajectory.swing.base_frequency_hz = 1.3;
    s.uncertainty.payload_kg = 3.0;
    s.timing.duration_2dof_s = 3.0;
    let (_, rep) = run_experiment_report::<TwoDof, 2>(&s, &mut []).unwrap();
    let tr = trips(&rep);
    let first = |k: MonitorKind| tr.iter().find(|e| e.0 == k).map(|e| e.1);
    let force = first(MonitorKind::StrapForce).expect("no strap-force trip");
    if let Some(timeout) = first(MonitorKind::SensorTimeout) {
        assert!(force < timeout, "{:?}", rep.events);
    }
}
