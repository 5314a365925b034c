//! The oscillation monitor and the strap-model tracking-error estimate of the safety
//! supervisor (control/safety.rs): closed-form checks of the high-pass detector and of the
//! angle estimate, a provoked limit cycle that must trip the monitor within 1 s, and the
//! default scenario that must trip nothing.

use exompc::config::{ControllerKind, Scenario};
use exompc::control::{MonitorAction, MonitorKind, OscillationDetector, StrapAngleEstimate};
use exompc::model::Straps;
use exompc::scenario::{run_experiment_report, TwoDof};
use exompc::sim::TraceLog;
use nalgebra::SVector;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Steady-state RMS of a unit sine through the detector's Butterworth high-pass:
/// `|H(f)| / √2` with `|H|² = 1 / (1 + (tan(π f_c dt) / tan(π f dt))⁴)`.
#[test]
fn detector_rms_of_sines_matches_the_butterworth_gain() {
    let dt = 0.01;
    let fc = 3.0;
    for f in [0.5, 1.0, 3.0, 4.0, 10.0, 25.0] {
        // Window of whole periods of f (4 s covers them all).
        let mut d = OscillationDetector::<1>::new(fc, dt, 4.0);
        let mut last = 0.0;
        for k in 0..1000 {
            last = d.push(&SVector::from([2.0 * (2.0 * PI * f * k as f64 * dt).sin()]));
        }
        let ratio = (PI * fc * dt).tan() / (PI * f * dt).tan();
        let want = 2.0 / (1.0 + ratio.powi(4)).sqrt() / 2f64.sqrt();
        assert!(
            (last - want).abs() < 0.01 * want + 1e-6,
            "{f} Hz: {last} vs {want}"
        );
    }
    // A constant never trips, a NaN sample is skipped.
    let mut d = OscillationDetector::<2>::new(fc, dt, 0.5);
    for _ in 0..100 {
        assert!(d.push(&SVector::from([40.0, -7.0])) < 1e-9);
    }
    assert!(d.push(&SVector::from([f64::NAN, 1.0])) < 1e-9);
    assert_eq!(d.window(), 50);
}

/// The estimate inverts `F = ks J (Δq + τ Δqd)` (docs/MODEL.md §4): forces made from a known
/// angle error give it back (to the O(dt) of the held-force integration).
#[test]
fn strap_angle_estimate_inverts_the_strap_model() {
    let (ls1, ls2, ks, cs, dt) = (0.28, 0.16, 937.5, 93.7, 0.01);
    let straps = Straps::two_dof(ls1, ls2, ks, cs);
    let mut est = StrapAngleEstimate::<2>::new(&[ls1, ls2], ks, cs, dt);
    let dq = |t: f64| {
        SVector::from([
            0.1 * (2.0 * PI * t).sin(),
            -0.2 * (2.0 * PI * 0.7 * t).cos(),
        ])
    };
    let dqd = |t: f64| {
        SVector::from([
            0.2 * PI * (2.0 * PI * t).cos(),
            0.28 * PI * (2.0 * PI * 0.7 * t).sin(),
        ])
    };
    let mut worst: f64 = 0.0;
    for k in 0..500 {
        let t = k as f64 * dt;
        let e = est.update(&straps.force(&dq(t), &dqd(t)));
        if t > 1.0 {
            worst = worst.max((e - dq(t)).amax());
        }
    }
    assert!(worst < 0.005, "{worst}");
    // The 1-DOF knee uses the shank lever only; without damping the inversion is exact.
    let mut one = StrapAngleEstimate::<1>::new(&[ls1, ls2], ks, 0.0, dt);
    let f = Straps::one_dof(ls2, ks, 0.0).force(&SVector::from([0.3]), &SVector::from([0.0]));
    assert!((one.update(&f)[0] - 0.3).abs() < 1e-12);
}

fn run(
    s: &Scenario,
) -> (
    exompc::sim::Summary,
    exompc::control::SafetyReport,
    TraceLog<2>,
) {
    let mut log = TraceLog::default();
    let (sum, rep) = run_experiment_report::<TwoDof, 2>(s, &mut [&mut log]).unwrap();
    (sum, rep, log)
}

/// The paper's method (`controller.method = "paper"`) with a 9-sample filter and 2 kg at the
/// ankle (0.43 m): a 4 Hz limit cycle from the start.
fn provoked() -> Scenario {
    let mut s = Scenario::default();
    s.controller.method = exompc::config::Method::Paper;
    s.uncertainty.filter_window = 9;
    s.uncertainty.payload_kg = 2.0;
    s.robot.payload_position_m = 0.43;
    s
}

fn first_oscillation_trip(rep: &exompc::control::SafetyReport) -> Option<f64> {
    rep.events
        .iter()
        .find(|e| {
            e.action == MonitorAction::Trip
                && matches!(
                    e.monitor,
                    MonitorKind::ForceOscillation | MonitorKind::TorqueOscillation
                )
        })
        .map(|e| e.t)
}

#[test]
fn provoked_limit_cycle_trips_the_oscillation_monitor_within_1_s() {
    let (_, rep, _) = run(&provoked());
    let t = first_oscillation_trip(&rep).expect("no oscillation trip");
    assert!(t <= 1.0, "first oscillation trip at {t} s");
}

#[test]
fn default_scenario_trips_no_monitor() {
    let mut cases = Vec::new();
    for kind in [ControllerKind::Msnmpc, ControllerKind::Nmpc] {
        for p in [0.0, 1.0, 2.0, 3.0] {
            let mut s = Scenario::default();
            s.controller.kind = kind;
            s.uncertainty.payload_kg = p;
            cases.push(s);
        }
    }
    let reps: Vec<_> = cases.par_iter().map(|s| run(s).1).collect();
    for (s, rep) in cases.iter().zip(&reps) {
        assert_eq!(
            rep.monitor_trips, 0,
            "{:?} {} kg: {:?}",
            s.controller.kind, s.uncertainty.payload_kg, rep.events
        );
    }
}

/// Issue acceptance: the response to the provoked limit cycle brings the RMS strap force of
/// the 2 s after the trip below 10 N. FAILS today with either response: `ramp_to_zero`
/// (default) gives 32.4 / 48.5 N (thigh / shank), `hold` 31.7 / 62.0 N — at zero or held
/// torque the person carries the robot and the 2 kg at the ankle through the straps. A
/// response that meets it needs a controller that is stable there (the robust-controller
/// work); a rate-derated torque (rate limit × 0.2 … × 0.003) measured 36-57 / 37-56 N.
#[test]
#[ignore = "acceptance not met by hold / ramp_to_zero: 32 / 49 N after the trip (see doc)"]
fn provoked_limit_cycle_response_brings_the_force_below_10_n() {
    let (_, rep, log) = run(&provoked());
    let t = first_oscillation_trip(&rep).expect("no oscillation trip");
    let after: Vec<_> = log
        .rows
        .iter()
        .filter(|r| r.t > t && r.t <= t + 2.0)
        .collect();
    for i in 0..2 {
        let rms = (after.iter().map(|r| r.force_true[i].powi(2)).sum::<f64>() / after.len() as f64)
            .sqrt();
        assert!(
            rms < 10.0,
            "strap {i}: RMS {rms:.2} N in the 2 s after the trip at {t} s"
        );
    }
}

#[test]
fn oscillation_settings_are_validated_by_name() {
    let mut s = Scenario::default();
    s.monitors.oscillation_cutoff_hz = 0.0;
    assert_eq!(
        s.validate().unwrap_err().field,
        "monitors.oscillation_cutoff_hz"
    );
    let mut s = Scenario::default();
    s.monitors.oscillation_window_s = 0.0;
    assert_eq!(
        s.validate().unwrap_err().field,
        "monitors.oscillation_window_s"
    );
    let mut s = Scenario::default();
    s.monitors.oscillation_force_rms_n = f64::NAN;
    assert_eq!(
        s.validate().unwrap_err().field,
        "monitors.oscillation_force_rms_n"
    );
}
