//! Every response path of the supervisor is stable (issue 28, item 3; docs/RELIABILITY.md
//! §2b): `hold`, `ramp_to_zero`, the transparent `fallback` and the protective stop, each
//! driven on the hardest cells of the standard envelope at 3 kg (`envelopes/standard.toml`:
//! the payload at the ankle, the 1.1-Hz gait, the stiff straps ×2; the 1.3-Hz gait at 2-3 kg
//! is beyond the actuator and only torque-limited), must neither oscillate (no oscillation
//! monitor trip, the run not a limit cycle or growing by the envelope's classifier) nor drop
//! the load onto the person abruptly (the largest step of a true strap force over one period
//! within `MAX_JUMP_N` of the clean run's).
//!
//! The configured response (`hold`, `ramp_to_zero`, `fallback`) is driven by a shank force
//! railed at the sensor's full scale for 0.5 s from 3 s (after 0.05 s the sensor-timeout
//! monitor applies `response`); the protective stop by a NaN on both angles for 1 s from 3 s
//! (a persistent fault: the stop from 3.5 s, the controller back 0.1 s after the angles).

use exompc::config::Experiment;
use exompc::control::{MonitorAction, MonitorKind, MonitorResponse, TorqueLimits};
use exompc::scenario::{run_experiment_report, TwoDof};
use exompc::sim::{
    classify_run, Channel, FaultEvent, FaultKind, RunClass, StabilityCriteria, TraceLog,
};

/// Largest step of a true strap force over one 10-ms period (N) a response may add, within
/// `RAMP_WINDOW_S` of its start, to the clean run's largest step over the same window (the
/// load must not drop onto the person abruptly). Measured (docs/RELIABILITY.md §2b): the
/// clean hard cells at 3 kg step by 2.5-9.2 N a period there; the protective stop at the
/// torque-rate limit (10 N·m a period) stepped by up to 27.0 N (17.8 N more than clean), at
/// `STOP_RAMP_NM_PER_S` by up to 14.9 N (5.7 N more); every path now stays within 7.4 N of
/// the clean run.
const MAX_JUMP_N: f64 = 8.0;

/// The window after the response begins in which the strap-force steps are judged (s).
const RAMP_WINDOW_S: f64 = 0.4;

/// The hard cells at 3 kg, 6-s 2-DOF MS-NMPC runs.
fn cells() -> Vec<(&'static str, Experiment)> {
    cells_of(6.0)
}

/// The hard cells at 3 kg, 2-DOF MS-NMPC runs of `seconds`.
fn cells_of(seconds: f64) -> Vec<(&'static str, Experiment)> {
    let base = || {
        let mut s = Experiment::default();
        s.uncertainty.payload_kg = 3.0;
        s.timing.duration_2dof_s = seconds;
        s
    };
    let mut ankle = base();
    ankle.robot.payload_position_m = 0.43;
    let mut fast = base();
    fast.trajectory.swing.base_frequency_hz = 1.1;
    let mut stiff = base();
    stiff.straps.stiffness = 1875.0;
    stiff.straps.damping = 187.4;
    vec![
        ("payload at 0.43 m", ankle),
        ("gait 1.1 Hz", fast),
        ("straps x2", stiff),
    ]
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Path {
    Hold,
    Ramp,
    Fallback,
    Stop,
}

const PATHS: [Path; 4] = [Path::Hold, Path::Ramp, Path::Fallback, Path::Stop];

/// When the response begins (s): 0.05 s after the force rails at 3 s, or when the angles'
/// NaN at 3 s becomes persistent (0.5 s); the strap-force steps are judged from just before.
fn response_start(path: Path) -> f64 {
    if path == Path::Stop {
        3.45
    } else {
        3.0
    }
}

fn event(kind: FaultKind, channel: Channel, start_s: f64, duration_s: f64) -> FaultEvent {
    FaultEvent {
        kind,
        channel,
        start_s,
        duration_s,
        magnitude: 0.0,
    }
}

/// `s` with the fault that drives `path` from 3 s.
fn driven(s: &Experiment, path: Path) -> Experiment {
    let mut s = s.clone();
    let railed = vec![event(FaultKind::Saturation, Channel::F2, 3.0, 0.5)];
    match path {
        Path::Hold => s.monitors.response = MonitorResponse::Hold,
        Path::Ramp => s.monitors.response = MonitorResponse::RampToZero,
        Path::Fallback => s.monitors.response = MonitorResponse::Fallback,
        Path::Stop => {}
    }
    s.faults.events = if path == Path::Stop {
        vec![
            event(FaultKind::Nan, Channel::Q1, 3.0, 1.0),
            event(FaultKind::Nan, Channel::Q2, 3.0, 1.0),
        ]
    } else {
        railed
    };
    s.validate().unwrap();
    s
}

/// What the person feels in one run.
#[derive(Debug)]
struct Felt {
    /// Largest |true strap force| (N).
    peak: f64,
    /// Largest change of a true strap force over one period from 2.9 s on (N).
    jump: f64,
    /// RMS true strap force, the larger strap (N).
    rms: f64,
    class: RunClass,
    /// Trips of the force and torque oscillation monitors.
    oscillation_trips: usize,
    /// Trips of any monitor, and of the sensor timeout (the path's trigger).
    trips: u64,
    latched: bool,
    limit_violations: u64,
    /// Hand-overs of `hold` or `ramp_to_zero` to the transparent fallback.
    escalations: u64,
}

/// The persistent fault of docs/RELIABILITY.md §2 on the default cell at `payload_kg`: a NaN
/// on both angles for 1.5 s from 2 s (the stop from 2.5 s), a 6-s run.
fn angle_nan_default_cell(payload_kg: f64) -> Experiment {
    let mut s = Experiment::default();
    s.uncertainty.payload_kg = payload_kg;
    s.timing.duration_2dof_s = 6.0;
    s.faults.events = vec![
        event(FaultKind::Nan, Channel::Q1, 2.0, 1.5),
        event(FaultKind::Nan, Channel::Q2, 2.0, 1.5),
    ];
    s
}

fn feel(s: &Experiment, from: f64) -> Felt {
    let mut log = TraceLog::<2>::default();
    let (sum, rep) = run_experiment_report::<TwoDof, 2>(s, &mut [&mut log]).unwrap();
    let rows = &log.rows;
    let peak = rows.iter().map(|r| r.force_true.amax()).fold(0.0, f64::max);
    let jump = rows
        .windows(2)
        .filter(|w| w[0].t >= from && w[0].t < from + RAMP_WINDOW_S)
        .map(|w| (w[1].force_true - w[0].force_true).amax())
        .fold(0.0, f64::max);
    let limits = TorqueLimits {
        max: s.controller.torque_max,
        rate: s.controller.torque_rate_max * s.timing.dt,
    };
    let class = classify_run(&log, &limits, s.timing.dt, &StabilityCriteria::default()).class;
    let oscillation_trips = rep
        .events
        .iter()
        .filter(|e| {
            e.action == MonitorAction::Trip
                && matches!(
                    e.monitor,
                    MonitorKind::ForceOscillation | MonitorKind::TorqueOscillation
                )
        })
        .count();
    Felt {
        peak,
        jump,
        rms: sum
            .rms_force_n
            .thigh
            .unwrap()
            .max(sum.rms_force_n.shank.unwrap()),
        class,
        oscillation_trips,
        trips: rep.monitor_trips,
        latched: rep.latched_at.is_some(),
        limit_violations: sum.limit_violations,
        escalations: rep.escalations,
    }
}

/// Measurement (ignored; a few seconds): every path on every hard cell at 3 kg, with the
/// clean run: peak, largest step per period, RMS, class, trips.
/// `cargo test --release -p exompc --test response_paths table -- --ignored --nocapture`
#[test]
#[ignore = "measurement: prints the response-path table (docs/RELIABILITY.md §2b)"]
fn table() {
    for (name, s) in cells() {
        let clean = feel(&s, 3.0);
        println!(
            "{name}: clean peak {:.1} N, jump {:.2} N, RMS {:.2} N, {:?}",
            clean.peak, clean.jump, clean.rms, clean.class
        );
        for path in PATHS {
            let from = response_start(path);
            let f = feel(&driven(&s, path), from);
            println!(
                "  {path:?}: peak {:.1} N, jump {:.2} N (clean {:.2}), RMS {:.2} N ({:.2}x), {:?}, osc trips {}, trips {}, latched {}",
                f.peak,
                f.jump,
                feel(&s, from).jump,
                f.rms,
                f.rms / clean.rms,
                f.class,
                f.oscillation_trips,
                f.trips,
                f.latched
            );
        }
    }
    // The persistent fault of docs/RELIABILITY.md §2 on the default cell: a NaN on both
    // angles for 1.5 s from 2 s (the stop from 2.5 s).
    for payload in [0.0, 2.0, 3.0] {
        let f = feel(&angle_nan_default_cell(payload), 2.45);
        println!(
            "default, {payload} kg, 1.5-s NaN on the angles: peak {:.1} N, jump {:.2} N, RMS {:.2} N, {:?}, trips {}",
            f.peak, f.jump, f.rms, f.class, f.trips
        );
    }
}

/// Every response path on every hard cell at 3 kg: the limits hold, the supervisor does not
/// latch, the run is no limit cycle (its strap forces keep less than a quarter of their
/// power above 3 Hz: no oscillation) and no strap force steps by more than `MAX_JUMP_N` over
/// the clean run's largest step in the window after the response begins (no abrupt drop of
/// the load). Before the ramp at `STOP_RAMP_NM_PER_S` the protective stop on the payload at
/// the ankle stepped by 27.0 N (clean 9.2 N).
#[test]
fn every_response_path_is_stable_on_the_hard_cells() {
    for (name, s) in cells() {
        for path in PATHS {
            let from = response_start(path);
            let clean = feel(&s, from);
            let f = feel(&driven(&s, path), from);
            let what = format!("{name}, {path:?}: {f:?} (clean {clean:?})");
            assert!(f.trips > 0, "{what}: the path was not driven");
            assert_eq!(f.limit_violations, 0, "{what}");
            assert!(!f.latched, "{what}");
            assert_ne!(f.class, RunClass::LimitCycle, "{what}");
            assert!(f.jump <= clean.jump + MAX_JUMP_N, "{what}");
        }
    }
}

/// Every response path settles: in 10-s runs of the hard cells at 3 kg (6 s after the fault)
/// every path ends in its clean run's class, `saturating` (ankle, 1.1 Hz) or `stable`
/// (straps ×2): none `growing` (the last 2 s above 1.5× the first) or a limit cycle. In the
/// 6-s runs of §2b's table the last 2 s still hold the response's own transient (the
/// protective stop's zero torque until 4.1 s). Before `hold` and `ramp_to_zero` handed over to
/// the fallback, they kept the strap force at full scale to the end of the run (`growing`).
#[test]
fn every_response_path_settles_after_the_fault() {
    for (name, s) in cells_of(10.0) {
        let clean = feel(&s, 3.0);
        assert!(
            matches!(clean.class, RunClass::Stable | RunClass::Saturating),
            "{name}: {clean:?}"
        );
        for path in PATHS {
            let f = feel(&driven(&s, path), response_start(path));
            let what = format!("{name}, {path:?}: {f:?}");
            assert!(f.trips > 0, "{what}: the path was not driven");
            assert_eq!(f.class, clean.class, "{what} (clean {clean:?})");
        }
    }
}

/// `hold` and `ramp_to_zero` hand the torque to the transparent fallback when the trip's cause
/// is present after `RESPONSE_ESCALATE_S` (the railed shank force here): on every hard cell
/// at 3 kg the peak true strap force stays under 70 N and the RMS within 1.6× the clean run's.
/// Without the hand-over (docs/RELIABILITY.md §2b, measured on 2026-12-05) the held torque
/// and the zero torque kept the strap force at the sensor's full scale and so the strap-force
/// monitor tripped: `hold` 214.2 / 153.9 / 64.6 N (RMS 7.50 / 3.12 / 2.36×), `ramp_to_zero`
/// 163.8 / 125.9 / 57.1 N (5.88 / 2.78 / 2.38×) on the ankle, 1.1-Hz and straps ×2 cells.
#[test]
fn hold_and_ramp_hand_over_to_the_fallback_when_their_cause_persists() {
    for (name, s) in cells() {
        let clean = feel(&s, 3.0);
        for path in [Path::Hold, Path::Ramp] {
            let f = feel(&driven(&s, path), response_start(path));
            let what = format!("{name}, {path:?}: {f:?} (clean {clean:?})");
            assert_eq!(f.escalations, 1, "{what}");
            assert!(f.peak < 70.0, "{what}");
            assert!(f.rms <= 1.6 * clean.rms, "{what}");
        }
    }
}

/// The transparent fallback is itself watched (issue 28): when its demand jumps by more than
/// `FALLBACK_DEMAND_JUMP` × the rate limit in one period, to beyond `FALLBACK_DEMAND_BEYOND` ×
/// the torque limit, the torque goes to the protective stop, which ramps it to zero at
/// `STOP_RAMP_NM_PER_S` and keeps it there until every monitor has cleared; the controller
/// then has the torque again. Driven open loop (`build_supervised`, the default scenario at
/// 0 kg with `response = "fallback"`): a 1-Hz gait through the sensors' moving average, and a
/// shank force railed at full scale for 0.5 s from 3.2 s (the strap-force and sensor-timeout
/// monitors hand the torque to the fallback). The angles do not answer the applied torque,
/// so the fallback's estimate of the human motion from the robot's dynamics swings: its
/// demand jumps by 40.3 N·m at 3.33 s and the stop takes the torque (measured on 2026-12-05).
/// In closed loop this happened after a 1-s spike of both forces at 0 kg believed at once
/// after `FORCE_RESYNC_S` (a jump of 45.8 N·m to 52.4 N·m when the spike ended); with the
/// force's jump taken in at `FORCE_BIAS_RATE` no fault of the scans reaches the fallback's
/// divergence (docs/RELIABILITY.md §2a).
#[test]
fn a_diverging_fallback_hands_the_torque_to_the_protective_stop() {
    use exompc::config::ControllerKind;
    use exompc::control::{
        Controller, Measurement, SafetySettings, StepStatus, FALLBACK_DEMAND_JUMP,
        STOP_RAMP_NM_PER_S,
    };
    use exompc::estimate::MovingAverage;
    use exompc::scenario::build_supervised;
    use nalgebra::SVector;
    let mut s = Experiment::default();
    s.uncertainty.payload_kg = 0.0;
    s.monitors.response = MonitorResponse::Fallback;
    let rate = SafetySettings::from_scenario(&s).limits.rate;
    let dt = s.timing.dt;
    let mut sup = build_supervised::<TwoDof, 2>(&s, ControllerKind::MSNMPC).unwrap();
    let w = std::f64::consts::TAU;
    // Raw samples through the sensors' 5-sample moving average (the filtered velocity then
    // equals the angle's mean slope, what the channel guard holds a clean velocity to).
    let raw = |k: usize| {
        let t = k as f64 * dt;
        (
            SVector::from([0.3 * (w * t).sin(), -0.6 + 0.4 * (w * t + 1.0).sin()]),
            SVector::from([0.3 * w * (w * t).cos(), 0.4 * w * (w * t + 1.0).cos()]),
            SVector::from([2.0 * (w * t).sin(), 3.0 * (w * t + 0.5).sin()]),
        )
    };
    let (mut qd_f, mut f_f) = (MovingAverage::<2>::new(5), MovingAverage::<2>::new(5));
    let mut outs = Vec::new();
    for k in 0..700 {
        let (q, qd, mut f) = raw(k);
        if (320..370).contains(&k) {
            f[1] = 70.0;
        }
        let m = Measurement::<2> {
            t: k as f64 * dt,
            q,
            qd: qd_f.push(qd),
            force: f_f.push(f),
        };
        outs.push(sup.step(&m));
    }
    let rep = sup.report();
    let stop = rep
        .events
        .iter()
        .find(|e| e.action == MonitorAction::Stop)
        .unwrap_or_else(|| panic!("no fallback stop: {:?}", rep.events));
    assert_eq!(
        stop.monitor,
        MonitorKind::FallbackDemand,
        "{:?}",
        rep.events
    );
    assert!(stop.value > FALLBACK_DEMAND_JUMP * rate, "{stop:?}");
    assert!((3.25..3.45).contains(&stop.t), "{stop:?}");
    assert_eq!(rep.fallback_stops, 1);
    assert_eq!(rep.latched_at, None);
    // From the stop until the monitors clear: the torque goes to zero at the stop ramp,
    // never away from it.
    let step = STOP_RAMP_NM_PER_S * dt + 1e-9;
    let mut k = (stop.t / dt).round() as usize;
    while k + 1 < outs.len() && outs[k + 1].status == StepStatus::MonitorTripped {
        let (a, b) = (outs[k].torque, outs[k + 1].torque);
        for j in 0..2 {
            assert!(
                b[j].abs() <= a[j].abs() + 1e-12,
                "step {}: {a} -> {b}",
                k + 1
            );
            assert!((b[j] - a[j]).abs() <= step, "step {}: {a} -> {b}", k + 1);
        }
        k += 1;
    }
    // The stop ends when every monitor has cleared: the controller has the torque again.
    assert!(k + 1 < outs.len(), "the controller did not resume");
    assert_eq!(sup.previous_torque(), outs.last().unwrap().torque);
}

/// The fallback restarts its estimates when it is fed again after steps without measured
/// angles (issue 28): across the gap its second differences of the angles spanned the
/// missing samples as if they were one period, and after a 1.5-s NaN on both angles at 2 kg
/// (the protective stop, then the controller's return) its demand moved by up to 72 N·m a
/// period. Measured on 2026-12-05 (the default cell, 6 s): peak true strap force 65.9 →
/// 56.6 N, RMS of the larger strap 17.76 → 12.58 N, `growing` → `stable`.
#[test]
fn the_fallback_restarts_after_steps_without_measured_angles() {
    let f = feel(&angle_nan_default_cell(2.0), 2.45);
    assert_eq!(f.limit_violations, 0, "{f:?}");
    assert!(!f.latched, "{f:?}");
    assert!(f.rms <= 14.0, "{f:?}");
    assert_eq!(f.class, RunClass::Stable, "{f:?}");
}
