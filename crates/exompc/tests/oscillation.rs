//! The oscillation monitor and the strap-model tracking-error estimate of the safety
//! supervisor (control/safety.rs): closed-form checks of the high-pass detector and of the
//! angle estimate, a provoked limit cycle that must trip the monitor within 1 s, and the
//! default scenario that must trip nothing.

mod common;

use exompc::config::{ControllerKind, Experiment, MonitorResponse};
use exompc::control::{
    Controller, Measurement, MonitorAction, MonitorKind, OscillationDetector, SafetySettings,
    StrapAngleEstimate, Supervisor, OSCILLATION_MIN_HALF_CYCLES,
};
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
    s: &Experiment,
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
fn provoked() -> Experiment {
    common::provoked_limit_cycle()
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
    for kind in [ControllerKind::MSNMPC, ControllerKind::NMPC] {
        for p in [0.0, 1.0, 2.0, 3.0] {
            let mut s = Experiment::default();
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

/// RMS strap forces (thigh, shank) of the 2 s after the first oscillation trip, its time, and
/// the run's escalations of `hold` / `ramp_to_zero` to the fallback.
fn rms_after_trip(s: &Experiment) -> (f64, [f64; 2], u64) {
    let (_, rep, log) = run(s);
    let t = first_oscillation_trip(&rep).expect("no oscillation trip");
    let after: Vec<_> = log
        .rows
        .iter()
        .filter(|r| r.t > t && r.t <= t + 2.0)
        .collect();
    let rms = |i: usize| {
        (after.iter().map(|r| r.force_true[i].powi(2)).sum::<f64>() / after.len() as f64).sqrt()
    };
    (t, [rms(0), rms(1)], rep.escalations)
}

/// Issue acceptance: the response to the provoked limit cycle brings the RMS strap force of
/// the 2 s after the trip below 10 N (the `fallback` response, default: 1.95 / 3.65 N thigh /
/// shank; `ramp_to_zero` 2.47 / 4.36 N, `hold` 2.77 / 4.75 N, see below).
#[test]
fn provoked_limit_cycle_response_brings_the_force_below_10_n() {
    let (t, rms, _) = rms_after_trip(&provoked());
    for (i, r) in rms.iter().enumerate() {
        assert!(
            *r < 10.0,
            "strap {i}: RMS {r:.2} N in the 2 s after the trip at {t} s"
        );
    }
}

/// The transparent fallback (the default response) on the provoked limit cycle, and `hold`
/// and `ramp_to_zero`, which hand the torque to it when the oscillation is present after
/// `RESPONSE_ESCALATE_S`: the monitor trips within 1 s, the fallback's payload estimate finds
/// the 2 kg, and the RMS strap forces of the 2 s after the trip stay below 10 N on every
/// response, the fallback's the smallest (measured on 2026-12-05: fallback 1.95 / 3.65 N,
/// `ramp_to_zero` 2.47 / 4.36 N, `hold` 2.77 / 4.75 N; 32.5 / 48.8 N and 31.7 / 62.0 N while
/// they kept the torque until the monitor cleared).
#[test]
fn fallback_response_calms_the_provoked_limit_cycle() {
    let fb = provoked();
    assert_eq!(fb.monitors.response, MonitorResponse::Fallback);
    let mut rz = provoked();
    rz.monitors.response = MonitorResponse::RampToZero;
    let mut hold = provoked();
    hold.monitors.response = MonitorResponse::Hold;
    let runs: Vec<_> = [&fb, &rz, &hold]
        .par_iter()
        .map(|s| rms_after_trip(s))
        .collect();
    let (t_fb, fb_rms, fb_esc) = runs[0];
    assert!(t_fb <= 1.0, "first oscillation trip at {t_fb} s");
    assert_eq!(fb_esc, 0);
    for (name, (_, rms, esc)) in ["ramp_to_zero", "hold"].iter().zip(&runs[1..]) {
        assert!(*esc > 0, "{name}: no hand-over to the fallback");
        for i in 0..2 {
            assert!(
                fb_rms[i] <= rms[i] && rms[i] < 10.0,
                "strap {i}: fallback {fb_rms:?} N vs {name} {rms:?} N"
            );
        }
    }
    // The fallback's payload estimate, replaying the run's measurements and applied torques.
    let mut log = TraceLog::<2>::default();
    exompc::scenario::run_experiment_report::<TwoDof, 2>(&fb, &mut [&mut log]).unwrap();
    let mut est = exompc::scenario::fallback::<TwoDof, 2>(&fb);
    let mut prev = log.rows[0].torque_robot;
    // The human-angle estimate (from the robot's dynamics and the strap model, one period
    // old) against the plant's true human angles, after the first second.
    let (mut worst, mut worst_robot): (f64, f64) = (0.0, 0.0);
    for (k, r) in log.rows.iter().enumerate() {
        let m = Measurement {
            t: r.t,
            q: r.robot.q,
            qd: r.robot.qd,
            force: r.force_measured,
        };
        est.observe(&m, &prev);
        prev = r.torque_robot;
        if let (Some(h), true) = (est.human_angle_estimate(), r.t > 1.0) {
            let true_human = log.rows[k - 1].human.q;
            worst = worst.max((h - true_human).amax());
            worst_robot = worst_robot.max((log.rows[k - 1].robot.q - true_human).amax());
        }
    }
    let m = est.payload_estimate();
    assert!((m - 2.0).abs() < 0.1, "payload estimate {m} kg");
    // Measured 0.045 rad; robot and human differ by up to 0.83 rad in the limit cycle.
    assert!(
        worst < 0.06 && worst < 0.1 * worst_robot,
        "human angle estimate off by {worst} rad (robot angles: {worst_robot} rad)"
    );
}

/// A supervisor around a PD controller, fed strap forces `force(t)` at rest; returns the
/// first force-oscillation trip time.
fn force_oscillation_trip(force: impl Fn(f64) -> [f64; 2], seconds: f64) -> Option<f64> {
    let s = Experiment::default();
    let inner = exompc::build_controller::<TwoDof, 2>(&s, ControllerKind::PD).unwrap();
    let mut sup = Supervisor::new(inner, SafetySettings::from_scenario(&s));
    let n = (seconds / s.timing.dt).round() as usize;
    for k in 0..n {
        let t = k as f64 * s.timing.dt;
        // The encoders move a little every step (a fresh sample, no sensor timeout).
        let q = SVector::from([0.1 + 1e-4 * (k % 7) as f64, -0.2]);
        sup.step(&Measurement {
            t,
            q,
            qd: SVector::from([1e-3 * (k % 5) as f64, 1e-3 * (k % 3) as f64]),
            force: SVector::from(force(t)),
        });
    }
    sup.report()
        .events
        .iter()
        .find(|e| e.action == MonitorAction::Trip && e.monitor == MonitorKind::ForceOscillation)
        .map(|e| e.t)
}

/// A single jolt of the strap force (a 60 N pulse of 0.1 s, or a 45 N step) does not trip the
/// force-oscillation monitor, although its high-passed RMS over the window exceeds the 8 N
/// threshold; a 4 Hz oscillation of the same size trips it within 1 s.
#[test]
fn a_jolt_does_not_trip_the_force_oscillation_monitor_a_4_hz_limit_cycle_does() {
    let pulse = |t: f64| [if (1.0..1.1).contains(&t) { 60.0 } else { 0.0 }, 0.0];
    let step = |t: f64| [0.0, if t >= 1.0 { 45.0 } else { 0.0 }];
    // The RMS alone would trip on both (so the test can fail).
    for f in [&pulse as &dyn Fn(f64) -> [f64; 2], &step] {
        let mut d = OscillationDetector::<2>::new(3.0, 0.01, 0.5).with_hysteresis(8.0);
        let mut peak: f64 = 0.0;
        let mut cycles: f64 = 0.0;
        for k in 0..300 {
            d.push(&SVector::from(f(k as f64 * 0.01)));
            peak = peak.max(d.rms_max());
            cycles = cycles.max(d.half_cycles().max());
            assert!(!d.is_oscillating(8.0, OSCILLATION_MIN_HALF_CYCLES));
        }
        assert!(peak > 8.0, "jolt RMS {peak}");
        assert!(cycles < f64::from(OSCILLATION_MIN_HALF_CYCLES), "{cycles}");
        assert_eq!(force_oscillation_trip(f, 3.0), None);
    }
    let osc = |t: f64| {
        let a = if t >= 1.0 { 20.0 } else { 0.0 };
        [
            a * (2.0 * PI * 4.0 * t).sin(),
            0.5 * a * (2.0 * PI * 4.0 * t).cos(),
        ]
    };
    let t = force_oscillation_trip(osc, 3.0).expect("4 Hz oscillation did not trip");
    assert!(
        t > 1.0 && t <= 2.0,
        "tripped at {t} s (oscillation from 1 s)"
    );
}

#[test]
fn oscillation_settings_are_validated_by_name() {
    let mut s = Experiment::default();
    s.monitors.oscillation_cutoff_hz = 0.0;
    assert_eq!(
        s.validate().unwrap_err().field,
        "monitors.oscillation_cutoff_hz"
    );
    let mut s = Experiment::default();
    s.monitors.oscillation_window_s = 0.0;
    assert_eq!(
        s.validate().unwrap_err().field,
        "monitors.oscillation_window_s"
    );
    let mut s = Experiment::default();
    s.monitors.oscillation_force_rms_n = f64::NAN;
    assert_eq!(
        s.validate().unwrap_err().field,
        "monitors.oscillation_force_rms_n"
    );
    let mut s = Experiment::default();
    s.monitors.fallback.inertia_share = 1.5;
    let e = s.validate().unwrap_err();
    assert_eq!(e.field, "monitors.fallback.inertia_share");
    assert_eq!(e.allowed, "finite, in [0, 1]");
    let mut s = Experiment::default();
    s.monitors.fallback.human_window = 2;
    assert_eq!(
        s.validate().unwrap_err().field,
        "monitors.fallback.human_window"
    );
}
