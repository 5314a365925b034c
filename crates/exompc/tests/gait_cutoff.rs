//! The oscillation monitors' gait-following cut-off (`[monitors]
//! oscillation_cutoff_gait_ratio`, control/safety.rs `GaitFrequency`; docs/ROBUSTNESS.md §4,
//! "Eighth pass"). A second-order high-pass at 3 Hz passes a 1.45 Hz gait's fundamental with
//! gain `1/√(1 + (3/1.45)⁴)` ≈ 0.23, so a fast gait's own, torque-limited hip torque read as a
//! 10 N·m "oscillation"; the cut-off now keeps the default's 3:1 ratio to the gait.

use exompc::config::Experiment;
use exompc::control::{
    ControlOutput, Controller, GaitFrequency, HighPass, Measurement, MonitorAction, MonitorKind,
    SafetyReport, SafetySettings, StepStatus, Supervisor, GAIT_MAX_HZ,
};
use exompc::scenario::{run_experiment_report, TwoDof};
use nalgebra::SVector;
use std::f64::consts::PI;

/// A sine gait of 1.3 Hz (0.3 rad around 0.1 rad) with a 0.04 rad, 4 Hz ripple (below the
/// crossing band) gives 1.3 Hz within two samples of the period, nothing before
/// its first period; when the gait stops the estimate falls as `1/(t − t_up)`; a fast 4 Hz
/// swing of 0.3 rad is capped at `GAIT_MAX_HZ`.
#[test]
fn gait_frequency_follows_a_sine_gait_and_ignores_a_small_4_hz_ripple() {
    let dt = 0.01;
    let mut g = GaitFrequency::<2>::new(dt);
    let q = |t: f64| {
        let hip = 0.1 + 0.3 * (2.0 * PI * 1.3 * t).sin() + 0.04 * (2.0 * PI * 4.0 * t).sin();
        let knee = -0.5 + 0.5 * (2.0 * PI * 1.3 * t - PI / 3.0).cos();
        SVector::from([hip, knee])
    };
    let mut first = None;
    for k in 0..1000 {
        let t = k as f64 * dt;
        g.update(&q(t), t);
        if first.is_none() && g.frequency(t).is_some() {
            first = Some(t);
        }
        if t < 0.75 {
            // Less than one period after the first possible upward crossing.
            assert!(g.frequency(t).is_none(), "{t}");
        }
        if t > 3.0 {
            let f = g.frequency(t).unwrap();
            // Period quantised to a sample, the ripple moving a crossing by about one more:
            // 1/(1/1.3 ± 2 dt).
            assert!((f - 1.3).abs() < 2.0 * 1.3 * 1.3 * dt * 1.05, "{t}: {f}");
        }
    }
    assert!(first.unwrap() < 2.0, "{first:?}");
    // The gait stops (held at its last angle): after 2 s the estimate is at most 1/2 s.
    let last = q(9.99);
    for k in 1000..1200 {
        let t = k as f64 * dt;
        g.update(&last, t);
    }
    let f = g.frequency(11.99).unwrap();
    assert!(f <= 0.5 + 1e-9, "{f}");
    // A non-finite sample is skipped.
    g.update(&SVector::from([f64::NAN, 0.0]), 12.0);
    // A 0.3 rad swing at 4 Hz: capped.
    let mut g = GaitFrequency::<1>::new(dt);
    for k in 0..300 {
        let t = k as f64 * dt;
        g.update(&SVector::from([0.3 * (2.0 * PI * 4.0 * t).sin()]), t);
    }
    assert_eq!(g.frequency(2.99), Some(GAIT_MAX_HZ));
}

/// `HighPass::set_cutoff` keeps the filter running at the new cut-off: the steady-state gain
/// on a sine matches the closed form `|H|² = 1/(1 + (tan(π f_c dt)/tan(π f dt))⁴)` of the new
/// cut-off, not the old.
#[test]
fn high_pass_set_cutoff_gives_the_closed_form_gain_of_the_new_cutoff() {
    let dt = 0.01;
    let f = 1.45;
    let mut hp = HighPass::<1>::new(3.0, dt);
    let sine = |k: usize| SVector::from([(2.0 * PI * f * k as f64 * dt).sin()]);
    for k in 0..500 {
        hp.push(&sine(k));
    }
    hp.set_cutoff(4.35, dt);
    let mut peak: f64 = 0.0;
    for k in 500..2500 {
        let y = hp.push(&sine(k))[0];
        if k > 1500 {
            peak = peak.max(y.abs());
        }
    }
    let gain = |fc: f64| 1.0 / (1.0 + ((PI * fc * dt).tan() / (PI * f * dt).tan()).powi(4)).sqrt();
    assert!(
        (peak - gain(4.35)).abs() < 0.01 * gain(4.35),
        "{peak} vs {}",
        gain(4.35)
    );
    assert!(gain(3.0) > 2.0 * gain(4.35));
}

/// An inner controller that commands a prescribed torque `T(t)`.
struct Scripted<F: Fn(f64) -> [f64; 2]> {
    torque: F,
    prev: SVector<f64, 2>,
}

impl<F: Fn(f64) -> [f64; 2]> Controller<2> for Scripted<F> {
    fn step(&mut self, m: &Measurement<2>) -> ControlOutput<2> {
        ControlOutput {
            torque: SVector::from((self.torque)(m.t)),
            status: StepStatus::Ok,
            iterations: 0,
        }
    }
    fn name(&self) -> &'static str {
        "scripted"
    }
    fn previous_torque(&self) -> SVector<f64, 2> {
        self.prev
    }
    fn set_previous_torque(&mut self, t: SVector<f64, 2>) {
        self.prev = t;
    }
}

/// A supervisor (default `[monitors]` but for `ratio`) around a scripted hip torque, with the
/// encoders following a 1.45 Hz gait and the straps carrying (almost) nothing.
fn supervise(ratio: f64, seconds: f64, torque: impl Fn(f64) -> [f64; 2]) -> SafetyReport {
    let mut s = Experiment::default();
    s.monitors.oscillation_cutoff_gait_ratio = ratio;
    let dt = s.timing.dt;
    let inner = Scripted {
        torque,
        prev: SVector::zeros(),
    };
    let mut sup = Supervisor::new(inner, SafetySettings::from_scenario(&s));
    let w = 2.0 * PI * 1.45;
    for k in 0..(seconds / dt).round() as usize {
        let t = k as f64 * dt;
        sup.step(&Measurement {
            t,
            q: SVector::from([
                0.1 + 0.3 * (w * t).sin(),
                -0.5 + 0.5 * (w * t - PI / 3.0).cos(),
            ]),
            qd: SVector::from([0.3 * w * (w * t).cos(), -0.5 * w * (w * t - PI / 3.0).sin()]),
            force: SVector::from([0.01 * (k % 7) as f64 + 0.01, 0.01 * (k % 5) as f64 + 0.01]),
        });
    }
    sup.report().clone()
}

fn first_torque_trip(rep: &SafetyReport) -> Option<f64> {
    rep.events
        .iter()
        .find(|e| e.action == MonitorAction::Trip && e.monitor == MonitorKind::TorqueOscillation)
        .map(|e| e.t)
}

/// The fast gait's hip torque as the MS-NMPC commands it in the "gait 1.3 Hz, 2 kg" cell: a
/// 1.45 Hz gait torque on the ±30 N·m limit for most of each half-cycle and switching between
/// the limits at the rate limit (`100 sin(2π 1.45 t)` clamped by the supervisor, faded in over the
/// first two seconds: before one gait period has been seen the cut-off is the fixed one). With
/// the fixed 3 Hz cut-off (ratio 0, main's monitor) its high-passed RMS is about 11.3 N·m and the
/// torque-oscillation monitor trips; with the gait-following cut-off (4.35 Hz) about 8.5 N·m,
/// no trip. A ±25 N·m, 4 Hz oscillation added from 4 s on to a 15 N·m gait torque trips it
/// within 1 s either way (0.29 s fixed, 0.5 s following: the higher cut-off passes 4 Hz with
/// gain 0.6 instead of 0.87).
#[test]
fn a_clipped_fast_gait_torque_is_no_oscillation_a_4_hz_one_on_top_is() {
    let w = 2.0 * PI * 1.45;
    // Faded in over the first two seconds (the gait estimate needs one period).
    let gait = move |t: f64| {
        [
            100.0 * (0.5 * t).min(1.0) * (w * t).sin(),
            8.0 * (w * t).cos(),
        ]
    };
    let fixed = supervise(0.0, 10.0, gait);
    assert!(first_torque_trip(&fixed).is_some(), "{:?}", fixed.events);
    let follows = supervise(3.0, 10.0, gait);
    assert_eq!(follows.monitor_trips, 0, "{:?}", follows.events);

    let limit_cycle = move |t: f64| {
        let lc = if t >= 4.0 {
            25.0 * (2.0 * PI * 4.0 * t).sin()
        } else {
            0.0
        };
        [15.0 * (w * t).sin() + lc, 8.0 * (w * t).cos()]
    };
    for ratio in [0.0, 3.0] {
        let rep = supervise(ratio, 6.0, limit_cycle);
        let t = first_torque_trip(&rep).expect("no torque-oscillation trip");
        assert!((4.0..=5.0).contains(&t), "ratio {ratio}: trip at {t}");
    }
}

/// The envelope cell "gait 1.3 Hz, payload 2 kg" (MS-NMPC, default controller and monitors):
/// the fast gait's torque-limited hip torque tripped the torque-oscillation monitor at 1.85 s
/// and the fallback then overloaded the straps (strap-force trips from 2.35 s). With the
/// gait-following cut-off the first 6 s trip no monitor; with the fixed cut-off (ratio 0) the
/// torque-oscillation monitor trips as before.
#[test]
fn the_fast_gait_cell_trips_no_oscillation_monitor_with_the_gait_following_cutoff() {
    let mut s = Experiment::default();
    s.trajectory.swing.base_frequency_hz = 1.3;
    s.uncertainty.payload_kg = 2.0;
    s.timing.duration_2dof_s = 6.0;
    let (_, rep) = run_experiment_report::<TwoDof, 2>(&s, &mut []).unwrap();
    assert_eq!(rep.monitor_trips, 0, "{:?}", rep.events);
    s.monitors.oscillation_cutoff_gait_ratio = 0.0;
    let (_, rep) = run_experiment_report::<TwoDof, 2>(&s, &mut []).unwrap();
    assert!(first_torque_trip(&rep).is_some(), "{:?}", rep.events);
}

/// The key is validated by name and range.
#[test]
fn gait_ratio_is_validated_by_name_and_range() {
    for bad in [-0.1, 20.5, f64::NAN, f64::INFINITY] {
        let mut s = Experiment::default();
        s.monitors.oscillation_cutoff_gait_ratio = bad;
        let e = s.validate().unwrap_err();
        assert_eq!(e.field, "monitors.oscillation_cutoff_gait_ratio", "{bad}");
        assert_eq!(e.allowed, "finite, in [0, 20]");
    }
    for ok in [0.0, 3.0, 20.0] {
        let mut s = Experiment::default();
        s.monitors.oscillation_cutoff_gait_ratio = ok;
        s.validate().unwrap();
    }
}
